(expect: refuse line=3 col=8 word=Z10)
G21 G90 G1 X10 Z1 A0 F100
G19 G2 Z10 K5
M30
