(expect: refuse line=3 col=5 word=G68)
G21 G90 G1 X10 Z1 A0 F100
G18 G68 X0 Z0 R30
M30
