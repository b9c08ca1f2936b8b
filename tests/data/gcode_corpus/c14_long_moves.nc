(expect: compensate max-segment=2)
G21 G90
G1 X20 Z5 A0 F300
X40 (20 mm across X)
Z25 (20 mm in Z)
X60 Z45 A90
M30
