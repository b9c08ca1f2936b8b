(expect: refuse line=3 col=4 word=Z3)
G21 G90 G18 G1 X10 Z1 A0 F100
G2 Z3 X12 I0 K2.5
M30
