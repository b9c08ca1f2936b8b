; expect: refuse line=3 col=8 word=Y0
G21 G90
G0 X10 Y0 Z5 A0
G1 Z1 F100
M2
