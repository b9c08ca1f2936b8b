"""``linuxcnc``: one pitch table per joint the exact solver moves (``joint_<w>.comp``), on any machine tool.

Lines ``nominal forward reverse`` in the joint's unit (mm; deg for a rotary joint), at most 256, increasing
nominal: ``forward``/``reverse`` are the positions the joint actually reaches when commanded to ``nominal``
approaching in + / −; the controller commands ``nominal + (nominal − actual)``, linear between lines (a
full-turn joint folded into its one-turn table). A joint's correction may depend on that joint's position
only, so the model's exact correction is projected onto one function per joint: averaged over seeded
positions of the other axes inside the fitting region (default the calibrated volume), a rotary joint's
weighted by ``r²`` (the least-squares angle; ``r`` the tool point's distance from its axis). What that cannot
represent — every coupling between axes — is left in the residual, and the check shows how much. Reversal
comes from the model's reversal terms (a diagnosed backlash): forward − reverse; without one they are equal.
Rotary joints the exact solver keeps as commanded (a five-axis machine's A and C) get no table.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.io import InputError, atomic_write

from .common import LINUXCNC_MAX_POINTS, fold, node_means
from .model import ModelError, exact_corrections

JOINT_SAMPLES = 48
"""Positions of the other axes each node's correction is averaged over."""
ROTARY_WEIGHTS = ("r2", "plain")
"""How a rotary joint's samples are averaged: ``r2`` (the least-squares angle, the default) or ``plain`` (the
unweighted mean of the linear joints; kept for the benchmark's comparison)."""


class JointTables:
    """Per-joint tables: ``nominal[j]``, ``forward[j]``, ``reverse[j]`` (m,) in the joint's unit; ``joints``
    ``{j: index into the machine's axes}`` (j the lower-case axis word); ``units`` ``{j: "mm" | "deg"}``;
    ``turns`` ``{j: first node}`` for a full-turn joint whose table covers one turn."""

    kind = "linuxcnc"

    def __init__(self, nominal: dict, forward: dict, reverse: dict, joints: dict, units: dict | None = None,
                 turns: dict | None = None, unfilled: dict | None = None):
        self.nominal, self.forward, self.reverse, self.joints = nominal, forward, reverse, joints
        self.units = units if units is not None else {j: "mm" for j in nominal}
        self.turns = turns or {}
        self.unfilled = unfilled or {}

    def actual(self, j: str):
        return self.forward[j], self.reverse[j]

    def command(self, axes, dirs) -> np.ndarray:
        """Motor commands (n, k) for nominal axes (n, k) approached in ``dirs`` (n, k) ±1: each tabulated
        joint ``q + (q − actual(q))``, linear between lines, clamped to the table (a full-turn joint folded
        into its turn first); other axes as given."""
        axes = np.asarray(axes, dtype=float)
        out = axes.copy()
        for j, k in self.joints.items():
            nom = self.nominal[j]
            q = fold(axes[:, k], self.turns[j]) if j in self.turns else axes[:, k]
            act = np.where(dirs[:, k] >= 0, np.interp(q, nom, self.forward[j]), np.interp(q, nom, self.reverse[j]))
            out[:, k] = axes[:, k] + (np.interp(q, nom, nom) - act)
        return out

    def max_reversal(self) -> dict:
        """Largest |forward − reverse| per joint, in the joint's unit."""
        return {j: float(np.max(np.abs(self.forward[j] - self.reverse[j]))) for j in self.nominal}

    def n_values(self) -> int:
        return int(sum(3 * v.size for v in self.nominal.values()))


def region_box(model: ModelError, region: dict | None) -> tuple:
    """The sampling box ``(lo, hi)`` (k,): the calibrated ranges with those of ``region`` (``{column: (lo,
    hi)}``) in place of their axes'; ValueError for an unknown column or a range outside the calibrated one."""
    mt = model.mt
    box_lo = np.array([model.range(j)[0] for j in range(len(mt.axes))])
    box_hi = np.array([model.range(j)[1] for j in range(len(mt.axes))])
    cols = list(mt.axis_columns)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(np.r_[box_lo, box_hi]))))
    for c, (a, b) in (region or {}).items():
        if c not in cols:
            raise ValueError(f"region: no axis column {c!r} on machine {mt.name!r} (columns: {', '.join(cols)})")
        k = cols.index(c)
        if not (box_lo[k] - tol <= a <= b <= box_hi[k] + tol):
            raise ValueError(f"region {c} {a:g}:{b:g} leaves the calibrated range {box_lo[k]:g}:{box_hi[k]:g}")
        box_lo[k], box_hi[k] = a, b
    return box_lo, box_hi


