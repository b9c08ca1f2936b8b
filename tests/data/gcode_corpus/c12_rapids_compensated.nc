(expect: compensate rapids=compensate)
G21 G90
G0 X100 Z5 A0
G1 Z0.4 F100
X101 A45
G0 Z5
M30
