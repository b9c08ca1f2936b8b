(expect: refuse line=3 col=1 word=G41)
G21 G90 G18 G1 X10 Z1 A0 F100
G41 D1 G1 X12
M30
