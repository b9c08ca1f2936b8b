"""Compile numba's cached kernels (``@njit(cache=True)``: errormap.chain_kernel and _chain_frames,
compensation.solvers.exact and _ga_kernels, compensation.gcode_kernels, the GP marginal likelihood's
training._gp_kernels) once, before the tests:
``.ci/run`` starts this in the background after the install, while Chromium's install ends, so that the fast tier's two
workers find the kernels in numba's cache instead of each compiling them (tens of CPU seconds a worker on a fresh
clone). It runs the public API on the built-in machines the tests use; a kernel it misses is compiled by the tests as
before (nothing is asserted here, nothing changes but the cache)."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from compensation import compensate_points, compensate_program
from errormap import Identification, load_machine, simulate_sweeps, simulate_truth
from errormap.chain_truth import random_axes

PROGRAM = "G21 G90 G17 G54\nG0 X10 Y10 Z5\nG1 Z-1 F200\nG2 X30 Y10 I10 J0\nG1 X30 Y40\nG0 Z5\nM30\n"


def main() -> None:
    rng = np.random.default_rng(0)
    models = {}
    for name in ("grinder", "mill-xyz", "five-axis-ac", "lathe-xzc"):
        m = load_machine(name)
        model = models[name] = Identification(m).fit(simulate_sweeps(simulate_truth(m, seed=1), noise_um=1.0, seed=2,
                                                                     n_stations=11))
        axes = random_axes(m, 20, rng)
        compensate_points(model.field_, m, axes, allow=("volume", "stroke", "ball"))
        compensate_points(model.field_, m, axes[:1], method="ga", allow=("volume", "stroke", "ball"))  # ~1 s a point
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        (td / "p.nc").write_text(PROGRAM, encoding="ascii")
        models["mill-xyz"].elements_.save(td / "el.json")
        compensate_program([td / "p.nc"], load_machine("mill-xyz"), td / "el.json", td / "out", work_offsets="machine")
    from training.residual import ResidualRegressor   # the learned stage's GP kernels (one signature for all)
    X = rng.uniform(-1.0, 1.0, (40, 3))
    ResidualRegressor(families=("gp",), seed=0).fit(X, np.c_[np.sin(2 * X[:, 0]), X[:, 1], X[:, 2] ** 2])

if __name__ == "__main__":
    main()
