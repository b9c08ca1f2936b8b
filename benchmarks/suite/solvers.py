"""Solvers on the grinder's flute: residual and speed of ``exact`` and the batched GA beside the paper's GA.

The 23-element HTM field of ``make_chain_truth(grinder, seed)`` is the model and the truth (so the MODEL and the TRUE
residual agree: what the solver leaves). ``exact`` and ``batched-ga`` solve the whole flute path (2,800 points;
quick 280), ``ga`` (PyGAD, the paper's per-point GA) a few points spread along it, each timed alone; one-time
costs (imports, numba compilation) run before any timing. Speed: wall seconds per point, one process.
"""
from __future__ import annotations

import numpy as np

from compensation.solvers import solve
from compensation.toolpath import flute_path
from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth

TITLE = "Exact and GA solves on the grinder's flute: residual and speed"
DATA = ("the default flute (2,800 points over 7 turns; quick: 280), HTM field of `make_chain_truth(grinder, seed 0)` as "
        "model and truth; `ga` on 10 points spread along it (quick: 3), `batched-ga` on 280 (quick: 40)")


def _true_max_um(truth, r) -> float:
    n = len(r.axes)
    return float(np.linalg.norm((truth.tool_point(r.axes, **truth.default_conditions(n)) - r.targets_mm) * 1e3,
                                axis=1).max())


def run(quick: bool, seed: int) -> dict:
    m = load_machine()
    truth = make_chain_truth(m, seed)
    field = ChainField(m, truth.elements)
    fp = flute_path(points_per_turn=40) if quick else flute_path()
    targets, axes = fp.targets_mm, fp.axes(m)
    for method in ("exact", "batched-ga", "ga"):                           # warm-up: imports, compilation
        solve(method, field, targets[:2], m, target_axes=axes[:2], progress=False,
              **({} if method == "exact" else {"generations": 2}))
    n = len(targets)
    ex = solve("exact", field, targets, m, target_axes=axes, progress=False)
    nb = 40 if quick else 280
    sb = np.linspace(0, n - 1, nb).round().astype(int)
    bg = solve("batched-ga", field, targets[sb], m, target_axes=axes[sb], seed=seed, progress=False)
    sg = np.linspace(0, n - 1, 3 if quick else 10).round().astype(int)
    ga = [solve("ga", field, targets[i:i + 1], m, target_axes=axes[i:i + 1], seed=seed, progress=False) for i in sg]
    ga_s = float(np.median([r.seconds for r in ga]))
    ga_max = float(max(r.residual_norm_um.max() for r in ga))
    unc = float(np.linalg.norm(field.predict(axes), axis=1).max())
    fig = lambda what, v, unit, res, anchor, av: {"what": what, "value": v, "unit": unit, "residual": res,  # noqa: E731
                                                  "anchor": anchor, "anchor_value": av}
    return {"figures": [
        fig(f"exact, max over {n} points", float(ex.residual_norm_um.max()), "μm", "model",
            "uncompensated, max", unc),
        fig("exact, TRUE max (the same field as truth)", _true_max_um(truth, ex), "μm", "true", "uncompensated, max", unc),
        fig(f"batched-ga, max over {nb} points", float(bg.residual_norm_um.max()), "μm", "model",
            f"ga (the paper's), max over {len(sg)} points", ga_max),
        fig("exact, wall per point", ex.seconds / n * 1e6, "μs", "none", "ga, median per point", ga_s * 1e6),
        fig("batched-ga, wall per point", bg.seconds / nb * 1e6, "μs", "none", "ga, median per point", ga_s * 1e6),
    ], "notes": [f"exact is {ga_s / (ex.seconds / n):,.0f}× faster per point than the paper's GA in this run."]}
