(expect: compensate)
(G53: a move in machine coordinates, passed through unchanged)
G21 G90 G1 X10 Z1 A0 F100
G53 G0 Z0
G1 X12 Z2 A1
M30
