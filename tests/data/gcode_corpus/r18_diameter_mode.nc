(expect: refuse line=2 col=1 word=G7)
G7 G18 G21 G90
G1 X20 Z1 A0 F100
M30
