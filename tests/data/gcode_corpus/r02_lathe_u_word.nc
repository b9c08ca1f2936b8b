(expect: refuse line=3 col=4 word=U1.0)
G21 G90 G1 X10 Z1 A0 F100
G1 U1.0
M30
