"""The effect terms of the closed loop on a machine-tool chain: the candidates over the machine's axes
(:func:`effect_candidates`), their basis columns through the chain's error Jacobian (:func:`effect_columns`),
those the element slots represent (:func:`representable_terms`), the held-out gated forward search
(:func:`effect_search`) and the sweep prior of a term re-fitted jointly with the update (:func:`sweep_shift`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.stats

from ..effect_kinds import effect_kind
from ..machine_tool import MachineTool
from ..chain_elements import ChainElementSet
from .chain_update import parameter_matrix

HELD_OUT_Z = 3.0
"""An effect is accepted when it lowers the held-out squared residual norm, paired per point, by more than
3 standard errors (one-sided p ≈ 0.001; a few candidates in rank order)."""
JOINT_Z = HELD_OUT_Z
"""A term accepted on the held-out checks stays only if the joint fit with the element update (the fitting
checks, the update's prior and smoothness prior) still gives its coefficients a Wald χ² above the level of
this many standard errors, corrected for the shapes tried (:func:`joint_threshold`): an update made before
the term was found (its σ inflated by the unmodelled effect) leaves element geometry behind that a term can
take up, and the joint fit gives it back to the elements. Decided on development seeds 100–114 (a 2.3 mm
periodic term on X at held-out z 3.05, joint χ² 2.2, threshold 28; every simulated effect above 60)."""
PERIOD_GRID_MM = np.geomspace(2.0, 60.0, 240)
"""Periods tried for a periodic (pitch) term on a linear axis: 2–60 mm, 1.4 % apart."""
PERIOD_REFINE = 0.015
"""Then ±1.5 % around the best grid period in 121 steps (0.025 %): a 1 % period error over 40 cycles of a
400 mm stroke is 0.4 of a cycle."""
HARMONIC_ORDERS = np.arange(2, 121)
"""Orders tried for a harmonic on a rotary axis (per turn), those the stations resolve left out (:func:`shape_band`)."""
SHAPE_NYQUIST = 2.0
"""Station spacings per cycle at and above which a periodic or harmonic shape is resolved by the element
stations (sampling theorem): such a shape is the element's own geometry, which the sweeps measure at the
stations and the update refines, not an effect term (:func:`shape_band`). Decided on development seeds
100–104: with the smoothness prior the update leaves part of a truth's low-order geometry (orders 3–6 on a
rotary axis with 18° stations), and a harmonic term of that order took it up in 7 of 60 effect runs."""
REF_TEMP_C = 20.0
SPAN_RANK_TOL = 1e-9
"""A pivoted-QR diagonal of the column-scaled slot Jacobian below this fraction of the largest is a
direction the slots do not span (as the identification's :data:`errormap.identification.RANK_TOL`)."""
REPRESENTED_TOL = 1e-2
"""An effect term whose columns leave less than this fraction of their norm outside the span of the
element slots (over the checks) is represented by the slots. The span is the first-order one at the
identified elements and the term's column the nominal chain's, so a represented term leaves a
second-order part of the order of the angular errors (3e-5 to 7e-5 on the built-in chains with
their simulated elements, ≤ 1e-3 for angular errors up to 1 mrad); a term the slots cannot
represent leaves 0.2 or more (a generic column 0.7 or more, :data:`SPAN_ROWS_PER_PARAM`). 1e-2
sits an order of magnitude from either side."""
SPAN_ROWS_PER_PARAM = 2.0
"""Representability is decided only when the checks give at least this many rows (3 per check) per
element parameter: with fewer, the slots' many station values fit any column at the checks (a
generic column keeps a fraction ≈ √(1 − N/rows) ≥ 0.7 of its norm outside the span at this ratio);
else nothing is declared represented and every term is searched."""


@dataclass
class EffectTerm:
    """A fitted effect: ``kind``, ``axes`` (words), ``element`` it acts on, ``shape`` parameters
    (period, order), ``coefficients`` (of its basis columns), held-out ``gain_z``."""

    kind: str
    axes: tuple
    element: str
    shape: dict
    coefficients: np.ndarray
    gain_z: float = 0.0
    joint_chi2: float | None = None
    """Wald χ² of the coefficients in the joint fit with the element update (:func:`joint_threshold`)."""
    n_shapes: int = 1
    """Shapes the search tried for this kind and axis on the same fitting checks (periods, orders; 1 without a shape)."""

    def to_dict(self) -> dict:
        return {"kind": self.kind, "axis": "*".join(self.axes), "element": self.element, "shape": self.shape,
                "coefficients": self.coefficients.tolist(), "held_out_gain_z": self.gain_z,
                **({} if self.joint_chi2 is None else {"joint_chi2": self.joint_chi2,
                                                        "joint_chi2_threshold": joint_threshold(self)}),
                "shapes_tried": self.n_shapes}


def joint_threshold(term: EffectTerm) -> float:
    """The Wald χ² a term's coefficients must exceed in the joint fit with the element update (fitting checks
    only, :data:`JOINT_Z`): the one-sided level of ``JOINT_Z`` standard errors, Bonferroni-corrected over the
    shapes tried (the shape is the best of ``n_shapes`` on the same checks), with as many degrees of freedom
    as the term has coefficients."""
    p = scipy.stats.norm.sf(JOINT_Z) / max(int(term.n_shapes), 1)
    return float(scipy.stats.chi2.isf(p, df=max(np.size(term.coefficients), 1)))


def _own_element(machine: MachineTool, word: str) -> str | None:
    a = next(a for a in machine.axes if a.word == word)
    name = f"{'d' if a.kind == 'linear' else 'e'}{'xyz'[a.along]}_{word.lower()}"
    return name if name in machine.slot_names else None


def effect_candidates(machine: MachineTool, conditions: dict) -> list:
    """``(kind, axis words)`` the search tries on this machine with these check columns."""
    lin = [a.word for a in machine.axes if a.kind == "linear" and _own_element(machine, a.word)]
    rot = [a.word for a in machine.axes if a.kind == "rotary" and _own_element(machine, a.word)]
    out = []
    if "temp_c" in conditions:
        out += [("thermal", (w,)) for w in lin]
    out += [("reversal", (w,)) for w in lin + rot if f"dir_{w.lower()}" in conditions]
    out += [("periodic", (w,)) for w in lin]
    out += [("harmonic", (w,)) for w in rot]
    out += [("interaction", (v, w)) for v in lin for w in lin if v != w]   # on v's own element: v*w ≠ w*v
    return out


def full_parameters(elements: ChainElementSet) -> tuple[list, np.ndarray]:
    """Every element parameter of the chain: each slot at each station of its axis (a full turn's
    last station is its first: left out) and the constants, as ``(slot names, stations)`` (−1: a
    constant), the parameters :func:`parameter_matrix` takes."""
    m = elements.machine
    names, stations = [], []
    for a in m.axes:
        if not m.slots_of(a.word):
            continue
        n = elements.stations[a.column].size - (1 if a.full_turn else 0)
        for i in range(n):
            for s in m.slots_of(a.word):
                names.append(s)
                stations.append(i)
    for s in m.constant_slots:
        names.append(s)
        stations.append(-1)
    return names, np.array(stations)


@dataclass
class SlotSpan:
    """The span of the chain's element parameters over a set of points: ``Q`` (3n, rank) an
    orthonormal basis of the columns of ``∂(tool-point error)/∂(parameters)``, its ``rank`` and the
    number of parameters ``n_params`` (pivoted QR, relative tolerance :data:`SPAN_RANK_TOL`)."""

    Q: np.ndarray
    rank: int
    n_params: int

    @classmethod
    def of(cls, elements: ChainElementSet, axes) -> "SlotSpan":
        names, stations = full_parameters(elements)
        M = parameter_matrix(elements.machine, elements, axes, names, stations).reshape(-1, len(names))
        scale = np.linalg.norm(M, axis=0)
        scale[scale == 0] = 1.0
        Q, R, _ = scipy.linalg.qr(M / scale, mode="economic", pivoting=True)
        d = np.abs(np.diag(R))
        rank = int(np.sum(d > SPAN_RANK_TOL * d[0])) if d.size else 0
        return cls(Q[:, :rank], rank, len(names))

    def outside(self, columns) -> np.ndarray:
        """Per column of ``columns`` (n, 3, c): the fraction of its norm outside the span, (c,)."""
        C = np.asarray(columns, float).reshape(-1, np.shape(columns)[-1])
        out = C - self.Q @ (self.Q.T @ C)
        return np.linalg.norm(out, axis=0) / np.maximum(np.linalg.norm(C, axis=0), 1e-300)

    def rank_with(self, columns) -> int:
        """Numerical rank of the span augmented by ``columns`` (n, 3, c): ``rank`` + the columns'
        independent parts above :data:`REPRESENTED_TOL` of their norm."""
        C = np.asarray(columns, float).reshape(-1, np.shape(columns)[-1])
        nrm = np.maximum(np.linalg.norm(C, axis=0), 1e-300)
        out = (C - self.Q @ (self.Q.T @ C)) / nrm
        sv = np.linalg.svd(out, compute_uv=False)
        return self.rank + int(np.sum(sv > REPRESENTED_TOL))


def representable_terms(machine: MachineTool, elements: ChainElementSet, axes, conditions, span=None) -> list:
    """Which effect candidates without a shape parameter (:func:`effect_candidates`: thermal,
    reversal, interaction) the element slots can represent over the points ``axes`` (n, k): the rank
    of the slots' Jacobian (every slot at every station, :func:`full_parameters`) is unchanged by the
    term's columns (less than :data:`REPRESENTED_TOL` of their norm outside the span). Such a term is
    taken up by the element update; it is reported as absorbed, not searched. E.g. an interaction
    V·W on V's own direction is an angular error of V (a function of v) through a lever arm that
    grows with w exactly when moving W moves the tool point relative to V's carriage across v:
    represented then, not otherwise (W carried by V on the workpiece side, or V on the tool side with
    W not beyond it). ``[{"kind", "axis", "element", "outside_fraction", "rank_slots",
    "rank_with_term", "represented"}]`` for every such candidate; ``[]`` when the points give fewer
    than :data:`SPAN_ROWS_PER_PARAM` rows per parameter (not decidable there)."""
    axes = np.asarray(axes, float)
    if span is None:
        if 3 * len(axes) < SPAN_ROWS_PER_PARAM * len(full_parameters(elements)[0]):
            return []
        span = SlotSpan.of(elements, axes)
    Je = machine.error_jacobian(axes)
    out = []
    for kind, words in effect_candidates(machine, conditions):
        if effect_kind(kind).nonlinear:
            continue
        C, el = effect_columns(machine, kind, words, axes, conditions, None, Je)
        if not np.any(C):   # e.g. thermal at a constant reference temperature: nothing to represent
            continue
        frac = float(span.outside(C).max())
        out.append({"kind": kind, "axis": "*".join(words), "element": el, "outside_fraction": frac,
                    "rank_slots": span.rank, "rank_with_term": span.rank_with(C),
                    "represented": bool(frac < REPRESENTED_TOL)})
    return out


def effect_columns(machine: MachineTool, kind: str, words, axes, conditions, shape=None, Je=None):
    """Basis columns (n, 3, c) μm of an effect term per unit coefficient (μm or μrad on its element),
    for a given ``shape`` (``period_mm`` / ``order``)."""
    col = {a.word: j for j, a in enumerate(machine.axes)}
    a = machine.axes[col[words[0]]]
    el = _own_element(machine, words[0])
    Je = machine.error_jacobian(axes) if Je is None else Je
    jcol = Je[:, :, machine.slot_names.index(el)]
    q = axes[:, col[words[0]]]
    rel = q - a.stroke[0]
    if kind == "thermal":
        f = [(conditions["temp_c"] - REF_TEMP_C) * rel]
    elif kind == "reversal":
        f = [0.5 * conditions[f"dir_{words[0].lower()}"]]
    elif kind == "periodic":
        ph = 2 * np.pi * q / shape["period_mm"]
        f = [np.sin(ph), np.cos(ph)]
    elif kind == "harmonic":
        ph = shape["order"] * np.deg2rad(q)
        f = [np.sin(ph), np.cos(ph)]
    elif kind == "interaction":
        b = machine.axes[col[words[1]]]
        f = [rel * (axes[:, col[words[1]]] - b.stroke[0]) / ((a.stroke[1] - a.stroke[0]) * (b.stroke[1] - b.stroke[0]))]
    else:
        raise ValueError(f"unknown effect kind {kind!r}")
    return np.stack([jcol * fi[:, None] for fi in f], axis=2), el


def shape_band(elements: ChainElementSet) -> dict:
    """Per axis word, the shapes a periodic or harmonic term may take (:data:`SHAPE_NYQUIST`): a
    harmonic's lowest order ``{"min_order": N}`` on a rotary axis, a period's upper bound
    ``{"max_period_mm": P}`` on a linear axis. A shape the element stations resolve (at least two
    stations per cycle) is measured by the sweeps as the element's own geometry and carried by its
    station values; only what aliases between the stations is an effect term."""
    m = elements.machine
    out = {}
    for a in m.axes:
        st = np.asarray(elements.stations.get(a.column, ()), float)
        if st.size < 2:
            continue
        step = float(np.max(np.diff(st)))
        if a.kind == "rotary":
            out[a.word] = {"min_order": int(np.floor(360.0 / (SHAPE_NYQUIST * step))) + 1}
        else:
            out[a.word] = {"max_period_mm": SHAPE_NYQUIST * step}
    return out


def _shape_functions(kind, q, shapes) -> np.ndarray:
    """Per-point shape functions (n, G, 2) of the periodic / harmonic ``shapes`` (G) at axis values ``q`` (n,)."""
    if kind == "periodic":
        ph = 2 * np.pi * q[:, None] / np.array([s["period_mm"] for s in shapes])[None]
    else:
        ph = np.deg2rad(q)[:, None] * np.array([s["order"] for s in shapes], float)[None]
    return np.stack([np.sin(ph), np.cos(ph)], axis=2)


def _fit_shape(machine, kind, words, checks, fit_idx, r_fit, Je, response=None, band=None):
    """Best shape (periodogram over the grid) and its columns, fitted on the fitting checks:
    ``(rss, shape, coefficients, element, columns at all checks (n, 3, c), shapes tried)``, ``None`` when the band
    leaves no shape. ``response``: maps an effect's columns (n, 3, c) to what of them is left after
    the element update (the update's linear response removed; module doc of :func:`effect_search`),
    ``response(C, fit_only=True)`` its fitting rows (n_fit, 3, c). ``band``: :func:`shape_band` of the
    axis (None: the whole grid). The grid is scored in one batch (normal equations per shape); the
    best shape is then re-fitted by least squares as a single one."""
    band = band or {}
    if kind == "periodic":
        grid = [{"period_mm": float(p)} for p in PERIOD_GRID_MM if p < band.get("max_period_mm", np.inf)]
    elif kind == "harmonic":
        grid = [{"order": int(n)} for n in HARMONIC_ORDERS if n >= band.get("min_order", 0)]
    else:
        grid = [None]
    if not grid:
        return None
    rf = r_fit.reshape(-1)

    def one(shape):
        C, el = effect_columns(machine, kind, words, checks.axes, checks.conditions, shape, Je)
        if response is not None:
            C = response(C)
        X = C[fit_idx].reshape(-1, C.shape[2])
        c = np.linalg.lstsq(X, rf, rcond=None)[0]
        return float(np.sum((rf - X @ c) ** 2)), shape, c, el, C, len(grid)

    if grid == [None]:
        return one(None)
    col = {a.word: j for j, a in enumerate(machine.axes)}
    jcol = Je[:, :, machine.slot_names.index(_own_element(machine, words[0]))]
    q = checks.axes[:, col[words[0]]]

    def best_of(shapes):
        F = _shape_functions(kind, q, shapes)                              # (n, G, 2)
        C = (jcol[:, :, None, None] * F[:, None]).reshape(len(q), 3, -1)   # (n, 3, 2G): shape g in 2g, 2g+1
        Cf = response(C, fit_only=True) if response is not None else C[fit_idx]
        X = Cf.reshape(-1, len(shapes), 2)                                 # (3 n_fit, G, 2)
        XtX = np.einsum("rgi,rgj->gij", X, X)
        Xtr = np.einsum("rgi,r->gi", X, rf)
        try:
            coef = np.linalg.solve(XtX, Xtr[..., None])[..., 0]
        except np.linalg.LinAlgError:
            coef = np.stack([np.linalg.lstsq(A, b, rcond=None)[0] for A, b in zip(XtX, Xtr)])
        rss = float(rf @ rf) - np.einsum("gi,gi->g", Xtr, coef)
        return int(np.argmin(rss)), rss

    g, rss = best_of(grid)
    shape = grid[g]
    if kind == "periodic":  # refine: over a long stroke a 1.4 % period error drifts by cycles
        p0 = shape["period_mm"]
        fine = [{"period_mm": float(p)} for p in p0 * (1.0 + np.linspace(-PERIOD_REFINE, PERIOD_REFINE, 121))]
        gf, rssf = best_of(fine)
        if rssf[gf] < rss[g]:
            shape = fine[gf]
    return one(shape)


def _paired_z(r_before, r_after) -> float:
    from .plausibility import paired_z
    return paired_z(r_before, r_after)


def effect_search(machine: MachineTool, checks: ChainChecks, residual, fit_idx, hold_idx, max_effects: int = 4,
                  exclude=(), response=None, bands=None):
    """Forward search (module doc): ``(accepted terms, rejected (kind, axes, z) list, residual after)``.
    ``exclude``: ``(kind, words)`` not tried (found, or represented by the slots); ``response``: when the
    residual is an element update's, the map of an effect's columns to what the update leaves of them
    (``C − M·gain·C_fit``): the update has taken up the part of an effect the slots can imitate, so the
    term is fitted and judged by the rest, with its own coefficient. ``bands``: :func:`shape_band`
    (None: every shape of the grids)."""
    Je = machine.error_jacobian(checks.axes)
    r = np.asarray(residual, float).copy()
    cands = effect_candidates(machine, checks.conditions)
    accepted, rejected = [], []
    for _ in range(max_effects):
        scored = []
        for kind, words in cands:
            if any(t.kind == kind and t.axes == words for t in accepted) or (kind, words) in exclude:
                continue
            best = _fit_shape(machine, kind, words, checks, fit_idx, r[fit_idx], Je, response,
                              (bands or {}).get(words[0]))
            if best is not None:
                scored.append((best[0], kind, words) + tuple(best[1:]))
        if not scored:
            break
        scored.sort(key=lambda s: s[0])
        rss, kind, words, shape, c, el, C, n_shapes = scored[0]
        contrib = np.einsum("nic,c->ni", C, c)
        z = _paired_z(r[hold_idx], (r - contrib)[hold_idx])
        if z <= HELD_OUT_Z:
            rejected.append({"kind": kind, "axis": "*".join(words), "held_out_gain_z": z})
            break
        accepted.append(EffectTerm(kind, words, el, shape or {}, c, z, n_shapes=n_shapes))
        r = r - contrib
    return accepted, rejected, r


def sweep_shift(machine: MachineTool, elements: ChainElementSet, term: EffectTerm, slot_names, stations, cov):
    """(N, c): per coefficient of ``term``, what it added to the identified parameters through the
    sweeps — its element sampled at its axis' stations under the sweeps' conditions (reference
    temperature, positive approach): a periodic or harmonic term aliased at the stations, a reversal's
    +b/2. Stations the gauge holds at zero (zero prior variance) take the samples relative to the first
    station's. Thermal (sweeps at 20 °C) and interaction (the other axes parked at their lower ends)
    leave nothing there."""
    N = len(slot_names)
    c = term.coefficients.size
    S = np.zeros((N, c))
    if term.kind not in ("periodic", "harmonic", "reversal"):
        return S
    a = next(a for a in machine.axes if a.word == term.axes[0])
    st = elements.stations[a.column]
    if term.kind == "periodic":
        ph = 2 * np.pi * st / term.shape["period_mm"]
        f = np.stack([np.sin(ph), np.cos(ph)], axis=1)
    elif term.kind == "harmonic":
        ph = term.shape["order"] * np.deg2rad(st)
        f = np.stack([np.sin(ph), np.cos(ph)], axis=1)
    else:
        f = np.full((st.size, 1), 0.5)
    idx = {(s, i): j for j, (s, i) in enumerate(zip(slot_names, stations))}
    j0 = idx.get((term.element, 0))
    if j0 is None:
        return S
    rel = cov[j0, j0] <= 0.0  # station 0 held by the gauge
    for i in range(st.size):
        j = idx.get((term.element, i))
        if j is not None:
            S[j] = f[i] - (f[0] if rel else 0.0)
    return S
