(expect: refuse line=2 col=9 word=G55 work-offsets=none)
G21 G90 G55
G1 X10 Z1 A0 F100
M30
