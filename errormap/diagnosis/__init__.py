"""Residual diagnosis: trace the measured residual (measurement − model) to the effect the model
lacks (thermal, drift, reversal, periodic, harmonic, interaction), and thermal error modelling on
drift logs. See docs/explanation/closed-loop.md. Imports only within ``errormap``."""
