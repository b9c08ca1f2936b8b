; expect: compensate
; grbl style: lower case, no N, semicolon comments
g21 g90 g94
m3 s12000
g0 x100 z2 a0
g1 z0.5 f80 ; plunge
x100.5 a45
x101 a90
x101.5 a135 ; keep going
g0 z2
m5
m2
