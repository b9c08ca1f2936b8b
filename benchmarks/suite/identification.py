"""Identification from laser-tracker sweeps: noise-free exactness and the propagation of tracker noise.

Truth: ``make_chain_truth(builtin grinder, seed 3 + seed)``; 10,000 random axis points. Noise-free sweeps in both
gauges; then σ = 2 μm tracker noise over ``draws`` noise draws. TRUE residual: identified HTM field minus the
truth field, ‖Δe‖ (μm). Anchor: the truth field itself (what an uncompensated machine shows).
"""
from __future__ import annotations

import time

import numpy as np

from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth, random_axes
from errormap.stats import residual_stats
from errormap.chain_sweeps import simulated_sweeps
from errormap.identification import ChainIdentification
from errormap.sweeps import sweeps_from_columns

TITLE = "Identification: tracker sweeps → 23 elements of the grinder"
DATA = ("simulated grinder (`make_chain_truth` seed 3), 21 stations per axis, 3 balls per body, 10,000 random axis "
        "points; σ = 2 μm tracker noise over 100 draws (quick: 5)")
NOISE_UM = 2.0


def _identify(sweeps, machine, gauge="first-station"):
    return ChainIdentification(gauge=gauge).fit(sweeps_from_columns(sweeps), machine).result_


def run(quick: bool, seed: int) -> dict:
    m = load_machine()
    truth = make_chain_truth(m, 3 + seed)
    pts = random_axes(m, 2_000 if quick else 10_000, np.random.default_rng(2024 + seed))
    e_true = ChainField(m, truth.elements).predict(pts)
    field_max = float(np.linalg.norm(e_true, axis=1).max())
    free = max(float(np.abs(ChainField(m, _identify(simulated_sweeps(truth, noise_um=0.0, seed=0), m, g).elements_)
                            .predict(pts) - e_true).max()) for g in ("first-station", "reference-line"))
    t0 = time.perf_counter()
    _identify(simulated_sweeps(truth, noise_um=NOISE_UM, seed=0), m)
    t_id = time.perf_counter() - t0
    rms, mx = [], []
    for k in range(1, (5 if quick else 100) + 1):
        r = _identify(simulated_sweeps(truth, noise_um=NOISE_UM, seed=k), m)
        st = residual_stats(ChainField(m, r.elements_).predict(pts) - e_true)
        rms.append(st["rms_um"])
        mx.append(st["max_um"])
    anchor = "truth field (no compensation), max"
    return {"figures": [
        {"what": "noise-free sweeps, max ‖Δe‖ (both gauges)", "value": free, "unit": "μm", "residual": "true",
         "anchor": "target < 0.01 μm", "anchor_value": None},
        {"what": f"σ = {NOISE_UM:g} μm, RMS ‖Δe‖ (mean over draws)", "value": float(np.mean(rms)), "unit": "μm",
         "residual": "true", "anchor": anchor, "anchor_value": field_max},
        {"what": f"σ = {NOISE_UM:g} μm, max ‖Δe‖ (95th percentile over draws)", "value": float(np.percentile(mx, 95)),
         "unit": "μm", "residual": "true", "anchor": anchor, "anchor_value": field_max},
        {"what": "one identification, wall", "value": round(t_id, 3), "unit": "s", "residual": "none",
         "anchor": "", "anchor_value": None},
    ], "notes": ["The noise is amplified by the ball spacing (~100 mm) against the lever arms (200–400 mm): "
                 "2 μm on a ball is ~20–30 μrad on a body's angles."]}
