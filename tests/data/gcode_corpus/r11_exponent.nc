(expect: refuse line=3 col=4 word=X1e2)
G21 G90 G1 X10 Z1 A0 F100
G1 X1e2
M30
