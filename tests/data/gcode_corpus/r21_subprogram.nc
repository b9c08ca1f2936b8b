%
O3000 (expect: refuse line=5 col=9 word=M98)
N10 G21 G90
N20 G1 X10 Z1 A0 F100
N30 M98 P1000
N40 M30
%
