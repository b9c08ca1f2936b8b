"""Drilling canned cycles compensated on ``mill-xyz`` (docs/decisions/020-benchmark-notebook.md, "Programs as shops write them:
canned cycles"): TRUE residual at the hole bottoms before/after, the tilt left along each hole by kept
cycles, and the TRUE residual of the expanded moves.

Machine: built-in ``mill-xyz``; truth: seeded element set (±10 μm / μrad 1 σ, seed 101); model: the truth
plus 0.3 μm / μrad noise per station and constant (seed 102), as benchmarks/suite/work_offsets.py.
Program: ``tests/data/cycles/drill_linuxcnc.ngc`` (G81 ×3 with modal repeats, G82, G83, G73, G85, G89
under G55 = (200, 100, −150) mm from ``tests/data/controller/offsets.csv``). Residual kind: TRUE (the truth
machine's tool point minus the programmed point), μm; tilt: |XY correction at R − at the bottom| (model).

    PYTHONPATH=. python benchmarks/bench_cycles.py
"""
from __future__ import annotations

import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np

from compensation.app.cli import main
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = ROOT / "tests" / "data" / "cycles" / "drill_linuxcnc.ngc"
OFFSETS = ROOT / "tests" / "data" / "controller" / "offsets.csv"
NOISE_UM = 0.3


def compensate(d: Path, model: Path, truth: Path, *extra) -> dict:
    out = d / ("o" + "".join(extra).replace("-", ""))
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["compensate", str(PROGRAM), "--machine", "mill-xyz", "--model", str(model), "--method", "exact",
                   "--truth", str(truth), "--work-offsets", str(OFFSETS), "--out", str(out), "--force", *extra])
    assert rc == 0, rc
    return json.loads((out / "compensate_summary.json").read_text())["files"][0]


def main_() -> None:
    mt = load_machine("mill-xyz")
    truth = ChainElementSet.random(mt, 101, 10.0, 11)
    rng = np.random.default_rng(102)
    est = ChainElementSet(mt, truth.stations,
                          {k: v + rng.normal(0.0, NOISE_UM, v.shape) for k, v in truth.functions.items()},
                          {k: v + rng.normal(0.0, NOISE_UM) for k, v in truth.constants.items()})
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        tf, ef = truth.save(d / "truth.json"), est.save(d / "model.json")
        for name, model in (("truth as model", tf), ("estimate (0.3 um noise)", ef)):
            keep = compensate(d, model, tf)
            c = keep["cycles"]
            print(f"{name}: kept, {c['holes']} holes: TRUE bottom max/rms uncompensated "
                  f"{c['true_bottom_uncompensated']['max_um']:.2f} / {c['true_bottom_uncompensated']['rms_um']:.2f} um, "
                  f"compensated {c['true_bottom']['max_um']:.3g} / {c['true_bottom']['rms_um']:.3g} um; tilt per line "
                  + ", ".join(f"{k}: {v:.1f}" for k, v in c["tilt_um"].items()) + " um")
            ex = compensate(d, model, tf, "--expand-cycles", "--dialect", "linuxcnc")
            print(f"{name}: expanded, {ex['points']} compensated vertices: TRUE max/rms uncompensated "
                  f"{ex['true_uncompensated']['max_um']:.2f} / {ex['true_uncompensated']['rms_um']:.2f} um, "
                  f"compensated {ex['true']['max_um']:.3g} / {ex['true']['rms_um']:.3g} um")


if __name__ == "__main__":
    main_()
