(expect: refuse line=3 col=1 word=G53)
G21 G90 G1 X10 Z1 A0 F100
G53 G0 Z0
M30
