"""The lathe's identification on the user's path.

Per seed, through the command line: ``simulate --machine M --seed S`` → ``sweeps --machine M --seed S
--seed-noise S`` (2 μm tracker noise; the noise seed varied with the truth seed: with one noise seed the
identification error is the same on every truth, it is noise, not the truth) → ``identify`` →
``compensate --method exact --truth`` of a turning program (G18 arc, C moves). TRUE residual (the hidden
truth driven with the compensated axes) beside the uncompensated program. The mill's identified model gives
the same volume-grid figure beside it.

Also, per slot of the shipped lathe file, the identified minus the noise-free identification (the truth in
the identification's gauge) in units of the identification's standard error (z-score RMS) and the
volume-grid field error of the identified model.

Tool offsets (why a lathe tool's X and Z offsets must go through the chain): a LinuxCNC turning program with
two tools (tool table ``T1 X-40 Z+120``, ``T2 X+25 Z+80``; ``G43`` after each tool change; G54 at Z 300;
tests/test_lathe_tool_offsets.py's program) on ``lathe-xzc``, per seed a truth ``ChainElementSet.random(lathe,
seed, 10.0, 11)`` (±10 μm / μrad). TRUE residual: the truth machine with its tool point at the tool's
offsets, driven to the written axes, radial and axial deviation from the programmed surface of revolution,
mean over one spindle turn (max over the turning points, μm), for the program as written (uncompensated),
compensated at the machine file's own tool point (offsets ignored in the chain: the axes shift as the
controller shifts them, the Abbe arm of the offset left out) and at each tool's offsets (``--tool-table``);
the model the truth itself and a noisy model (the truth's values plus seeded 0.3 μm / μrad noise).

Contour cycles (Fanuc G71/G70 whose contour blocks are in the program, compensation/nc_contour.py): the stepped
shaft :data:`STEPS` on ``lathe-xzc``, per seed a truth ``ChainElementSet.random(lathe, seed, 10.0, 11)`` that is
also the model (``--method exact``), compensated on the user's path twice: by default (the contour compensated in
place: accepted while the type I contour stays monotonic, else refused naming ``--expand-cycles``) and with
``--expand-cycles`` (the G71 and its contour written as they are, the G70 written as its compensated moves). TRUE
residual judged here, not by the compensator: the true machine driven to the written axes of each G70 move, the tip
(mean over one turn) beside the programmed contour point that move reaches (``gcode_checks.lathe_points_reached``,
the corpus count's lathe check); beside it the program as written (uncompensated) at the same points.

Threading (Fanuc G32, compensation/nc_thread.py; LinuxCNC G76 with ``--expand-cycles``, compensation/nc_g76.py):
:data:`THREAD` and :data:`THREAD_G76` on ``lathe-xzc``, per seed a truth ``ChainElementSet.random(lathe, seed, 10.0,
11)`` that is also the model, compensated by default. Judged here: the TRUE lead of every written G32 (G33) piece
(:func:`true_leads`: written F' × true travel / commanded travel along the lead axis, the tip mean over one turn)
against the programmed F (P), the TRUE position at the programmed points
(``lathe_points_reached``) and the spread of the passes' TRUE start Z less their programmed start Z (the thread's
phase between passes; a G76's passes start shifted by its compound slide); beside each, the program as written
(uncompensated; a G76 as its expansion) on the same truth.

Grooving cycles (Fanuc G74/G75, compensation/nc_groove.py): tests/test_lathe_grooving.py's programs on ``lathe-xzc``,
per seed a truth ``ChainElementSet.random(lathe, seed, 10.0, 11)`` that is also the model: a G75 groove series (5
columns of pecks) by default (kept: refused naming ``--expand-cycles``, its columns cannot be written compensated)
and with ``--expand-cycles`` (written as the control's moves); TRUE residual judged here at the manual's moves rebuilt
by the test's ``hand_moves`` (not the expander's output), the true machine at the written axes (mean over one turn),
beside the program as written at the same points; and a one-plunge G75 kept (default: accepted where its error across
is within ``compensation.nc_groove.ACROSS_UM``), TRUE at its bottom with the control's across coordinate.

    python -m benchmarks.run lathe           # seeds 0–2 (user path), 0–4 (tool offsets), 0–19 (contour cycles,
                                             # threading, grooving)
"""
from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from .gcode_checks import lathe_points_reached

