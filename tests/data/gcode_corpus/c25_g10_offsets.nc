(expect: compensate)
G10 L2 P1 X10 Z5
G21 G90 G1 X10 Z1 A0 F100
M30
