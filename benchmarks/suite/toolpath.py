"""True residual ALONG long moves, with and without segment splitting.

What the controller runs between two written vertices is a straight line in the axes; the compensation
is exact only at the vertices. A simulated truth machine (default grinder, ``make_chain_truth(seed)``) is
driven along every written move, densely (17 points per written segment), and the TRUE residual is taken
against the target at the same parameter of the program's own move. The solver (``exact``) is given the
truth's own error (its 23 elements plus the undeclared effects ``pitch``, ``worm``, ``interaction``, at
20 °C with positive approach), so every μm left is the linearisation between vertices, which splitting
addresses. Two truth shapes: the element profiles alone, and with the three effects.

Paths: the paper's variable-helix flute (7 turns) written as G-code at 400, 40 and 10 points per turn;
single 20 mm G1 moves across the X stroke (X = x0 → x0 + 20, x0 = 0, 20, …, 180) at Z = 5 mm, A = 0°, 90°.
Per path: read and planned as ``volcomp compensate`` reads it (``read_tool_path``: the chain planner,
:func:`compensation.chain_gcode.plan_chain_gcode`), compensated with ``--max-segment-mm`` ``none`` (the program's
points only: the plain approach, the anchor), ``auto`` (tolerance 0.5 μm, the default) and a fixed 1 mm.

    python -m benchmarks.run toolpath
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from errormap.field import CalibratedVolume

SPLITS = (("none", None), ("auto", "auto"), ("1 mm", 1.0))
EFFECTS = ("pitch", "worm", "interaction")
SEEDS = 3
"""Truth seeds of the full run (seed .. seed + 2); figures are the worst seed's."""
SAMPLES = 17
"""Samples per written segment, ends included."""

TITLE = "Tool paths: true residual along long moves, compensated at the program's points vs split segments"
DATA = ("default grinder, `make_chain_truth(seed)` for 3 seeds, elements alone and + pitch, worm, interaction; the "
        "solver given the truth's own error; the flute at 400 / 40 / 10 points per turn, 20 mm straight G1 moves")


class TruthField:
    """The truth machine's error as a field (predict μm), calibrated over the strokes."""

    def __init__(self, truth):
        self.truth = truth
        self.calibrated_volume = CalibratedVolume(truth.machine.stroke_lo, truth.machine.stroke_hi)
        self.capabilities = frozenset()

    def predict(self, axes):
        axes = np.asarray(axes, dtype=float)
        return self.truth.spatial_error(axes, **self.truth.default_conditions(len(axes)))


def programs(machine, tmp: Path, quick: bool) -> dict:
    """The G-code programs measured: ``{name: path}``; quick: the straight moves at A 0° only."""
    from compensation.pathio import write_axes_gcode
    from compensation.toolpath import flute_path
    out = {}
    for ppt in () if quick else (400, 40, 10):
        out[f"flute, {ppt} pts/turn"] = write_axes_gcode(tmp / f"flute{ppt}.nc",
                                                        flute_path(points_per_turn=ppt).axes(machine))
    for a in (0.0,) if quick else (0.0, 90.0):
        lines = ["G21 G90 G94"]
        for x0 in range(0, 200, 20):
            lines += [f"G0 X{x0} Z5 A{a:g}", f"G1 X{x0 + 20} F300"]
        p = tmp / f"straight_a{a:g}.nc"
        p.write_text("\n".join(lines + ["M30"]) + "\n")
        out[f"straight 20 mm, A {a:g}°"] = p
    return out


