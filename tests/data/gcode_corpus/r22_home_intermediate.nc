(expect: refuse line=3 col=5 word=Z5)
G21 G90 G1 X10 Z1 A0 F100
G28 Z5 (home through an intermediate point)
M30
