(expect: refuse line=3 col=5 word=G81)
G21 G90 G1 X10 Z1 A0 F100
G98 G81 X12 Z-2 R1 F50
G80
M30
