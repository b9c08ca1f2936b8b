%
(expect: compensate)
(RS274NGC / Fanuc: G28 with axis words goes at rapid through that point, then to the reference;)
(the point is a rapid, written as programmed; Z is unknown until the next absolute Z)
N10 G21 G90 G18
N20 G0 X60. Z5. A0.
N30 G1 Z1. F300.
N40 X70. A30.
N50 G28 Z20. (through Z20 of the part, then Z home)
N60 G0 Z5.
N70 G1 X65. Z2. A10.
N80 G91 G28 X0. Z0.
N90 G90
N100 M30
%
