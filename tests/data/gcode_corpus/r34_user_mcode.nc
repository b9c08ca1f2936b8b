(expect: refuse line=3 col=1 word=M100)
G21 G90 G1 X10 Z1 A0 F100
M100 P1
M30
