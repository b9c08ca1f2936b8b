"""Why the controller's tables matter: TRUE residual of a compensated program when its work offset and
tool length are ignored vs used (BENCHMARKS.md, "Programs as shops write them").

Machine: built-in ``mill-xyz``; truth: a seeded element set (±10 μm / μrad, 1 σ; seed 101); model: the
truth plus 0.3 μm / μrad noise per station and constant (seed 102; the estimate tests/test_mt_compensate.py
uses). Program: ``tests/data/controller/g55_tool_linuxcnc.ngc`` (G55, G43 H1, a pocket with an arc),
offset G55 = (200, 100, −150) mm, tool 1 of length 0 or 150 mm (or no G43: the file's 120 mm tool).

"ignored": the program's axes taken as machine axes with the file's tool (what the reader did before:
G54/G55 as machine zero), then run by the controller with the real offset and tool; "used":
``compensate --work-offsets --tool-table``. Residual kind: TRUE (the truth machine's tool point at every
vertex minus the programmed point), μm.

    PYTHONPATH=. python benchmarks/bench_work_offsets.py
"""
from __future__ import annotations

import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from compensation.app.workflows.compensate import CompensateSettings, solve_paths
from compensation.app.workflows.compensate_paths import read_tool_path
from compensation.nc_state import machine_with_tool, read_tool_table, read_work_offsets
from compensation.solvers import solve
from compensation.solvers.chain_exact import nominal_and_jacobian
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = ROOT / "tests" / "data" / "controller" / "g55_tool_linuxcnc.ngc"
OFFSETS = ROOT / "tests" / "data" / "controller" / "offsets.var"
NOISE_UM = 0.3


def models(mt):
    truth = ChainElementSet.random(mt, 101, 10.0, 11)
    rng = np.random.default_rng(102)
    est = ChainElementSet(mt, truth.stations,
                          {k: v + rng.normal(0.0, NOISE_UM, v.shape) for k, v in truth.functions.items()},
                          {k: v + rng.normal(0.0, NOISE_UM) for k, v in truth.constants.items()})
    return truth, est


def stats(e):
    n = np.linalg.norm(e, axis=1)
    return float(n.max()), float(np.sqrt(np.mean(n ** 2)))


def run(prog, mt, truth, est, tools):
    s = CompensateSettings("exact", "", Path("."), work_offsets=read_work_offsets(OFFSETS), tool_table=tools)
    f_est, f_true = ChainField(mt, est), ChainField(mt, truth)
    tp = read_tool_path(prog, mt, s, f_est)
    _, _, used, before = solve_paths([tp], f_est, f_true, mt, s)[0]
    prog_axes = tp.axes - tp.shift
    t0, _ = nominal_and_jacobian(mt, prog_axes)
    old = solve("exact", f_est, t0, mt, target_axes=prog_axes, progress=False)
    drive = old.axes + tp.shift
    t1, _ = nominal_and_jacobian(mt, tp.axes)  # offset used, the tool taken as the file's
    drive_tool = solve("exact", f_est, t1, mt, target_axes=tp.axes, progress=False).axes
    ignored, tool_ignored = np.empty_like(used), np.empty_like(used)
    for L in np.unique(tp.tool_mm):
        i = tp.tool_mm == L if np.isfinite(L) else ~np.isfinite(tp.tool_mm)
        m = machine_with_tool(mt, L) if np.isfinite(L) else mt
        for out, q in ((ignored, drive), (tool_ignored, drive_tool)):
            out[i] = (m.nominal(q[i]) - m.nominal(tp.axes[i])) * 1e3 + ChainField(m, truth).predict(q[i])
    return len(tp.axes), stats(before), stats(ignored), stats(tool_ignored), stats(used)


def main() -> int:
    mt = load_machine("mill-xyz")
    truth, est = models(mt)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        plain = Path(d) / "no_g43.ngc"
        plain.write_text(re.sub(r"G43 H1 |G49\n", "", PROGRAM.read_text()), encoding="latin-1")
        rows.append(("G55, no G43 (file's 120 mm tool)", *run(plain, mt, truth, est, None)))
        for L in (0.0, 150.0):
            t = Path(d) / f"tools_{L:g}.csv"
            t.write_text(f"tool,length_mm\n1,{L}\n", encoding="utf-8")
            rows.append((f"G55 + G43 H1, tool {L:g} mm", *run(PROGRAM, mt, truth, est, read_tool_table(t))))
    print("| program | vertices | uncompensated | tables ignored | offset used, tool ignored | tables used |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, n, *r in rows:
        print(f"| {name} | {n} | " + " | ".join(f"{a:.2f} / {b:.2f}" for a, b in r) + " |")
    print("(TRUE residual max / rms, μm)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
