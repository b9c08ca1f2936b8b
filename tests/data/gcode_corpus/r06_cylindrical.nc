(expect: refuse line=3 col=1 word=G7.1)
G21 G90 G1 X10 Z1 A0 F100
G7.1 C20.
G1 A90
G7.1 C0
M30
