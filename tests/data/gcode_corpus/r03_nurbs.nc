(expect: refuse line=3 col=1 word=G5.2)
G21 G90 G1 X10 Z1 A0 F100
G5.2 X12 Z2 P1 L3
X14 Z3 P1
G5.3
M30
