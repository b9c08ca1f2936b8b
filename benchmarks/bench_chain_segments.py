"""Segment splitting on a machine-tool chain: the TRUE residual at the vertices and along the moves of a
compensated program, per ``--max-segment-mm`` (docs/decisions/020-benchmark-notebook.md, "Scale-out and segment splitting on
machine-tool chains").

Machine: built-in ``mill-xyz``; truth: a seeded element set (±10 μm / μrad, 1 σ; seed 101); model: the
truth plus 0.3 μm / μrad noise per station and constant (seed 102; tests/test_mt_compensate.py's
estimate), and the truth itself (what splitting alone changes). Programs: ``tests/data/mill_pocket.nc``
(in machine coordinates) and one 400 mm G1 move (X 100 → 500) after a 20 mm plunge. Each run is
``volcomp compensate --method exact --work-offsets machine --truth`` (the library call of the command).
Residual kind: TRUE (the truth's tool point minus the programmed one), μm: at the written vertices, and
along the linear moves at 8 points per written segment (axis-space interpolation, as the controller runs it).

    PYTHONPATH=. python benchmarks/bench_chain_segments.py
"""
from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from compensation.app.workflows.compensate import CompensateSettings, compensate_files
from compensation.nc_state import MACHINE, read_work_offsets
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet

ROOT = Path(__file__).resolve().parents[1]
POCKET = ROOT / "tests" / "data" / "mill_pocket.nc"
LONG = ("(ONE LONG MOVE)\nG21 G90 G17\nG0 X100. Y200. Z-300.\nG1 Z-320. F300.\nG1 X500. Y220. Z-330. F1500.\n"
        "G0 Z-300.\nM30\n")
NOISE_UM = 0.3
SETTINGS = ("auto", None, 10.0, 2.0, 1.0)


def models(mt, d: Path):
    truth = ChainElementSet.random(mt, 101, 10.0, 11)
    rng = np.random.default_rng(102)
    est = ChainElementSet(mt, truth.stations,
                          {k: v + rng.normal(0.0, NOISE_UM, v.shape) for k, v in truth.functions.items()},
                          {k: v + rng.normal(0.0, NOISE_UM) for k, v in truth.constants.items()})
    return truth.save(d / "truth.json"), est.save(d / "est.json")


def run(prog, mt, model, truth, seg, out: Path) -> dict:
    s = CompensateSettings("exact", str(model), out, truth=str(truth), max_segment_mm=seg,
                      work_offsets=read_work_offsets(MACHINE))
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert not compensate_files([prog], mt, s).refused
    return json.loads((out / "compensate_summary.json").read_text())["files"][0]


def main() -> int:
    mt = load_machine("mill-xyz")
    print("| program | model | --max-segment-mm | vertices | TRUE at vertices max / rms | TRUE along the moves "
          "max / rms | uncompensated along the moves max |")
    print("|---|---|---|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        truth, est = models(mt, d)
        long = d / "long.nc"
        long.write_text(LONG)
        for prog, name in ((POCKET, "mill_pocket.nc"), (long, "one 400 mm move")):
            for model, mname in ((truth, "truth"), (est, "estimate")):
                for k, seg in enumerate(SETTINGS):
                    e = run(prog, mt, model, truth, seg, d / f"o{name[:4]}{mname}{k}")
                    t, p, u = e["true"], e["true_path"], e["true_path_uncompensated"]
                    print(f"| {name} | {mname} | {'none' if seg is None else seg} | {e['points']} | "
                          f"{t['max_um']:.3g} / {t['rms_um']:.3g} | {p['max_um']:.3g} / {p['rms_um']:.3g} | "
                          f"{u['max_um']:.3g} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