HERE = Path(__file__).resolve().parent
NOISE = 0.3


PROGRAM = ("%\nO1000 (LATHE X Z C)\nG18 G90 G21\nT1 M6\nG0 X80. Z350. C0.\n"
           "G1 X60. Z320. C0. F200.\nG1 Z260. C90.\nG2 X80. Z240. I20. K0.\nG1 X120. C180.\n"
           "(FINISH)\nG1 Z180. C270.\nM30\n%\n")


def user_path(machine: str, seed: int, d: Path) -> dict:
    from compensation.app.cli import main
    base = ["--machine", machine, "--seed", str(seed)]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["simulate", *base, "--out", str(d / "sim")]) == 0
        assert main(["sweeps", *base, "--seed-noise", str(seed), "--out", str(d / "sw.csv")]) == 0
        assert main(["identify", str(d / "sw.csv"), "--machine", machine, "--out", str(d / "E.json")]) == 0
        (d / "p.nc").write_text(PROGRAM)
        assert main(["compensate", str(d / "p.nc"), "--machine", machine, "--model", str(d / "E.json"), "--method",
                     "exact", "--truth", str(d / "sim" / "truth.json"), "--out", str(d / "o"),
                     "--work-offsets", "machine"]) == 0  # PROGRAM is in machine coordinates
    e = json.loads((d / "o" / "compensate_summary.json").read_text())["files"][0]
    return {"true_max": e["true"]["max_um"], "true_rms": e["true"]["rms_um"],
            "unc_max": e["true_uncompensated"]["max_um"], "unc_rms": e["true_uncompensated"]["rms_um"],
            "model_max": e["model_max_um"], "failures": e["failures"]}


STEPS = ("G21 G18 G40 G99\nT0101\nG96 S180 M03\nG00 X110. Z3.\nG71 U1. R0.5\nG71 P100 Q200 U0.4 W0.1 F0.25\n"
         "N100 G00 X20.\nG01 Z-30. F0.15\nX40.\nZ-60.\nX60.\nZ-80.\nN200 X80.\nG70 P100 Q200\nG00 X150. Z50.\n"
         "M05\nM30\n")
"""A stepped shaft (three cylinders, three faces; Fanuc two-block G71, type I: monotonic in X and Z as programmed)."""
G70_LINE = STEPS.splitlines().index("G70 P100 Q200")
CONTOUR_LINES = (STEPS.splitlines().index("N100 G00 X20."), STEPS.splitlines().index("N200 X80."))
"""0-based first and last line of the contour blocks N100-N200."""
PART_Z_MM = 200.0
"""The G54 work offset's Z (the part's face 200 mm along the bed, inside Z's stroke)."""
TOL_POINT_UM = 1.0
"""A programmed contour point is reached by the first later written move whose TRUE tip is this close to it."""


