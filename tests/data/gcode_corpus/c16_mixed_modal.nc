(expect: compensate)
G17 G21 G90 (XY plane, no arcs in it)
G1 X45 Z3 A0 F100
G18 G2 X47 Z5 R2 (arc after switching to XZ)
G1 A30
G4 P0.5 (dwell)
X50 M8
G80
M9 M30
