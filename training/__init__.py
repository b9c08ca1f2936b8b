"""training: the learned error field (BP network, Levenberg–Marquardt, MLflow tracking).

May import ``errormap``; never ``compensation``.
"""