def _compensate_steps(d: Path, extra=(), out: str | None = None, dialect: str = "fanuc") -> tuple[int, str, Path]:
    """``volcomp compensate`` of ``d/p.nc`` (STEPS, THREAD, the grooving programs; ``dialect`` "fanuc" with
    ``--lathe-x diameter``, or "linuxcnc") with the truth in ``d`` as model and truth into ``d/out`` (``out-expand``
    with ``extra``; ``out`` names another): (rc, last stderr line, output)."""
    from compensation.app.cli import main
    err, out = io.StringIO(), out or ("out-expand" if extra else "out")
    x_words = ["--lathe-x", "diameter"] if dialect != "linuxcnc" else []
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(["compensate", str(d / "p.nc"), "--machine", "lathe-xzc", "--model", str(d / "truth.json"),
                   "--truth", str(d / "truth.json"), "--method", "exact", "--dialect", dialect, *x_words,
                   "--out", str(d / out), "--work-offsets", str(d / "off.csv"), "--tool-table",
                   str(d / "tools.csv"), *extra])
    lines = err.getvalue().strip().splitlines()
    return rc, lines[-1] if lines else "", d / out / "p.nc"


def _seeded(seed: int, d: Path, program: str) -> tuple:
    """``(lathe, truth)``: ``lathe-xzc`` and its truth ``ChainElementSet.random(lathe, seed, 10.0, 11)`` written to
    ``d/truth.json`` with the G54 offset (Z :data:`PART_Z_MM`), the tool table and ``program`` as ``d/p.nc``."""
    from errormap.chain_elements import ChainElementSet
    from errormap.machine import load_machine
    lathe = load_machine("lathe-xzc")
    els = ChainElementSet.random(lathe, seed, 10.0, 11)
    els.save(d / "truth.json")
    (d / "off.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{PART_Z_MM}\n")
    (d / "tools.csv").write_text("tool,length_mm,radius_mm\n1,0,0.8\n")
    (d / "p.nc").write_text(program)
    return lathe, els


def contour_cycle(seed: int, d: Path) -> dict:
    """One truth seed: the default's outcome, and with ``--expand-cycles`` the TRUE max (μm) at the contour points of
    the G70's written moves beside the program as written at the same points."""
    from compensation.turning import parse_lathe_program
    from errormap.chain_field import ChainField
    lathe, els = _seeded(seed, d, STEPS)
    rc, err, _ = _compensate_steps(d)
    row = {"default": "accepted" if rc == 0 else "expand" if "use --expand-cycles" in err else err}
    rc, err, written = _compensate_steps(d, ("--expand-cycles",))
    row["expanded"] = rc == 0
    if rc != 0:
        return row | {"expand_error": err}
    out = [ln for ln in written.read_text().splitlines() if not ln.startswith("(volcomp:")]
    src = STEPS.splitlines()
    tail = len(src) - G70_LINE - 1
    assert out[:G70_LINE] == src[:G70_LINE] and out[-tail:] == src[-tail:], f"seed {seed}: lines besides G70 changed"
    (d / "bare.nc").write_text("\n".join(out) + "\n")
    read = lambda f: parse_lathe_program(f, lathe, "keep", None, "fanuc", "diameter")[0].moves  # noqa: E731
    contour = [m for m in read(d / "p.nc") if m.compensate and CONTOUR_LINES[0] <= m.index <= CONTOUR_LINES[1]]
    finish = [m for m in read(d / "bare.nc") if m.compensate and G70_LINE <= m.index < len(out) - tail]
    field = ChainField(lathe, els)
    errs, missed = lathe_points_reached(field, lathe, contour, finish, (0.0, PART_Z_MM), TOL_POINT_UM)
    assert missed is None, f"seed {seed}: STEPS line {missed} reached by no written move of the expanded G70"
    as_written, _ = lathe_points_reached(field, lathe, contour, contour, (0.0, PART_Z_MM), np.inf)  # each its own
    return row | {"true_max": max(errs), "unc_max": max(as_written)}


def over_seeds(one, seeds) -> list:
    """``one(seed, directory)`` per seed, each in a temporary directory of its own."""
    rows = []
    for s in seeds:
        with tempfile.TemporaryDirectory() as td:
            rows.append(one(s, Path(td)))
    return rows


