(expect: compensate)
G20 G90 G1 X3. Z0.1 A0. F5.
G91 X0.01 A1.
X0.01 A1.
X0.01 A1.
G90 G21 X80. (back to mm)
M30
