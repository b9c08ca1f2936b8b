(expect: compensate)
G21 G90 G1 X12 Z1 A0 F100
X13 A90