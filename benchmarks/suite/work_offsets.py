"""Why the controller's tables matter: TRUE residual of a compensated program when its work offset and
tool length are ignored vs used.

Machine: built-in ``mill-xyz``; truth: a seeded element set (±10 μm / μrad, 1 σ; seed 101); model: the
truth plus 0.3 μm / μrad noise per station and constant (seed 102; the estimate tests/test_chain_compensate.py
uses). Program: ``tests/data/controller/g55_tool_linuxcnc.ngc`` (G55, G43 H1, a pocket with an arc),
offset G55 = (200, 100, −150) mm, tool 1 of length 0 and 150 mm (or no G43: the file's 120 mm tool).

"ignored": the program's axes taken as machine axes with the file's tool (what the reader did before:
G54/G55 as machine zero), then run by the controller with the real offset and tool; "used":
``compensate --work-offsets --tool-table``. Residual kind: TRUE (the truth machine's tool point at every
vertex minus the programmed point), μm.

Canned cycles (:func:`cycle_figures`): ``tests/data/cycles/drill_linuxcnc.ngc`` (G81 ×3 with modal repeats, G82,
G83, G73, G85, G89 under G55 from ``tests/data/controller/offsets.csv``) compensated with the same model and
``--truth``: the TRUE residual at the hole bottoms with the cycles kept, and at every vertex with
``--expand-cycles --dialect linuxcnc``; the tilt along each kept hole in the notes (|XY correction at R − at the
bottom|, model).

No assumed zero (:func:`no_assumed_zero`): every program of ``tests/data/gcode_corpus`` the corpus expects
compensated (``c*``, default grinder) and of ``tests/data/dialects`` plus ``tests/data/mill_pocket.nc``
(``mill-xyz``) read as ``compensate`` reads it before solving, with no work-offset table and with
``--work-offsets machine``: read or refused naming a line (a program that selects no work system is refused
without a table, not read at machine zero).

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
CYCLES = ROOT / "tests" / "data" / "cycles" / "drill_linuxcnc.ngc"
CYCLE_OFFSETS = ROOT / "tests" / "data" / "controller" / "offsets.csv"
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


TITLE = ("Work offsets and tool lengths: compensated program with the controller's tables used vs ignored; canned "
         "cycles kept or expanded; programs read with no table")
DATA = ("built-in `mill-xyz`, seeded truth with angular errors (every element ±10 μm / μrad 1 σ: pitch, yaw, roll "
        "and squareness; seed 101), model = truth + 0.3 μm / μrad noise (seed 102); "
        "`tests/data/controller/g55_tool_linuxcnc.ngc` (G55, G43 H1), G55 = (200, 100, −150) mm, tool 1 of 0 or 150 mm; "
        "`tests/data/cycles/drill_linuxcnc.ngc` (8 drilled holes, G55); the repository's corpus, dialect and mill "
        "programs (`tests/data/gcode_corpus/c*`, `tests/data/dialects`, `tests/data/mill_pocket.nc`)")
TOOL_LENGTHS_MM = (0.0, 150.0)
"""Tool 1's lengths shown: a gauge-line tool and a long one; ignoring the table runs either at the machine
file's 120 mm tool, an Abbe arm 120 mm or 30 mm off."""


def _compensate_cycles(d: Path, model: Path, truth: Path, *extra) -> dict:
    """The ``compensate_summary.json`` file entry of :data:`CYCLES` compensated with ``model`` and ``--truth``."""
    import contextlib
    import io
    import json
    from compensation.app.cli import main
    out = d / ("o" + "".join(extra).replace("-", ""))
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        rc = main(["compensate", str(CYCLES), "--machine", "mill-xyz", "--model", str(model), "--method", "exact",
                   "--truth", str(truth), "--work-offsets", str(CYCLE_OFFSETS), "--out", str(out), "--force", *extra])
    if rc != 0:
        raise RuntimeError(f"compensate {CYCLES.name} {' '.join(extra)} exited {rc}")
    return json.loads((out / "compensate_summary.json").read_text())["files"][0]


def cycle_figures(truth, est) -> tuple:
    """``(figures, notes)``: :data:`CYCLES` compensated with the estimate, cycles kept and expanded (TRUE, μm)."""
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        tf, ef = truth.save(d / "truth.json"), est.save(d / "model.json")
        c = _compensate_cycles(d, ef, tf)["cycles"]
        ex = _compensate_cycles(d, ef, tf, "--expand-cycles", "--dialect", "linuxcnc")
    figs = [{"what": f"canned cycles kept: TRUE at the {c['holes']} hole bottoms, max", "value":
             c["true_bottom"]["max_um"], "unit": "μm", "residual": "true", "anchor": "uncompensated",
             "anchor_value": c["true_bottom_uncompensated"]["max_um"]},
            {"what": f"canned cycles expanded (`--expand-cycles`): TRUE at {ex['points']} vertices, max",
             "value": ex["true"]["max_um"], "unit": "μm", "residual": "true", "anchor": "uncompensated",
             "anchor_value": ex["true_uncompensated"]["max_um"]}]
    notes = ["Kept cycles: the tilt along each hole (|XY correction at R − at the bottom|, model), per line: "
             + ", ".join(f"{k}: {v:.1f} μm" for k, v in c["tilt_um"].items()) + "."]
    return figs, notes


def no_assumed_zero() -> dict:
    """``{"no table" | "--work-offsets machine": (programs, read, refused)}`` (module docstring)."""
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.nc_state import MACHINE
    from errormap.io import InputError
    data = ROOT / "tests" / "data"
    grinder, mill = load_machine(), load_machine("mill-xyz")
    corpus = sorted(p for p in (data / "gcode_corpus").iterdir() if p.name.startswith("c"))
    mills = sorted((data / "dialects").iterdir()) + [data / "mill_pocket.nc"]
    out = {}
    for name, frame in (("no table", None), ("--work-offsets machine", read_work_offsets(MACHINE))):
        read = refused = 0
        for p in corpus + mills:
            try:
                text = p.read_text("latin-1")
                opts = {"block_delete": v for v in ("off", "on") if f"block-delete={v}" in text}
                read_tool_path(p, grinder if p in corpus else mill,
                               CompensateSettings("exact", "", Path("."), work_offsets=frame, **opts))
                read += 1
            except InputError:
                refused += 1
        out[name] = (len(corpus) + len(mills), read, refused)
    return out


def run(quick: bool, seed: int) -> dict:
    """One program, both tool lengths; the drilling cycles; the repository's programs with and without a table:
    the same size quick and full (a few seconds)."""
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
    cfigs, notes = cycle_figures(truth, est)
    counts = no_assumed_zero()
    n, read0, refused0 = counts["no table"]
    _, read1, _ = counts["--work-offsets machine"]
    figs += cfigs + [{"what": f"repository programs read with no work-offset table (of {n}; the rest refused)",
                      "value": read0, "unit": "", "residual": "none", "anchor": "read with `--work-offsets machine`", "anchor_value": read1}]
    notes.append(f"No table: {read0} of {n} repository programs read, {refused0} refused; with `--work-offsets "
                 f"machine`: {read1} read.")
    return {"figures": figs, "notes": notes}
