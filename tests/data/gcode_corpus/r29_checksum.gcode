; expect: refuse line=3 col=14 word=*
G21 G90 G1 X10 Z1 A0 F100
N3 G1 X12 A10*57
M2