def contour_cycle_figures(seeds) -> tuple[list, list]:
    """The contour-cycle figures (module docstring) over ``seeds``, and notes on any other outcome."""
    rows = over_seeds(contour_cycle, seeds)
    n, ok = len(rows), [r for r in rows if r["expanded"]]
    k_in = sum(r["default"] == "accepted" for r in rows)
    what = "stepped-shaft G71/G70 (type I), truth as the model"
    figs = [{"what": f"{what}: programs accepted with the contour compensated in place (default)",
             "value": f"{k_in}/{n}", "unit": "", "residual": "none", "anchor": "refused naming `--expand-cycles`",
             "anchor_value": f"{sum(r['default'] == 'expand' for r in rows)}/{n}"},
            {"what": f"{what}: programs accepted with `--expand-cycles`", "value": f"{len(ok)}/{n}", "unit": "",
             "residual": "none", "anchor": "in place (default)", "anchor_value": f"{k_in}/{n}"},
            {"what": f"{what}, `--expand-cycles`: TRUE max at the contour points of the G70's moves (max over seeds)",
             "value": max((r["true_max"] for r in ok), default=None), "unit": "μm", "residual": "true",
             "anchor": "uncompensated (median over seeds)",
             "anchor_value": float(np.median([r["unc_max"] for r in ok])) if ok else None}]
    notes = [f"Contour cycles, seed {s}: " + (r["default"] if r["default"] not in ("accepted", "expand") else
                                              r.get("expand_error", ""))
             for s, r in zip(seeds, rows) if r["default"] not in ("accepted", "expand") or not r["expanded"]]
    return figs, notes


THREAD = ("%\nO0100\nG21 G18 G40 G99\nT0101\nG97 S800 M03\nG00 X40. Z5.\nX29.4\nG32 Z-30. F1.5\nG00 X40.\nZ5.\n"
          "X28.8\nG32 Z-30.\nG00 X40.\nZ5.\nX28.4\nG32 Z-10. F1.5\nZ-30.\nG00 X40.\nZ5.\nG01 X38. F0.2\nX37.\n"
          "G00 X100. Z50.\nM05\nM30\n%\n")
"""An M30x1.5 thread in three Fanuc G32 passes (the second's lead modal, the third two consecutive G32 blocks), then
a feed move with its own F and one without (tests/test_lathe_threading.py reads the same program)."""
THREAD_LEAD_MM = 1.5
THREAD_G76 = ("(M20x2.5 outside thread, LinuxCNC G76, diameter mode)\nG21 G18 G90 G7\nG54\nS400 M3\nG0 X22 Z5\n"
              "G76 P2.5 Z-30 I-2 J0.6 K3.068 R1.5 Q29.5 H1\nG0 X40 Z10\nG1 X38 F100\nM5\nM2\n")
"""An M20x2.5 thread by LinuxCNC's G76 (compensation/nc_g76.py; tests/test_lathe_g76.py): crest Ø20, full depth
1.534 mm, first depth 0.3 mm, degression 1.5 (11 passes), 29.5° compound slide, one spring pass: 13 passes."""
G76_LEAD_MM = 2.5


