"""Why the controller's tables matter: TRUE residual of a compensated program when its work offset and
tool length are ignored vs used.

Machine: built-in ``mill-xyz``; truth: a seeded element set (±10 μm / μrad, 1 σ; seed 101); model: the
truth plus 0.3 μm / μrad noise per station and constant (seed 102; the estimate tests/test_mt_compensate.py
uses). Program: ``tests/data/controller/g55_tool_linuxcnc.ngc`` (G55, G43 H1, a pocket with an arc),
offset G55 = (200, 100, −150) mm, tool 1 of length 0 and 150 mm (or no G43: the file's 120 mm tool).

"ignored": the program's axes taken as machine axes with the file's tool (what the reader did before:
G54/G55 as machine zero), then run by the controller with the real offset and tool; "used":
``compensate --work-offsets --tool-table``. Residual kind: TRUE (the truth machine's tool point at every
vertex minus the programmed point), μm.

    python -m benchmarks.run work_offsets
"""
from __future__ import annotations

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

ROOT = Path(__file__).resolve().parents[2]
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


def run_program(prog, mt, truth, est, tools):
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


TITLE = "Work offsets and tool lengths: compensated program with the controller's tables used vs ignored"
DATA = ("built-in `mill-xyz`, seeded truth with angular errors (every element ±10 μm / μrad 1 σ: pitch, yaw, roll "
        "and squareness; seed 101), model = truth + 0.3 μm / μrad noise (seed 102); "
        "`tests/data/controller/g55_tool_linuxcnc.ngc` (G55, G43 H1), G55 = (200, 100, −150) mm, tool 1 of 0 or 150 mm")
TOOL_LENGTHS_MM = (0.0, 150.0)
"""Tool 1's lengths shown: a gauge-line tool and a long one; ignoring the table runs either at the machine
file's 120 mm tool, an Abbe arm 120 mm or 30 mm off."""


def run(quick: bool, seed: int) -> dict:
    """One program, both tool lengths: the same size quick and full (it takes a second)."""
    mt = load_machine("mill-xyz")
    truth, est = models(mt)
    figs = []
    fig = lambda what, v, anchor, av: {"what": what, "value": v, "unit": "μm", "residual": "true",  # noqa: E731
                                       "anchor": anchor, "anchor_value": av}
    with tempfile.TemporaryDirectory() as d:
        for length in TOOL_LENGTHS_MM:
            t = Path(d) / f"tools-{length:g}.csv"
            t.write_text(f"tool,length_mm\n1,{length:g}\n", encoding="utf-8")
            n, before, ignored, tool_ignored, used = run_program(PROGRAM, mt, truth, est, read_tool_table(t))
            figs += [fig(f"tool {length:g} mm: tables used (`--work-offsets --tool-table`), max over {n} vertices",
                         used[0], "tables ignored (G55 as machine zero, the file's 120 mm tool)", ignored[0]),
                     fig(f"tool {length:g} mm: offset used, tool length ignored (the file's 120 mm), max",
                         tool_ignored[0], "uncompensated", before[0])]
    return {"figures": figs, "notes": []}
