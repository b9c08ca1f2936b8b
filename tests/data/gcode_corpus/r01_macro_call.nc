(expect: refuse line=3 col=5 word=G65)
G21 G90 G1 X10 Z1 A0 F100
G65 P9000 A1 X2 Z3
G1 X12
M30
