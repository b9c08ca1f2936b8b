(expect: refuse line=3 col=8 word=X12)
G21 G90 G1 X10 Z1 A0 F100
G17 G2 X12 I1
M30
