(expect: refuse line=3 col=1 word=G92)
G21 G90 G1 X10 Z1 A0 F100
G92 X0 Z0
M30
