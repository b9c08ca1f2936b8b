(expect: refuse line=3 col=5 word=G107)
G21 G90 G1 X10 Z1 A0 F100
N30 G107 A20.
M30