def true_leads(field, lathe, moves, zero_xz_mm, lead_mm: float) -> tuple:
    """``(relative TRUE lead errors (n,), TRUE start Z (mm) of each thread (t,))`` of the G32 (or LinuxCNC G33)
    pieces among ``moves`` (each with ``lead``: its written F or K, the lead axis or the drive line's columns), judged
    on ``field`` (the truth): the tip driven to each piece's written start and end (program axes, the work frame's
    zero ``zero_xz_mm`` in the machine), mean over one turn (``compensation.turning.surface_residual_um``); true
    lead = F × true travel / commanded travel along the lead axis (a G33: along its drive line), against
    ``lead_mm``. A thread starts at a piece whose line does not follow another piece's."""
    from compensation.turning import surface_residual_um
    pieces = [m for m in moves if m.lead is not None]

    def tip(xz):  # the TRUE tip (radius, z) mm in the work frame, the nominal moving one for one with X and Z
        q = np.column_stack([xz[:, 0] + zero_xz_mm[0], xz[:, 1] + zero_xz_mm[1], np.zeros(len(xz))])
        return xz + surface_residual_um(field, lathe, q, q)[0] * 1e-3
    a, b = tip(np.array([m.start for m in pieces])), tip(np.array([m.end for m in pieces]))

    def travel(p, q, j):  # along the lead axis j (a G32), or the drive line's length (columns j: a LinuxCNC G33)
        return float(np.linalg.norm(q[list(j)] - p[list(j)])) if isinstance(j, tuple) else q[j] - p[j]
    revs = np.array([travel(m.start, m.end, m.lead[2]) / m.lead[0] for m in pieces])
    true = np.array([travel(p, q, m.lead[2]) for p, q, m in zip(a, b, pieces)])
    first = [n for n, m in enumerate(pieces) if n == 0 or pieces[n - 1].index != m.index - 1]
    return true / revs / lead_mm - 1.0, a[first, 1]


def threading(seed: int, d: Path, g76: bool = False) -> dict:
    """One truth seed: THREAD (``g76``: THREAD_G76, with ``--expand-cycles``) compensated with the truth as the model;
    TRUE lead error (relative, max over the pieces), TRUE position error at the programmed points (μm, max) and the
    spread of the passes' TRUE start Z less their programmed start Z (μm), beside the program as written (a G76's as
    its expansion reads)."""
    from compensation.turning import parse_lathe_program
    from errormap.chain_field import ChainField
    lathe, els = _seeded(seed, d, THREAD_G76 if g76 else THREAD)
    dialect, lead_mm, x_words = ("linuxcnc", G76_LEAD_MM, None) if g76 else ("fanuc", THREAD_LEAD_MM, "diameter")
    rc, err, written = _compensate_steps(d, ("--expand-cycles",) if g76 else (), dialect=dialect)
    assert rc == 0, f"seed {seed}: the thread was refused: {err}"
    read = lambda f, c: parse_lathe_program(f, lathe, "keep", None, dialect, x_words, cycles=c)[0].moves  # noqa: E731
    src, out = read(d / "p.nc", "expand" if g76 else "keep"), read(written, "keep")
    field, zero = ChainField(lathe, els), (0.0, PART_Z_MM)
    m_src = [m for m in src if m.compensate]
    errs, missed = lathe_points_reached(field, lathe, m_src, [m for m in out if m.compensate], zero, TOL_POINT_UM)
    assert missed is None, f"seed {seed}: thread line {missed} reached by no written move"
    unc, _ = lathe_points_reached(field, lathe, m_src, m_src, zero, np.inf)
    programmed = np.array([m.start[1] for n, m in enumerate(src) if m.lead is not None and src[n - 1].lead is None])
    lead, starts = true_leads(field, lathe, out, zero, lead_mm)
    lead_unc, starts_unc = true_leads(field, lathe, src, zero, lead_mm)
    return {"lead": float(np.abs(lead).max()), "lead_unc": float(np.abs(lead_unc).max()), "pos": max(errs),
            "pos_unc": max(unc), "phase": float(np.ptp(starts - programmed)) * 1e3,
            "phase_unc": float(np.ptp(starts_unc - programmed)) * 1e3}


