%
(expect: refuse line=5 col=5 word=G28)
(Fusion-like program ending with a return home)
N10 G90 G94 G21 G1 X60 Z5 A0 F300
N15 G28 G91 Z0.
N20 G90
N25 M30
%
