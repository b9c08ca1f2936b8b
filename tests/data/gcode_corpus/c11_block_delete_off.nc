(expect: compensate block-delete=off)
G21 G90
G1 X20 Z1 A0 F100
/G1 X25 A10 (optional pass)
G1 X30 A20
M30
