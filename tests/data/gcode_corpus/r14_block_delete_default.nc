(expect: refuse line=4 col=1 word=/)
G21 G90
G1 X10 Z1 A0 F100
/N70 G1 X15 A10
G1 X20
M30
