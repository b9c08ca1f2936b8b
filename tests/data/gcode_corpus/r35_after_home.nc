(expect: refuse line=4 col=4 word=X20)
G21 G90 G1 X10 Z1 A0 F100
G28
G1 X20
M30
