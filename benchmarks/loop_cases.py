"""One closed-loop benchmark case through the user's CLI path (used by bench_diagnosis.py).

``volcomp sweeps`` (2 μm) → ``volcomp simulate`` (800 checks at 1 μm) → ``volcomp identify``
→ ``volcomp diagnose`` → evaluation against the hidden truth (only here).
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

EXPECTED = {"none": None, "pitch": ("periodic", "x"), "reversal": ("reversal", "z"), "thermal": ("thermal", "x"),
            "interaction": ("interaction", "x*z"), "worm": ("harmonic", "a")}
N_PROBE = 5000
Z95 = 1.959963984540054


def _param_cover(effect, found, truth):
    """Whether the found effect's 95 % interval holds the true parameter (None if not comparable)."""
    p = found["parameters"]
    t = truth.effects[effect]
    key = {"thermal": ("k_um_per_mm_c", "k_um_per_mm_c"), "reversal": ("backlash_um", "backlash_um"),
           "pitch": ("period_mm", "period_mm"), "worm": ("amplitude_urad", "amplitude_urad"),
           "interaction": ("corner_um", "corner_um")}[effect]
    if key[0] not in p or not np.isfinite(p[key[0]].get("se") or np.nan):
        return None
    v, se = p[key[0]]["value"], p[key[0]]["se"]
    tv = t[key[1]]
    if effect == "worm":
        v, tv = abs(v), abs(tv)
    return bool(abs(v - tv) <= Z95 * se)


def run_case(family: str, seed: int, effect: str) -> dict:
    from compensation.app.cli import main
    from errormap.elements import ElementSet
    from errormap.htm import HTMField
    from errormap.machine import load_machine
    from errormap.simulator import random_axes
    from errormap.truth_families import make_truth
    from errormap.uncertainty import ElementCovariance, covariance_path
    eff = [] if effect == "none" else [effect]
    m = load_machine()
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        ea = sum((["--effect", e] for e in eff), [])
        q = ["--family", family, "--seed", str(seed)] + ea
        assert main(["sweeps", *q, "--noise-um", "2", "--seed-noise", str(seed + 500), "--out", str(td / "sw.csv")]) == 0
        assert main(["simulate", *q, "--checks", "800", "--noise-um", "1", "--out", str(td / "sim")]) == 0
        assert main(["identify", str(td / "sw.csv"), "--out", str(td / "el.json")]) == 0
        assert main(["diagnose", str(td / "sim" / "checks.csv"), "--model", str(td / "el.json"),
                     "--out", str(td / "diag")]) == 0
        s = json.loads((td / "diag" / "diagnosis.json").read_text())
        el = ElementSet.load(td / "el.json")
        cov = ElementCovariance.load(covariance_path(td / "el.json"), el)
        upd = ElementSet.load(td / "diag" / "updated_elements.json")
    truth = make_truth(m, seed, effects=eff, family=family)
    P = random_axes(m, N_PROBE, np.random.default_rng(seed + 7))
    et = HTMField(m, truth.elements).predict(P)
    e_id = HTMField(m, el).predict(P) - et
    sd = np.sqrt(np.diagonal(cov.prediction_cov(m, P), axis1=1, axis2=2))
    e_up = HTMField(m, upd).predict(P) - et
    found = s["effects"]
    exp = EXPECTED[effect]
    top = (found[0]["kind"], found[0]["axis"]) if found else None
    named = (not found) if exp is None else (top == exp)
    return {"family": family, "seed": seed, "effect": effect,
            "sweeps_rms_um": float(np.sqrt(np.mean(np.sum(e_id**2, axis=1)))),
            "sweeps_floor_um": float(np.sqrt(np.mean(np.sum(sd**2, axis=1)))),
            "band95_cover": float(np.mean(np.abs(e_id) <= Z95 * sd)),
            "updated_geometry_rms_um": float(np.sqrt(np.mean(np.sum(e_up**2, axis=1)))),
            "held_identified_um": s["stages"]["identified"]["held_out"]["rms_um"],
            "held_updated_um": s["stages"]["updated"]["held_out"]["rms_um"],
            "held_final_um": s["stages"]["updated_plus_effects"]["held_out"]["rms_um"],
            "effects": [f"{e['kind']} {e['axis']}" for e in found], "named_right": bool(named),
            "param_cover": (_param_cover(effect, found[0], truth) if exp is not None and top == exp else None),
            "contradicted": [c["element"] for c in s["update"]["contradicted_by_sweeps"]]}