def threading_figures(seeds) -> list:
    """The threading figures (module docstring) over ``seeds``: maxima over the seeds, the G32 thread and the G76."""
    figs = []
    for g76, what, lead_mm, word in (
            (False, "Fanuc G32 thread M30x1.5, 3 passes, truth as the model", THREAD_LEAD_MM, "G32"),
            (True, "LinuxCNC G76 thread M20x2.5, 13 passes (29.5° compound, R1.5, H1), --expand-cycles, truth as the "
                   "model", G76_LEAD_MM, "G33")):
        rows = over_seeds(lambda s, d: threading(s, d, g76), seeds)
        mx = lambda k: float(max(r[k] for r in rows))  # noqa: E731
        figs += [{"what": f"{what}: TRUE lead error of every written {word} piece (max over pieces and seeds)",
                  "value": mx("lead") * lead_mm * 1e3, "unit": "μm/rev", "residual": "true",
                  "anchor": "uncompensated (lead as programmed)", "anchor_value": mx("lead_unc") * lead_mm * 1e3},
                 {"what": f"{what}: TRUE position at the programmed points (pass starts, {word} ends; max over seeds)",
                  "value": mx("pos"), "unit": "μm", "residual": "true", "anchor": "uncompensated",
                  "anchor_value": mx("pos_unc")},
                 {"what": f"{what}: spread of the passes' TRUE start Z less their programmed start Z (the thread's "
                          "phase; max over seeds)", "value": mx("phase"), "unit": "μm", "residual": "true",
                  "anchor": "uncompensated", "anchor_value": mx("phase_unc")}]
    return figs


def grooving_cycle(seed: int, d: Path) -> dict:
    """One truth seed: the G75 series' default outcome and, expanded, the TRUE max (μm) at the manual's moves beside
    the program as written; the one-plunge G75's default outcome and TRUE at its bottom."""
    import re
    from types import SimpleNamespace
    sys.path.insert(0, str(HERE.parent.parent / "tests"))
    from test_lathe_grooving import G75_KEPT, G75_SERIES, hand_moves  # the test's programs and rebuilt moves
    from compensation.turning import parse_lathe_program
    from errormap.chain_field import ChainField
    lathe, els = _seeded(seed, d, G75_SERIES)
    field = ChainField(lathe, els)

    def run(extra=(), out=None):
        rc, err, written = _compensate_steps(d, extra, out)
        return rc, err, [] if rc else [ln for ln in written.read_text().splitlines() if not ln.startswith("(volcomp:")]

    def reached(expected, moves, tol):
        src = [SimpleNamespace(end=np.array([x, z, 0.0]), index=i) for i, (_, x, z) in enumerate(expected)]
        errs, missed = lathe_points_reached(field, lathe, src, moves, (0.0, PART_Z_MM), tol)
        assert missed is None, f"seed {seed}: grooving point {missed} reached by no written move"
        return max(errs)
    rc, err, _ = run()
    row = {"default": "accepted" if rc == 0 else "expand" if "use --expand-cycles" in err else err}
    rc, err, out = run(("--expand-cycles",))
    row["expanded"] = rc == 0
    expected = hand_moves("G75", (31.0, -20.0), (20.0, -30.0), 2.0, 2.5, 0.5)
    if rc == 0:
        (d / "bare.nc").write_text("\n".join(out) + "\n")
        at = G75_SERIES.splitlines().index("G75 X40. Z-30. P2000 Q2500 F0.08")
        moves = [m for m in parse_lathe_program(d / "bare.nc", lathe, "keep", None, "fanuc", "diameter")[0].moves
                 if m.index >= at]
        as_written = [SimpleNamespace(end=np.array([x, z, 0.0]), index=i) for i, (_, x, z) in enumerate(expected)]
        row |= {"true_max": reached(expected, moves, TOL_POINT_UM), "unc_max": reached(expected, as_written, np.inf)}
    else:
        row["expand_error"] = err
    (d / "p.nc").write_text(G75_KEPT)
    rc, err, out = run(out="out-kept")
    row["kept"] = "accepted" if rc == 0 else "expand" if "use --expand-cycles" in err else err
    if rc == 0:
        src = G75_KEPT.splitlines()
        x_w = float(re.search(r"X(-?[\d.]+)", out[src.index("G75 X61. P300 F0.08")]).group(1))
        z_w = float(re.search(r"Z(-?[\d.]+)", out[src.index("G01 X62. F0.2")]).group(1))
        bottom = [("G1", 30.5, -20.0)]
        row["kept_true"] = reached(bottom, [SimpleNamespace(end=np.array([x_w / 2, z_w, 0.0]), index=0)], np.inf)
        row["kept_unc"] = reached(bottom, [SimpleNamespace(end=np.array([30.5, -20.0, 0.0]), index=0)], np.inf)
    return row


