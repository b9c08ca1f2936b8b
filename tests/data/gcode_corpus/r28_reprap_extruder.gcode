; expect: refuse line=3 col=11 word=E2
G21 G90 G1 X10 Z1 A0 F100
G1 X12 A5 E2
M2
