(expect: compensate max-segment=100)
G21 G90 G1 X10 Z1 A0 F100
G93 G1 X20 F2
M30
