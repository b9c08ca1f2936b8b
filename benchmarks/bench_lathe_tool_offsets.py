"""Benchmark (the lathe's tool offsets): why a lathe tool's X and Z offsets must go through the chain.

A LinuxCNC turning program with two tools (tool table ``T1 X-40 Z+120``, ``T2 X+25 Z+80``; ``G43`` after each
tool change; G54 at Z 300; tests/test_lathe_tool_offsets.py's program) on ``lathe-xzc``, per seed a truth
``ChainElementSet.random(lathe, seed, 10.0, 11)`` (±10 μm / μrad). TRUE residual: the truth machine with its
tool point at the tool's offsets, driven to the written axes, radial and axial deviation from the programmed
surface of revolution, mean over one spindle turn (max over the turning points, μm), for

* ``uncompensated``: the program as written;
* ``ignored``: compensated with the model's chain at the machine file's own tool point (the offsets shift the
  axes as the controller shifts them, but the Abbe arm of the offset is left out);
* ``used``: compensated at each tool's offsets (``compensate --tool-table``);

with the model the truth itself (nothing else differs) and a noisy model (the truth's element values plus
seeded 0.3 μm / μrad noise, tests/test_turning.py's estimate) — the plain baseline beside the learned one.

    nice -n 10 python benchmarks/bench_lathe_tool_offsets.py --seeds 0 1 2 3 4
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from test_lathe_tool_offsets import PROGRAM, TBL, WORK_Z_MM  # noqa: E402  (the test's program and tables)

NOISE = 0.3


def _noisy(truth, lathe, seed):
    from errormap.chain_elements import ChainElementSet
    rng = np.random.default_rng(1000 + seed)
    f = {k: v + rng.normal(0.0, NOISE, v.shape) for k, v in truth.functions.items()}
    for k, v in truth.functions.items():  # a closed profile (C at 360° = at 0°) stays closed
        if abs(v[-1] - v[0]) < 1e-12:
            f[k][-1] = f[k][0]
    return ChainElementSet(lathe, truth.stations, f, {k: v + rng.normal(0.0, NOISE) for k, v in truth.constants.items()})


def one(seed, d: Path):
    from compensation.app.workflows.compensate import CompensateSettings, solve_paths
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.nc_state import machine_with_lathe_tool, read_tool_table, read_work_offsets
    from compensation.turning import solve_turning, surface_residual_um
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    lathe = load_machine("lathe-xzc")
    (d / "p.ngc").write_text(PROGRAM)
    (d / "t.tbl").write_text(TBL)
    (d / "o.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{WORK_Z_MM}\n")
    s = CompensateSettings("exact", "", d, work_offsets=read_work_offsets(d / "o.csv"),
                           tool_table=read_tool_table(d / "t.tbl"), dialect="linuxcnc")
    truth_els = ChainElementSet.random(lathe, seed, 10.0, 11)
    truth = ChainField(lathe, truth_els)
    out = {}
    for model_name, els in (("truth", truth_els), ("noisy", _noisy(truth_els, lathe, seed))):
        model = ChainField(lathe, els)
        tp = read_tool_path(d / "p.ngc", lathe, s, model)
        res = solve_paths([tp], model, model, lathe, s)[0][0]
        ignored = solve_turning(model, lathe, tp.axes, ball_um=250.0)[0]
        for name, q in (("uncompensated", tp.axes), ("ignored", ignored), ("used", res.axes)):
            worst = 0.0
            for x, z in {tuple(r) for r in tp.tool_xz}:
                idx = np.flatnonzero((tp.tool_xz == (x, z)).all(axis=1))
                mt = machine_with_lathe_tool(lathe, x, z)
                tr = ChainField(mt, truth.elements)
                worst = max(worst, float(np.abs(surface_residual_um(tr, mt, q[idx], tp.axes[idx])[0]).max()))
            out[(model_name, name)] = worst
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    args = ap.parse_args(argv)
    rows = []
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            r = one(seed, Path(tmp))
        rows.append(r)
        print(f"seed {seed}: " + ", ".join(f"{m}/{n} {v:.3g} um" for (m, n), v in r.items()), flush=True)
    for key in rows[0]:
        v = np.array([r[key] for r in rows])
        print(f"{key[0]:>5} model, {key[1]:>13}: TRUE max over the turn, mean {v.mean():.3g} um, max {v.max():.3g} um")
    return 0


if __name__ == "__main__":
    sys.exit(main())