def grooving_figures(seeds) -> tuple[list, list]:
    """The grooving-cycle figures (module docstring) over ``seeds``, and notes on any other outcome."""
    rows = over_seeds(grooving_cycle, seeds)
    n, ok, kept = len(rows), [r for r in rows if r["expanded"]], [r for r in rows if r["kept"] == "accepted"]
    acc = f"{sum(r['default'] == 'accepted' for r in rows)}/{n}"
    what = "G75 groove series (5 columns of pecks), truth as the model"
    one = "one-plunge G75 (0.5 mm deep) kept, truth as the model"
    figs = [{"what": f"{what}: programs accepted with `--expand-cycles`", "value": f"{len(ok)}/{n}", "unit": "",
             "residual": "none", "anchor": "kept (default; the others refused naming `--expand-cycles`)",
             "anchor_value": acc},
            {"what": f"{what}, `--expand-cycles`: TRUE max at the manual's moves (65 points; max over seeds)",
             "value": max((r["true_max"] for r in ok), default=None), "unit": "μm", "residual": "true",
             "anchor": "the program as written (median over seeds)",
             "anchor_value": float(np.median([r["unc_max"] for r in ok])) if ok else None},
            {"what": f"{one}: programs accepted (error across within 0.5 μm)", "value": f"{len(kept)}/{n}",
             "unit": "",
             "residual": "none", "anchor": "refused naming `--expand-cycles`",
             "anchor_value": f"{sum(r['kept'] == 'expand' for r in rows)}/{n}"},
            {"what": f"{one}: TRUE at its bottom (max over the accepted seeds)",
             "value": max((r["kept_true"] for r in kept), default=None), "unit": "μm", "residual": "true",
             "anchor": "as written (median over the accepted seeds)",
             "anchor_value": float(np.median([r["kept_unc"] for r in kept])) if kept else None}]
    notes = [f"Grooving cycles, seed {s}: " + (r["default"] if r["default"] not in ("accepted", "expand") else
                                               r.get("expand_error", r["kept"]))
             for s, r in zip(seeds, rows) if r["default"] not in ("accepted", "expand") or not r["expanded"]
             or r["kept"] not in ("accepted", "expand")]
    return figs, notes


def grid_figure(machine_name, seeds):
    """Identified-model field error over the volume grid (4,000 points), max / RMS μm, and the z-scores."""
    from errormap.machine import load_machine
    from errormap.identifiability import identifiability
    m = load_machine(machine_name)
    out = []
    for s in seeds:
        rep = identifiability(m, seed=s, noise_um=2.0, seed_noise=s)
        out.append(rep)
    return out


def _noisy(truth, lathe, seed):
    from errormap.chain_elements import ChainElementSet
    rng = np.random.default_rng(1000 + seed)
    f = {k: v + rng.normal(0.0, NOISE, v.shape) for k, v in truth.functions.items()}
    for k, v in truth.functions.items():  # a closed profile (C at 360° = at 0°) stays closed
        if abs(v[-1] - v[0]) < 1e-12:
            f[k][-1] = f[k][0]
    return ChainElementSet(lathe, truth.stations, f, {k: v + rng.normal(0.0, NOISE) for k, v in truth.constants.items()})