def along_moves_um(truth, tp, command_axes, samples: int) -> np.ndarray:
    """|true residual| (μm) at ``samples`` points along every written segment, flattened.

    ``tp``: the G-code tool path as ``compensate`` reads and plans it (``read_tool_path``: a
    :class:`compensation.chain_gcode.ChainGCodeJob`, each move in equal pieces); ``command_axes`` (n, k) what is
    written at its vertices (the nominal axes for the uncompensated program). A segment runs from the previous
    vertex of the same move (or the move's nominal start) to the vertex.
    """
    from compensation.gcode import move_points
    from compensation.solvers.chain_exact import nominal_and_jacobian
    s = np.linspace(0.0, 1.0, samples)[1:]
    job, res, k, prev_cmd = tp.source, [], 0, None
    for m, c in zip([m for m in job.program.moves if m.compensate], job.counts):
        t = np.arange(1, c + 1) / c
        t_prev = np.concatenate([[0.0], t[:-1]])
        cmds = command_axes[k:k + c]
        k += c
        if not np.all(np.isfinite(m.start)) or prev_cmd is None:
            prev_cmd = cmds[-1]
            continue
        starts = np.vstack([prev_cmd[None], cmds[:-1]])
        cmd = (starts[:, None, :] + s[None, :, None] * (cmds - starts)[:, None, :]).reshape(-1, cmds.shape[1])
        target = move_points(m, (t_prev[:, None] + s[None, :] * (t - t_prev)[:, None]).ravel())
        reached = truth.tool_point(cmd, **truth.default_conditions(len(cmd)))
        res.append(1e3 * np.linalg.norm(reached - nominal_and_jacobian(truth.machine, target)[0], axis=1))
        prev_cmd = cmds[-1]
    return np.concatenate(res)


def run_seed(seed: int, quick: bool) -> list[dict]:
    """Rows ``{truth, path, split, vertices, max_um}`` for one truth seed (uncompensated and every split)."""
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.nc_state import MACHINE, read_work_offsets
    from compensation.solvers import solve
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    from compensation.solvers.chain_exact import nominal_and_jacobian
    machine, rows = load_machine(), []
    with tempfile.TemporaryDirectory() as d:
        progs = programs(machine, Path(d), quick)
        settings = lambda seg: CompensateSettings("exact", "", Path(d), rapids="keep", max_segment_mm=seg,  # noqa: E731
                                                  work_offsets=read_work_offsets(MACHINE))
        for shape, effects in (("elements", ()),) + ((() if quick else (("elements + effects", EFFECTS),))):
            truth = make_chain_truth(machine, seed, effects=effects)
            field = TruthField(truth)
            for name, path in progs.items():
                base = read_tool_path(path, machine, settings(None))
                rows.append({"truth": shape, "path": name, "split": "uncompensated", "vertices": len(base),
                             "max_um": float(along_moves_um(truth, base, base.axes, SAMPLES).max())})
                for label, seg in SPLITS[:2] if quick else SPLITS:
                    tp = read_tool_path(path, machine, settings(seg), field)
                    targets = nominal_and_jacobian(machine, tp.axes)[0]
                    q = np.round(solve("exact", field, targets, machine, target_axes=tp.axes).axes, 6)
                    rows.append({"truth": shape, "path": name, "split": label, "vertices": len(tp),
                                 "max_um": float(along_moves_um(truth, tp, q, SAMPLES).max())})
    return rows


def run(quick: bool, seed: int) -> dict:
    """Full: 3 seeds, both truths, every path and split; quick: one seed, elements, straight A 0°, none / auto.

    Figures: ``auto`` on every path, the fixed 1 mm on the straight moves only (the flute's written moves are
    shorter than 1 mm, so it splits nothing there: the full run measured the same vertices and residual as ``none``)."""
    rows = [r for s in range(seed, seed + (1 if quick else SEEDS)) for r in run_seed(s, quick)]
    worst = lambda **k: max(r["max_um"] for r in rows if all(r[a] == v for a, v in k.items()))  # noqa: E731
    verts = lambda **k: int(np.median([r["vertices"] for r in rows if all(r[a] == v for a, v in k.items())]))  # noqa: E731
    figs, notes = [], []
    for path in dict.fromkeys(r["path"] for r in rows):
        none = worst(path=path, split="none")
        for label, _ in SPLITS[1:2] if quick or path.startswith("flute") else SPLITS[1:]:  # 1 mm: straight only
            figs.append({"what": f"{path}: `--max-segment-mm {label.replace(' mm', '')}` ({verts(path=path, split=label)} "
                                 f"vertices), max along the moves, worst seed and truth", "value": worst(path=path, split=label),
                         "unit": "μm", "residual": "true",
                         "anchor": f"program's points only (`none`, {verts(path=path, split='none')} vertices)",
                         "anchor_value": none})
        notes.append(f"{path}: uncompensated {worst(path=path, split='uncompensated'):.3g} μm max along the moves")
    return {"figures": figs, "notes": ["; ".join(notes)]}
