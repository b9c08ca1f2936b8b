(expect: refuse line=3 col=4 word=X1.5)
G21 G90 G1 X10 Z1 A0 F100
G4 X1.5
M30
