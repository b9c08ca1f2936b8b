(expect: compensate)
G20 G90
G0 X4. Z0.2 A0.
G1 Z0.05 F4.
X4.1 A15.
X4.2 A30.
G0 Z0.2
M30
