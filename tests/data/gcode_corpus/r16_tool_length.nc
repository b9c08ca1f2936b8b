%
O2000 (expect: refuse line=5 col=5 word=G43)
N10 G21 G90
N20 T2 M6
N30 G43 H2
N40 G1 X10 Z1 A0 F100
N50 M30
%
