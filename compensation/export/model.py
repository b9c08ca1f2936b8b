"""The model a controller table is built from and checked against, on any machine tool.

Every machine tool is its chain (a ``kind = "grinder"`` file is read as the grinder's chain, with the same
23 element names and axis columns): the axes, their strokes and
full turns, the error slots and their ISO names, the bodies' frames. What differs between machine files
is only how their model files are read (:func:`load_model`, :func:`load_truth`, :func:`reversal_from_diagnosis`):
the grinder's older simulated truths (no ``format`` key), checks diagnoses and closed-loop models are still read.
"""
from __future__ import annotations

from dataclasses import dataclass, field as dc_field

import numpy as np

from errormap.chain_kernel import CompiledNominal, NominalChain

from .common import TableField, fold

TABLE_TEMP_C = 20.0
"""A table has no temperature input: a thermal term of the model is evaluated at the reference temperature."""


def nominal_mm(machine, axes) -> np.ndarray:
    """Nominal tool point (n, 3) mm in the workpiece frame at ``axes`` (n, k) (the compiled chain)."""
    return NominalChain(machine).forward(np.asarray(axes, dtype=float))


def own_slot(mt, word: str) -> str:
    """The slot that is axis ``word``'s own positioning error (ISO ``E<W><W>``: EXX, EZZ, EAA ...): where a
    reversal (backlash) of that joint acts."""
    for s in mt.slots:
        if s.axis == word and s.iso == f"E{word}{word}":
            return s.name
    raise ValueError(f"axis {word} of {mt.name!r} has no positioning error slot E{word}{word}")


@dataclass
class ModelError:
    """The model's spatial error (μm) at axes (n, k): an element set (``values(axes) -> (n, P)`` slot values
    through the exact chain) or an error field (``predict(axes) -> (n, 3)``, e.g. a network or a diagnosed
    chain model whose terms need conditions ``dir_<w>`` / ``temp_c``), plus reversal terms ``{word: b}`` (b in
    the unit of the joint's own slot, μm or μrad) added to that slot as ``b/2·dir`` (dir ±1, the approach
    direction; element sets only). ``elements`` may accompany a field (the diagnosed model's): the ISO tables
    read it, the error is the field's."""

    machine: object
    elements: object = None
    field: object = None
    reversal: dict = dc_field(default_factory=dict)

    def __post_init__(self):
        if self.elements is None and self.field is None:
            raise ValueError("Expected an element set or an error field")
        if self.reversal and self.elements is None:
            raise ValueError("Expected an element-set model to carry a reversal (backlash) term")
        self.mt = self.machine
        self._compiled = CompiledNominal(self.mt)
        self._own = {w: self.mt.slot_names.index(own_slot(self.mt, w)) for w in self.reversal}

    @property
    def needs(self) -> tuple:
        """Conditions the model's error depends on (``dir_<w>``, ``temp_c``)."""
        if self.field is None or self.reversal:
            return tuple(f"dir_{w.lower()}" for w in self.reversal)
        return tuple(getattr(self.field, "needs", ()))

    def range(self, j: int) -> tuple:
        """The calibrated range ``(lo, hi)`` of axis ``j``: the element set's stations, else the stroke."""
        a = self.mt.axes[j]
        st = getattr(self.elements, "stations", {}).get(a.column) if self.elements is not None else None
        return (float(st[0]), float(st[-1])) if st is not None else (float(a.stroke[0]), float(a.stroke[1]))

    def turn_start(self, j: int) -> float:
        """Where a full-turn axis' turn starts (its first station, else its stroke's start)."""
        return self.range(j)[0]

    def conditions(self, dirs, n: int) -> dict:
        """The condition arrays of :attr:`needs` at approach directions ``dirs`` (n, k) ±1 (None: all +)."""
        cond = {"temp_c": np.full(n, TABLE_TEMP_C)}
        for j, a in enumerate(self.mt.axes):
            cond[f"dir_{a.word.lower()}"] = np.ones(n) if dirs is None else np.broadcast_to(dirs[:, j], (n,))
        return {c: cond[c] for c in self.needs}

    def __call__(self, axes, dirs=None) -> np.ndarray:
        axes = np.asarray(axes, dtype=float)
        if self.field is not None and not self.reversal:
            a = axes.copy()
            for j, ax in enumerate(self.mt.axes):
                if ax.full_turn:
                    a[:, j] = fold(a[:, j], self.turn_start(j))
            f = self.field.with_conditions(self.conditions(dirs, len(a))) if self.needs else self.field
            return np.asarray(f.predict(a), dtype=float)
        v = self.elements.values(axes)
        for w, b in self.reversal.items():
            d = np.ones(len(axes)) if dirs is None else dirs[:, self.mt.axis_words.index(w)]
            v[:, self._own[w]] += 0.5 * b * d
        return self._compiled.spatial_error(axes, v)

    def solver_field(self, d=None):
        """The model at fixed approach directions ``d`` (k,) ±1 (None: +) as a field the exact solver takes, the
        same way on every machine, as measured: a field whose Jacobian is closed form (an element set's chain, a
        network) is given as itself, conditions as constants (half the solve time of differencing it on
        five-axis-ac, the same axes to 1e-10 mm); a model with effect terms (whose Jacobian differences the
        terms centrally) or reversal terms, or without a field, as a plain field the solver differentiates
        (forward differences, then Broyden: 2.5 of 24.7 CPU s less on the export benchmark)."""
        if self.field is None or self.reversal or getattr(self.field, "terms", ()):
            if d is None:
                return TableField(lambda q: self(q))
            return TableField(lambda q: self(q, np.broadcast_to(d, (len(q), len(d)))))
        if not self.needs:
            return self.field
        dd = np.ones(len(self.mt.axes)) if d is None else np.asarray(d, float)
        cond = {"temp_c": TABLE_TEMP_C, **{f"dir_{a.word.lower()}": float(dd[j]) for j, a in enumerate(self.mt.axes)}}
        return self.field.with_conditions({c: cond[c] for c in self.needs})

    def dir_columns(self) -> list:
        """Axis indices whose approach direction the model's error depends on."""
        return [j for j, a in enumerate(self.mt.axes) if f"dir_{a.word.lower()}" in self.needs]


def exact_corrections(model: ModelError, machine, axes, dirs=None, progress: bool = False):
    """The model's exact axis correction at nominal ``axes`` (n, k) (what the exact solver commands minus
    the axes) and a success mask (n,). Where the model depends on approach directions the points are solved
    per direction pattern, each with its own fixed-direction field (a solver evaluates fields on subsets)."""
    from ..solvers import solve
    axes = np.asarray(axes, dtype=float)
    cols = model.dir_columns() if dirs is not None else []
    if cols:
        keys, group = np.unique(np.asarray(dirs, float)[:, cols], axis=0, return_inverse=True)
        group = np.asarray(group).ravel()
        groups = [(np.flatnonzero(group == g), np.asarray(dirs, float)[np.flatnonzero(group == g)[0]])
                  for g in range(len(keys))]
    else:
        groups = [(np.arange(len(axes)), None)]
    c, ok = np.zeros_like(axes), np.zeros(len(axes), bool)
    for idx, d in groups:
        fld = model.solver_field(d)
        res = solve("exact", fld, nominal_mm(machine, axes[idx]), machine, target_axes=axes[idx], progress=progress)
        c[idx] = res.axes - axes[idx]
        ok[idx] = np.asarray(res.success, bool)
    return c, ok
