(expect: refuse line=3 col=1 word=G51)
G21 G90 G1 X10 Z1 A0 F100
G51 X0 Z0 P2000
G1 X12
M30
