"""The paper's path: the surrogate network on feature points, on the grid and between its nodes.

A simulated grinder's element set (``make_chain_truth(seed)``) gives feature points on an N³ grid (what ``volcomp
featurepoints`` writes); ``fit_field`` (what ``volcomp train`` runs) fits the paper's 3-10-15-25-15-10-3 network
with LM, the iterate best on 5,000 off-grid selection points kept. MODEL residual (surrogate − the element-set
field the feature points came from), largest |component|: on the feature points (the paper's 0.0267 μm) and on
10,000 random off-grid points (goal 0.1 μm). Configurations: the measured best (21³ grid, ``--physics
first-order``, 40 LM iterations) beside the paper's (11³ grid, no physics split, 300 iterations).
"""
from __future__ import annotations

import time

from errormap.featurepoints import make_feature_points
from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.seeds import spawn_rngs
from errormap.chain_truth import make_chain_truth, random_axes
from training.trainers import TrainSettings, fit_field

PAPER_UM = 0.0267
OFF_GRID_GOAL_UM = 0.1
CONFIGS = {"best": {"grid": 21, "physics": "first-order", "max_iter": 40},
           "paper": {"grid": 11, "physics": "none", "max_iter": 300}}
QUICK = {"best": {"grid": 11, "physics": "first-order", "max_iter": 5},
         "paper": {"grid": 11, "physics": "none", "max_iter": 5}}

TITLE = "Surrogate network on feature points: on the grid and off it"
DATA = ("simulated grinder (`make_chain_truth` seed 0), feature points of its element set; 10,000 random off-grid "
        "validation points; best: 21³ grid, `--physics first-order`, 40 LM iterations; paper: 11³, 300 iterations "
        "(quick: 11³ and 5 iterations each — smoke figures only)")


def fit_one(machine, field, cfg: dict, seed: int, n_val: int):
    fp = make_feature_points(machine, field, n=cfg["grid"])
    r_val, r_sel = spawn_rngs(seed, 2)
    va, sa = random_axes(machine, n_val, r_val), random_axes(machine, 5_000, r_sel)
    settings = TrainSettings(max_iter=cfg["max_iter"], seed=seed, threads=1, physics=cfg["physics"])
    c0 = time.process_time()
    r = fit_field(fp, settings, validation=(va, field.predict(va)), selection=(sa, field.predict(sa)), track=False,
                  quiet=True)
    return r.metrics, time.process_time() - c0


def run(quick: bool, seed: int) -> dict:
    m = load_machine()
    field = ChainField(m, make_chain_truth(m, seed).elements)
    res = {k: fit_one(m, field, cfg, seed, 2_000 if quick else 10_000) for k, cfg in (QUICK if quick else CONFIGS).items()}
    (best, cpu), (paper, cpu_p) = res["best"], res["paper"]
    fig = lambda what, v, anchor, av: {"what": what, "value": v, "unit": "μm", "residual": "model",  # noqa: E731
                                       "anchor": anchor, "anchor_value": av}
    return {"figures": [
        fig("best: max on the feature points", best["train_max_um"], "paper's figure", PAPER_UM),
        fig("best: max on random off-grid points", best["val_max_um"], "goal", OFF_GRID_GOAL_UM),
        fig("paper's configuration: max on the feature points", paper["train_max_um"], "paper's figure", PAPER_UM),
        fig("paper's configuration: max on random off-grid points", paper["val_max_um"], "best configuration",
            best["val_max_um"]),
        {"what": "best: CPU of the fit", "value": round(cpu, 1), "unit": "s", "residual": "none",
         "anchor": "paper's configuration", "anchor_value": round(cpu_p, 1)},
    ], "notes": []}