def joint_tables_from_model(model: ModelError, machine, n_points: int = LINUXCNC_MAX_POINTS,
                            samples: int = JOINT_SAMPLES, seed=0, rotary_weight: str = "r2",
                            region: dict | None = None) -> JointTables:
    """One table per joint the exact solver moves (:func:`compensation.solvers.chain_exact.solved_and_kept`):
    at ``n_points`` nominal positions over its calibrated range, the exact correction of that joint averaged
    over ``samples`` seeded positions of the other axes (inside ``region``; their approach directions drawn
    ±1); ``forward`` with the joint approached in +, ``reverse`` in − (equal unless the model depends on that
    joint's direction). Nodes where no sample is compensable take their neighbours' values; a full-turn
    joint's table covers one turn, the last line equal to the first (module docstring)."""
    from ..solvers.chain_exact import nominal_and_jacobian, rotary_radius_mm, solved_and_kept
    if not 2 <= n_points <= LINUXCNC_MAX_POINTS:
        raise ValueError(f"Expected 2 <= points per joint <= {LINUXCNC_MAX_POINTS}, got {n_points}")
    if rotary_weight not in ROTARY_WEIGHTS:
        raise ValueError(f"Expected rotary_weight in {ROTARY_WEIGHTS}, got {rotary_weight!r}")
    mt = model.mt
    k_axes = len(mt.axes)
    sol, _ = solved_and_kept(machine)
    rng = np.random.default_rng(seed)
    box_lo, box_hi = region_box(model, region)
    dir_cols = set(model.dir_columns())
    nominal, fwd, rev, joints, units, turns, unfilled = {}, {}, {}, {}, {}, {}, {}
    for k in (int(k) for k in sol):
        a = mt.axes[k]
        j = a.word.lower()
        rotary = a.kind != "linear"
        lo, hi = model.range(k)
        one_turn = rotary and a.full_turn and hi - lo >= 360.0 - 1e-9
        nom = np.linspace(lo, hi, n_points)
        q = np.repeat(rng.uniform(box_lo, box_hi, (samples, k_axes))[None], n_points, axis=0)
        q[:, :, k] = nom[:, None]
        q = q.reshape(-1, k_axes)
        d = np.repeat(rng.choice([-1.0, 1.0], (samples, k_axes))[None], n_points, axis=0).reshape(-1, k_axes)
        w = None
        if rotary:
            w = rotary_radius_mm(nominal_and_jacobian(machine, q)[1][:, :, k]).reshape(n_points, samples) ** 2
            w = np.ones_like(w) if rotary_weight == "plain" else w
        out = []
        for sign in ((1.0, -1.0) if k in dir_cols else (1.0,)):
            d[:, k] = sign
            c, ok = exact_corrections(model, machine, q, d)
            c, ok = c[:, k].reshape(n_points, samples), ok.reshape(n_points, samples)
            mean, good = node_means(nom, c, ok, f"joint {a.word}: the model cannot be compensated at any sampled "
                                                f"point of the fitting region", w)
            unfilled[j] = int((~good).sum())
            if one_turn:
                mean[-1] = mean[0]  # one turn: the last line is the first
            out.append(nom - mean)
        nominal[j], fwd[j], rev[j], joints[j] = nom, out[0], out[-1], k
        units[j] = "deg" if rotary else "mm"
        if one_turn:
            turns[j] = float(lo)
    return JointTables(nominal, fwd, rev, joints, units, turns, unfilled)


def write_joint_tables(tables: JointTables, folder) -> list[Path]:
    """``joint_<j>.comp`` for every joint of ``tables``: lines ``nominal forward reverse`` in the joint's unit,
    9 decimals, each file written atomically."""
    out = []
    for j in tables.nominal:
        fwd, rev = tables.actual(j)
        path = Path(folder) / f"joint_{j}.comp"
        with atomic_write(path, "w", encoding="utf-8") as fh:
            for a, b, c in zip(tables.nominal[j], fwd, rev):
                fh.write(f"{a:.9f} {b:.9f} {c:.9f}\n")
        out.append(path)
    return out


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def read_comp_file(path) -> np.ndarray:
    """The lines (m, 3) of one ``.comp`` file: three finite numbers a line, increasing nominal, 2 to 256 lines."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such compensation file")
    rows = []
    for ln, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        cells = line.split()
        if len(cells) != 3:
            raise InputError(f"{path}: line {ln}: expected 3 numbers (nominal forward reverse), got {len(cells)}")
        if not all(_is_float(c) for c in cells):
            bad = next(i for i, c in enumerate(cells) if not _is_float(c))
            raise InputError(f"{path}: line {ln}, column {bad + 1}: expected a number, got {cells[bad]!r}")
        vals = [float(c) for c in cells]
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path}: line {ln}: expected finite numbers, got {line!r}")
        if rows and vals[0] <= rows[-1][0]:
            raise InputError(f"{path}: line {ln}, column 1: expected increasing nominal positions, got "
                             f"{vals[0]} after {rows[-1][0]}")
        rows.append(vals)
    if not 2 <= len(rows) <= LINUXCNC_MAX_POINTS:
        raise InputError(f"{path}: expected 2 to {LINUXCNC_MAX_POINTS} lines, got {len(rows)}")
    return np.array(rows)


def read_joint_tables(folder, like: JointTables) -> JointTables:
    """Read the ``joint_<j>.comp`` files of the joints of ``like`` (their axes, units and turns)."""
    nominal, fwd, rev = {}, {}, {}
    for j in like.joints:
        r = read_comp_file(Path(folder) / f"joint_{j}.comp")
        nominal[j], fwd[j], rev[j] = r[:, 0], r[:, 1], r[:, 2]
    return JointTables(nominal, fwd, rev, dict(like.joints), dict(like.units), dict(like.turns))
