%
(expect: compensate)
(1001)
(Machine)
(  vendor: volcomp test)
(T1  D=6. CR=0. - ZMIN=0.5 - flat end mill)
N10 G90 G94 G18
N15 G21
(2D Contour1)
N20 T1 M6
N25 S9000 M3
N30 G0 X60. A0.
N35 Z15.
N40 G1 Z5. F500.
N45 Z1. F300.
N50 G2 X62. Z3. I0. K2.
N55 G1 X70.
N60 G3 X72. Z1. I2. K0.
N65 G0 Z15.
N70 M5
N75 M30
%
