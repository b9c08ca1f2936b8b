%
(expect: compensate)
(Fusion-like: return home at the start and the end)
N10 G90 G94 G21 G18
N15 G28 G91 Z0.
N20 G90
N25 G0 X60. Z5. A0.
N30 G1 Z1. F300.
N35 X70. A30.
N40 G2 X72. Z3. I0. K2.
N45 G0 Z5.
N50 G28 G91 Z0.
N55 G90
N60 M30
%
