"""Compensation solvers: traditional, ga (PyGAD), batched-ga, exact."""
