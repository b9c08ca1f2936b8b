(expect: refuse line=3 col=5 word=Z5 rapids=compensate)
G21 G90 G1 X10 Z1 A0 F100
G28 Z5 (home through an intermediate point: a rapid that --rapids compensate cannot carry compensated)
M30