def tool_offsets(seed, d: Path) -> dict:
    """TRUE max over the turn (μm) per (model, compensation) for one truth seed."""
    sys.path.insert(0, str(HERE.parent.parent / "tests"))
    from test_lathe_tool_offsets import PROGRAM as TURN_PROGRAM, TBL, WORK_Z_MM  # the test's program and tables
    from compensation.app.workflows.compensate import CompensateSettings, solve_paths
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.nc_state import machine_with_lathe_tool, read_tool_table, read_work_offsets
    from compensation.turning import solve_turning, surface_residual_um
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    lathe = load_machine("lathe-xzc")
    (d / "p.ngc").write_text(TURN_PROGRAM)
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


TITLE = "Lathe (`lathe-xzc`): identification from sweeps and a turning program compensated"
DATA = ("simulated `lathe-xzc` (`volcomp simulate --seed S`), sweeps at 2 μm, a G18 turning program with C moves; "
        "seeds 0–2 (quick: seed 0, no volume-grid figure); tool offsets: LinuxCNC two-tool program, ±10 μm/μrad "
        "truths, seeds 0–4 (quick: seed 0); contour cycles: Fanuc G71/G70 stepped shaft, ±10 μm/μrad truths as "
        "the model, seeds 0–19 (quick: 0–2); threading: Fanuc G32 M30x1.5 in 3 passes and LinuxCNC G76 M20x2.5 "
        "in 13, grooving: Fanuc G75 "
        "groove series and one-plunge G75, both on the contour cycles' truths and seeds")


def run(quick: bool, seed: int) -> dict:
    import numpy as np
    seeds = [seed] if quick else [seed, seed + 1, seed + 2]
    rows = []
    for s in seeds:
        with tempfile.TemporaryDirectory() as td:
            rows.append(user_path("lathe-xzc", s, Path(td)))
    med = lambda k: float(np.median([r[k] for r in rows]))  # noqa: E731
    figs = [{"what": "turning program, max (median over seeds)", "value": med("true_max"), "unit": "μm",
             "residual": "true", "anchor": "uncompensated", "anchor_value": med("unc_max")},
            {"what": "turning program, RMS", "value": med("true_rms"), "unit": "μm", "residual": "true",
             "anchor": "uncompensated", "anchor_value": med("unc_rms")}]
    if not quick:
        g = grid_figure("lathe-xzc", seeds)
        figs.append({"what": "identified model over the volume grid, RMS (median)",
                     "value": float(np.median([x.grid_rms_um for x in g])), "unit": "μm", "residual": "true",
                     "anchor": "mill-xyz's identified model, the same figure",
                     "anchor_value": float(np.median([x.grid_rms_um for x in grid_figure("mill-xyz", seeds)]))})
    figs += tool_offset_figures([seed] if quick else [seed + k for k in range(5)])
    cfigs, notes = contour_cycle_figures([seed + k for k in range(3 if quick else 20)])
    tfigs = threading_figures([seed + k for k in range(3 if quick else 20)])
    gfigs, gnotes = grooving_figures([seed + k for k in range(3 if quick else 20)])
    return {"figures": figs + cfigs + tfigs + gfigs, "notes": notes + gnotes}


def tool_offset_figures(seeds) -> list:
    """The tool-offset figures: offsets used in the chain beside ignored, ignored beside uncompensated."""
    import numpy as np
    rows = over_seeds(tool_offsets, seeds)
    mx = lambda k: float(max(r[k] for r in rows))  # noqa: E731
    figs = []
    for model, label in (("truth", "truth as the model"), ("noisy", "model 0.3 μm/μrad off the truth")):
        figs += [{"what": f"tool offsets, {label}: ignored in the chain, TRUE max over the turn (max over seeds)",
                  "value": mx((model, "ignored")), "unit": "μm", "residual": "true", "anchor": "uncompensated",
                  "anchor_value": mx((model, "uncompensated"))},
                 {"what": f"tool offsets, {label}: used in the chain (`--tool-table`), max over seeds",
                  "value": mx((model, "used")), "unit": "μm", "residual": "true", "anchor": "offsets ignored",
                  "anchor_value": mx((model, "ignored"))}]
    return figs
