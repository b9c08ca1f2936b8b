(expect: compensate)
G21 G90 G18
G1 X70 Z3 A0 F90
X71 A20 (crlf)
G2 X73 Z5 I2 K0
M30
