"""The closed loop on ANY machine-tool chain: checks → held-out measured residual, update, effects.

The generic form of :mod:`errormap.diagnosis.loop` (the grinder's), over the machine's axes and
element slots. Check measurements (``docs/reference/file-formats.md``): columns = the machine's axis columns
(``x_mm, y_mm, z_mm, a_deg, c_deg`` …) and ``dx_um, dy_um, dz_um``; optional ``time_s``,
``temp_c``, ``dir_<w>`` (+1/−1 per axis word), ``seq``. Blocked split as the grinder's: the
first ``fit_fraction`` of the checks by ``seq`` fit, the rest is held out (a later time).

Stages, each judged by the MEASURED residual (measurement − prediction) on the held-out checks:

1. **identified** — the sweep identification as it is;
2. **updated** — the element parameters re-estimated from the fitting checks with the sweep
   identification's covariance as the prior (Gaussian, :func:`update_elements`): the tool-point
   error is linear in small changes of the station values (spline basis) and constants through
   the chain's error Jacobian; the check noise σ is estimated with the update (fixed point on
   the residual with its effective degrees of freedom);
3. **updated + effects** — a forward search over the generic effect kinds on every axis the
   kind acts on (:data:`errormap.chain_truth.EFFECT_KINDS`: thermal growth and periodic on
   any linear axis, reversal on any axis, harmonic on any rotary axis, interaction between any
   two linear axes), each term = the chain's error-Jacobian column of the axis' own-direction
   element times the effect's shape; fitted on the fitting checks, accepted only when it
   lowers the held-out squared residual norm, paired per point, by more than
   :data:`HELD_OUT_Z` standard errors (rank order; the first that fails stops the search). The
   accepted effects are then re-fitted JOINTLY with the update (their columns free, the
   elements with the prior; an update made alone takes up part of an effect it can imitate,
   e.g. the mean thermal growth of the fitting period); a term whose coefficients the joint fit
   does not support (Wald χ² at or below :func:`joint_threshold`, fitting checks only) is dropped,
   and the search goes on from there (:data:`ROUNDS`). Periodic and harmonic shapes the element
   stations resolve are not searched (:func:`shape_band`): they are the element's own geometry.

The plain baselines beside them: the unregularised least-squares update (the same parameters
fitted to the fitting checks with no prior, ``baseline_ols_update``; kept instead of the prior update when
its GCV of the chain's own fitting residual is lower, :func:`fitting_gcv`) and OLS of the identified
model's residual on all axis columns (``baseline_ols_linear``). The model handed on is the last stage unless a
plainer one (identified, updated) is better on the held-out checks by more than
:data:`FALLBACK_Z` paired standard errors; ``kept_stage`` says which.

Noise floor of the held-out figure: ``√3·σ`` (vector norm of isotropic noise σ per axis) with
σ given (``noise_um``) or estimated by the update.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.stats
from scipy.interpolate import make_interp_spline

from ..effect_kinds import effect_kind
from ..io import InputError, read_table
from ..machine_tool import MachineTool
from ..chain_elements import ChainElementSet
from ..stats import residual_stats
from ..units import temperature_mistake
from .plausibility import stated_noise

ERROR_COLUMNS = ("dx_um", "dy_um", "dz_um")
MAX_ERROR_UM = 5000.0
"""Largest plausible measured error component (μm), as the grinder's checks."""
STROKE_TOL = 1e-6
MIN_CHECKS = 10
FALLBACK_Z = 2.0
"""A plainer stage replaces the final one when it lowers the held-out squared residual norm, paired per
point, by more than 2 standard errors (one-sided p ≈ 0.02), as the grinder's loop."""
HELD_OUT_Z = 3.0
"""An effect is accepted when it lowers the held-out squared residual norm, paired per point, by more than
3 standard errors (one-sided p ≈ 0.001; a few candidates in rank order), as the grinder's loop."""
JOINT_Z = HELD_OUT_Z
"""A term accepted on the held-out checks stays only if the joint fit with the element update (the fitting
checks, the update's prior and smoothness prior) still gives its coefficients a Wald χ² above the level of
this many standard errors, corrected for the shapes tried (:func:`joint_threshold`): an update made before
the term was found (its σ inflated by the unmodelled effect) leaves element geometry behind that a term can
take up, and the joint fit gives it back to the elements. Decided on development seeds 100–114 (a 2.3 mm
periodic term on X at held-out z 3.05, joint χ² 2.2, threshold 28; every simulated effect above 60)."""
SIGMA_ITERATIONS = 8
"""Fixed-point steps of the check-noise estimate in the update (converges in a few)."""
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
ROUNDS = 2
"""Update/search rounds: from the second on the update is made jointly with the effects found (so that it
does not take an effect up), then the search goes on (as the grinder's loop re-fits jointly)."""
REF_TEMP_C = 20.0
SMOOTH_GRID = np.r_[0.0, np.geomspace(0.1, 1e4, 21)]
"""Weights of the update's smoothness prior tried by GCV on the fitting checks: 0 (the sweep prior alone)
and 0.1–10⁴, a factor 1.78 apart (on the 5-axis machine GCV picks 3–200; the GCV curve is flat within a
factor 2 of its minimum)."""
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
OLS_RCOND = 1e-6
"""The plain least-squares baseline drops directions whose singular value is below this fraction of the
largest (numerically undetermined by the checks; min-norm there), else it returns values beyond any machine."""


@dataclass
class MTChecks:
    """Checks of a machine tool in ``seq`` order: ``axes`` (n, k), ``measured_um`` (n, 3),
    ``conditions`` (name -> (n,)), ``seq`` (n,), ``rows`` (n,) file lines."""

    axes: np.ndarray
    measured_um: np.ndarray
    conditions: dict = field(default_factory=dict)
    seq: np.ndarray | None = None
    rows: np.ndarray | None = None
    path: str = "<checks>"
    stated_noise_um: float | None = None
    """The instrument's noise σ per coordinate (μm) the file states (a ``# noise_um: σ`` header line), or None."""

    def __post_init__(self):
        n = len(self.axes)
        self.seq = np.arange(n) if self.seq is None else np.asarray(self.seq, dtype=np.int64)
        self.rows = np.zeros(n, dtype=np.int64) if self.rows is None else np.asarray(self.rows)
        o = np.argsort(self.seq, kind="stable")
        self.axes, self.measured_um = np.asarray(self.axes, float)[o], np.asarray(self.measured_um, float)[o]
        self.conditions = {k: np.asarray(v, float)[o] for k, v in self.conditions.items()}
        self.seq, self.rows = self.seq[o], self.rows[o]

    def __len__(self):
        return len(self.axes)

    @classmethod
    def from_columns(cls, machine: MachineTool, cols: dict, path: str = "<checks>") -> "MTChecks":
        axes = np.stack([np.asarray(cols[c], float) for c in machine.axis_columns], axis=1)
        meas = np.stack([np.asarray(cols[c], float) for c in ERROR_COLUMNS], axis=1)
        cond = {k: np.asarray(v, float) for k, v in cols.items() if k in condition_columns(machine)}
        return cls(axes, meas, cond, cols.get("seq"), None, path)


def condition_columns(machine: MachineTool) -> tuple:
    return ("time_s", "temp_c") + tuple(f"dir_{a.word.lower()}" for a in machine.axes)


def load_mt_checks(path, machine: MachineTool, units: str = "check") -> MTChecks:
    """Read and validate a machine tool's check CSV (module doc); errors name file, row, column."""
    t = read_table(path, "checks")
    t.require(*machine.axis_columns, *ERROR_COLUMNS)
    if len(t) < MIN_CHECKS:
        raise InputError(f"{path}: expected at least {MIN_CHECKS} check measurements, got {len(t)}")
    rows = np.array([t.row_number(k) for k in range(len(t))])
    axes = np.stack([t.float(c) for c in machine.axis_columns], axis=1)
    meas = np.stack([t.float(c) for c in ERROR_COLUMNS], axis=1)
    bad = np.argwhere(np.abs(meas) > MAX_ERROR_UM)
    if bad.size:
        k, j = bad[0]
        raise InputError(f"{path}: row {rows[k]}, column '{ERROR_COLUMNS[j]}': units do not fit: {meas[k, j]:g} μm is "
                         f"beyond the plausible {MAX_ERROR_UM:g} μm; expected an error in μm (not nm, not a position)")
    for j, a in enumerate(machine.axes):
        if a.full_turn:
            continue
        lo, hi = a.stroke
        out = np.flatnonzero((axes[:, j] < lo - STROKE_TOL * max(1, abs(lo))) | (axes[:, j] > hi + STROKE_TOL * max(1, abs(hi))))
        if out.size:
            k = out[0]
            raise InputError(f"{path}: row {rows[k]}, column '{a.column}': check point outside the stroke "
                             f"[{lo:g}, {hi:g}] {a.unit}: {axes[k, j]:g}")
    if units == "check" and len(axes) >= MIN_CHECKS:  # metres for mm, radians for degrees (as the grinder's check)
        for j, a in enumerate(machine.axes):
            span, stroke = float(np.ptp(axes[:, j])), a.stroke[1] - a.stroke[0]
            k = int(np.argmax(np.abs(axes[:, j])))
            if (a.kind == "linear" and 0 < span <= stroke / 200 and span * 1000 >= stroke / 4
                    and np.abs(axes[:, j]).max() <= 1.5e-3 * max(abs(a.stroke[0]), abs(a.stroke[1]))):
                raise InputError(f"{path}: row {rows[k]}, column '{a.column}': units do not fit: values span only "
                                 f"{span:.4g} mm of the {stroke:g} mm stroke; 1000x that fits it: metres rather than mm? "
                                 "(--units as-written if they are mm)")
            on_grid = np.allclose(axes[:, j] * 2, np.round(axes[:, j] * 2), rtol=0, atol=1e-9)
            if (a.kind == "rotary" and stroke >= 180 and np.all(np.abs(axes[:, j]) <= 2 * np.pi + 1e-6)
                    and span >= 1.5 * np.pi and not on_grid):
                raise InputError(f"{path}: row {rows[k]}, column '{a.column}': units do not fit: values lie within "
                                 f"±2π and span {span:.4g}: radians rather than degrees? (--units as-written if degrees)")
    cond = {}
    for c in condition_columns(machine):
        if c in t:
            cond[c] = t.int(c, allowed=(-1, 1)).astype(float) if c.startswith("dir_") else t.float(c)
    if "temp_c" in cond:
        m = temperature_mistake(cond["temp_c"], units)
        if m is not None:
            raise InputError(f"{path}: row {rows[m[0]]}, column 'temp_c': units do not fit: {m[1]}")
    seq = t.int("seq") if "seq" in t else None
    if seq is not None:
        u, first = np.unique(seq, return_index=True)
        if u.size != seq.size:
            dup = np.setdiff1d(np.arange(seq.size), first)[0]
            raise InputError(f"{path}: row {rows[dup]}, column 'seq': duplicated value {seq[dup]}")
    return MTChecks(axes, meas, cond, seq, rows, str(path), stated_noise(path, t.comments))


# -- the update ---------------------------------------------------------------------------------
def spline_basis(stations, x, full_turn: bool) -> np.ndarray:
    """Values at ``x`` (n,) of the interpolating cubic spline through each unit station vector,
    (n, m); on a full turn the first station's column carries the closed pair (first = last)
    and the last column is zero (its value is the first's)."""
    m = len(stations)
    Y = np.eye(m)
    if full_turn:
        Y[-1, 0] = 1.0
        Y[:, -1] = 0.0
        Y[-1, -1] = 0.0
        x = stations[0] + np.mod(np.asarray(x, float) - stations[0], 360.0)
    return make_interp_spline(stations, Y, k=3, bc_type="periodic" if full_turn else None)(x)


def parameter_matrix(machine: MachineTool, elements: ChainElementSet, axes, slot_names, stations) -> np.ndarray:
    """∂(tool-point error, μm)/∂(element parameters), (n, 3, N): parameter j is slot ``slot_names[j]`` at
    station ``stations[j]`` (−1: a constant), linearised at ``elements``."""
    axes = np.atleast_2d(np.asarray(axes, float))
    Je = machine.error_jacobian(axes, elements.values(axes))           # (n, 3, P)
    sidx = {n: j for j, n in enumerate(machine.slot_names)}
    slot = {s.name: s for s in machine.slots}
    col = {a.word: j for j, a in enumerate(machine.axes)}
    basis = {}
    M = np.zeros((axes.shape[0], 3, len(slot_names)))
    for j, (s, i) in enumerate(zip(slot_names, stations)):
        if i < 0:
            M[:, :, j] = Je[:, :, sidx[s]]
            continue
        w = slot[s].axis
        if w not in basis:
            a = machine.axes[col[w]]
            basis[w] = spline_basis(elements.stations[a.column], axes[:, col[w]], a.full_turn)
        M[:, :, j] = Je[:, :, sidx[s]] * basis[w][:, i, None]
    return M


def apply_parameters(elements: ChainElementSet, slot_names, stations, delta) -> ChainElementSet:
    """``elements`` with ``delta`` added to its parameters (module doc of :func:`parameter_matrix`)."""
    out = elements.copy()
    fun = {k: v.copy() for k, v in out.functions.items()}
    const = dict(out.constants)
    for s, i, d in zip(slot_names, stations, delta):
        if i < 0:
            const[s] += float(d)
        else:
            fun[s][i] += float(d)
    for a in elements.machine.axes:  # a full turn stays closed
        if a.full_turn:
            for s in elements.machine.slots_of(a.word):
                fun[s][-1] = fun[s][0]
    return ChainElementSet(elements.machine, out.stations, fun, const, elements.machine_name, elements.machine_sha256)


def parameter_values(elements: ChainElementSet, slot_names, stations) -> np.ndarray:
    """The element parameters of ``elements`` as a vector (N,) in the order of ``slot_names`` /
    ``stations`` (station −1: a constant), μm or μrad."""
    return np.array([elements.constants[s] if i < 0 else elements.functions[s][i] for s, i in zip(slot_names, stations)])


def second_differences(elements: ChainElementSet, slot_names, stations, M) -> np.ndarray:
    """The roughness operator of the smoothness prior, (R, N): one row per element slot and interior
    station of its axis, the second divided difference of the slot's station values along its axis
    (times the squared mean station spacing: a plain second difference on equal spacing; cyclic over a
    full turn, whose last station is its first), scaled by the slot's RMS tool-point sensitivity over
    the checks (the mean column RMS of its station parameters in ``M`` (rows, N), μm per μm or μrad):
    ``‖D·θ‖²`` is a roughness in tool-point μm², so one weight fits slots of both units. Constants
    have no rows."""
    machine = elements.machine
    slot = {s.name: s for s in machine.slots}
    idx = {(s, int(i)): j for j, (s, i) in enumerate(zip(slot_names, stations))}
    colrms = np.sqrt(np.mean(np.asarray(M, float) ** 2, axis=0))
    rows = []
    for s in machine.function_slots:
        a = next(a for a in machine.axes if a.word == slot[s].axis)
        st = np.asarray(elements.stations[a.column], float)
        m = st.size
        js = [idx.get((s, i)) for i in range(m)]
        if a.full_turn:          # stations 0..m-2 on a circle; m-1 is station 0 again
            m -= 1
            js = js[:m]
            pos = st[:m]
            nxt = lambda i: (i + 1) % m  # noqa: E731
            prv = lambda i: (i - 1) % m  # noqa: E731
            inner = range(m)
        else:
            pos = st
            nxt, prv = (lambda i: i + 1), (lambda i: i - 1)
            inner = range(1, m - 1)
        known = [j for j in js if j is not None]
        if m < 3 or not known:
            continue
        scale = float(np.mean(colrms[known]))
        hbar = (st[-1] - st[0]) / (st.size - 1)
        for i in inner:
            h1 = (pos[i] - pos[prv(i)]) % 360.0 if a.full_turn else pos[i] - pos[prv(i)]
            h2 = (pos[nxt(i)] - pos[i]) % 360.0 if a.full_turn else pos[nxt(i)] - pos[i]
            w = 2.0 * hbar**2 / (h1 + h2)
            row = np.zeros(len(slot_names))
            for j, c in ((js[prv(i)], w / h1), (js[i], -w / h1 - w / h2), (js[nxt(i)], w / h2)):
                if j is not None:
                    row[j] += c * scale
            rows.append(row)
    return np.array(rows).reshape(-1, len(slot_names))


@dataclass
class ChainUpdate:
    """``elements_`` the updated set, ``sigma_um`` the check noise estimated with it, ``dof`` the
    effective number of parameters the checks moved; ``smoothing`` the weight of the smoothness
    prior used and ``gcv`` the table ``[{"weight", "gcv", "dof"}]`` it was chosen from (GCV on the
    fitting checks; weight 0 = the sweep prior alone)."""

    elements_: ChainElementSet
    sigma_um: float
    dof: float
    extra_coef: np.ndarray | None = None
    smoothing: float = 0.0
    gcv: list = field(default_factory=list)
    gcv_value: float = float("nan")
    gain: np.ndarray | None = None
    """(N, 3n) the change of the element parameters per unit change of the fitting residual (flattened)
    at the chosen weight and noise; ``None`` when effect columns were fitted jointly."""
    extra_cov: np.ndarray | None = None
    """(c, c) posterior covariance of ``extra_coef`` (the elements' prior and the smoothness prior
    marginalised: ``σ²·(A⁻¹)`` of the effect block), ``None`` without effect columns."""
    plain: "ChainUpdate | None" = None
    """With ``with_plain``: the update at weight 0 (the sweep prior alone), from the same solves."""


def check_smoothing(smoothing) -> None:
    """``"gcv"`` or a weight ≥ 0 (finite)."""
    if isinstance(smoothing, str):
        if smoothing != "gcv":
            raise ValueError(f"Expected smoothing 'gcv' or a weight >= 0, got {smoothing!r}")
        return
    if not (np.isfinite(smoothing) and smoothing >= 0):
        raise ValueError(f"Expected smoothing 'gcv' or a finite weight >= 0, got {smoothing!r}")


def _cho_inverse(f) -> np.ndarray:
    """The inverse (N, N) of a matrix from its ``scipy.linalg.cho_factor`` (LAPACK potri: a third of the
    work of solving for N right-hand sides)."""
    c, lower = f
    inv, info = scipy.linalg.lapack.dpotri(c, lower=lower)
    if info != 0:
        raise np.linalg.LinAlgError(f"potri failed (info {info})")
    tri = np.tril(inv) if lower else np.triu(inv)
    return tri + tri.T - np.diag(np.diag(tri))


def update_elements(elements: ChainElementSet, slot_names, stations, cov, axes_fit, residual_fit,
                    extra=None, extra_shift=None, smoothing="gcv", with_plain: bool = False) -> ChainUpdate:
    """Gaussian update of the element parameters from check residuals (n, 3) μm at ``axes_fit`` (n, k).

    Model: the sweep identification measured the parameters, ``θ_id ~ N(θ, cov)`` (``cov`` (N, N)
    its covariance, gauge directions of zero variance held); the checks measure ``r = M·Δθ + noise``
    (σ per coordinate, estimated: fixed point on the residual with its effective degrees of freedom);
    a smoothness prior on the UPDATED values along each axis, ``weight·‖D·(θ_id + Δθ)‖²/σ²``
    (:func:`second_differences`; the sweeps' station noise is white along the stations, the
    geometry is not). ``smoothing``: the weight, or ``"gcv"``: chosen on :data:`SMOOTH_GRID`
    (0 included: the sweep prior alone) by generalised cross-validation on the fitting checks
    (``n·RSS/(n − dof)²``), never on held-out checks.

    ``extra`` (n, 3, c): effect columns fitted jointly with no prior (their coefficients in
    ``ChainUpdate.extra_coef``); ``extra_shift`` (N, c): what each effect coefficient put into the
    identified parameters during the sweeps (its samples at the stations): the measured values are
    ``θ_id − extra_shift·coef`` and the smoothness prior applies to those. ``with_plain``: also the
    update at weight 0 (``ChainUpdate.plain``; the grid holds weight 0, solved at the noise of weight 0:
    the same as ``smoothing=0.0``)."""
    check_smoothing(smoothing)
    m = elements.machine
    N = len(slot_names)
    M = parameter_matrix(m, elements, axes_fit, slot_names, stations).reshape(-1, N)
    r = np.asarray(residual_fit, float).reshape(-1)
    c = 0 if extra is None else np.shape(extra)[-1]
    S = np.zeros((N, c)) if extra_shift is None or extra is None else np.asarray(extra_shift, float)
    lam, U = np.linalg.eigh(0.5 * (cov + cov.T))
    keep = lam > 1e-12 * lam.max()
    L = U[:, keep] * np.sqrt(lam[keep])                                  # Δθ = L·z − S·b, z ~ N(0, I)
    K = L.shape[1]
    X = M @ L
    if c:
        E = np.asarray(extra, float).reshape(-1, c) - M @ S
        X = np.hstack([X, E])
    D = second_differences(elements, slot_names, stations, M)
    G = D @ np.hstack([L, -S])                                           # roughness of the update
    d0 = D @ parameter_values(elements, slot_names, stations)           # roughness of the identified values
    XtX, Xtr, GtG, Gtd = X.T @ X, X.T @ r, G.T @ G, G.T @ d0
    prior = np.r_[np.ones(K), np.zeros(c)]

    def solve(weight, s2):
        A = XtX + s2 * (np.diag(prior) + weight * GtG)
        try:
            f = scipy.linalg.cho_factor(A)
            w = scipy.linalg.cho_solve(f, Xtr - s2 * weight * Gtd)
            dof = float(np.sum(_cho_inverse(f) * XtX))     # trace(A⁻¹·XᵀX), both symmetric
        except np.linalg.LinAlgError:   # an effect column the elements can imitate exactly: min-norm
            Ai = np.linalg.pinv(A)
            w, dof = Ai @ (Xtr - s2 * weight * Gtd), float(np.trace(Ai @ XtX))
        return w, dof, float(np.sum((r - X @ w) ** 2))

    def noise(weight):
        s2 = float(np.mean(r**2))
        for _ in range(SIGMA_ITERATIONS):
            _, dof, rss = solve(weight, s2)
            s2 = rss / max(r.size - dof, 1.0)
        return s2

    s2 = noise(0.0)
    table = []
    grid = SMOOTH_GRID if smoothing == "gcv" else [float(smoothing)]
    sol = {}
    for weight in grid:
        sol[float(weight)] = w, dof, rss = solve(float(weight), s2)
        table.append({"weight": float(weight), "gcv": r.size * rss / max(r.size - dof, 1.0) ** 2, "dof": dof})
    plain = None
    if with_plain and not c and 0.0 in sol:   # the sweep prior alone (weight 0 at its own noise), from the same solves
        w0, dof0, _ = sol[0.0]
        t0 = next(t for t in table if t["weight"] == 0.0)
        plain = ChainUpdate(apply_parameters(elements, slot_names, stations, L @ w0), float(np.sqrt(s2)), dof0, None,
                            0.0, [t0], t0["gcv"])
    best = min(table, key=lambda t: t["gcv"])
    weight = best["weight"]
    if weight > 0:
        s2 = noise(weight)
    w, dof, _ = solve(weight, s2)
    z, coef = w[:K], (w[K:] if c else None)
    delta = L @ z - (S @ coef if c else 0.0)
    gain, extra_cov = None, None
    A = XtX + s2 * (np.diag(prior) + weight * GtG)
    if not c:
        gain = L @ np.linalg.solve(A, X.T)
    else:
        extra_cov = s2 * np.linalg.pinv(A)[K:, K:]
    return ChainUpdate(apply_parameters(elements, slot_names, stations, delta), float(np.sqrt(s2)), dof - c, coef,
                       weight, table, best["gcv"], gain, extra_cov, plain)


def ols_update(elements: ChainElementSet, slot_names, stations, axes_fit, residual_fit,
               return_gcv: bool = False):
    """The plain baseline: the same parameters fitted to the fitting checks by unregularised least
    squares (minimum norm over the directions above :data:`OLS_RCOND`), no prior. ``return_gcv``:
    also its GCV on the fitting checks (``n·RSS/(n − rank)²``), the figure the update is compared with,
    RSS of the chain's own residual with the fitted elements (:func:`fitting_gcv`), not of the
    linearisation: a large unregularised step leaves the linear range of the chain (a fit whose
    linear residual is 12 μm left 974 μm through the chain on a development seed)."""
    M = parameter_matrix(elements.machine, elements, axes_fit, slot_names, stations).reshape(-1, len(slot_names))
    r = np.asarray(residual_fit, float).reshape(-1)
    delta, _, rank, _ = np.linalg.lstsq(M, r, rcond=OLS_RCOND)
    el = apply_parameters(elements, slot_names, stations, delta)
    if not return_gcv:
        return el
    return el, fitting_gcv(elements, el, axes_fit, residual_fit, float(rank))


def fitting_gcv(elements: ChainElementSet, updated: ChainElementSet, axes_fit, residual_fit, dof: float) -> float:
    """GCV ``n·RSS/(n − dof)²`` on the fitting checks of an updated element set, RSS of the chain's own
    residual: ``residual_fit`` (n, 3) of ``elements`` minus the change of the chain's prediction at
    ``axes_fit`` (n, k), so that a step beyond the linear range is judged by what it does."""
    from ..chain_field import ChainField
    m = elements.machine
    r = np.asarray(residual_fit, float) - (ChainField(m, updated).predict(axes_fit) - ChainField(m, elements).predict(axes_fit))
    return r.size * float(np.sum(r**2)) / (r.size - dof) ** 2 if r.size > dof else float("inf")


# -- effects ------------------------------------------------------------------------------------
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


def effect_search(machine: MachineTool, checks: MTChecks, residual, fit_idx, hold_idx, max_effects: int = 4,
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


# -- the loop -----------------------------------------------------------------------------------
def closed_loop_chain(machine: MachineTool, elements: ChainElementSet, checks: MTChecks, cov=None,
                      fit_fraction: float = 0.6, noise_um: float | None = None, effects: bool = True,
                      max_effects: int = 4, smoothing="gcv", units: str = "check") -> dict:
    """Run the stages (module doc) and return the summary dict (``stages`` with held-out/fitting
    statistics, ``kept_stage``, ``noise_floor_um``, ``effects``) and, under ``"_models"``, the element
    sets of the stages (not JSON). Before any estimate, the deviations are checked against the identified
    model's prediction and the stated noise (``noise_um``, else the file's): another unit or another axis
    order is refused (:func:`errormap.diagnosis.plausibility.check_deviations`; ``units="as-written"`` skips
    the unit gate)."""
    if not 0 < fit_fraction < 1:
        raise ValueError(f"Expected 0 < fit_fraction < 1, got {fit_fraction}")
    check_smoothing(smoothing)
    n = len(checks)
    n_fit = int(round(fit_fraction * n))
    if n_fit < 5 or n - n_fit < 5:
        raise ValueError(f"Expected at least 5 fitting and 5 held-out checks, got {n_fit} and {n - n_fit}")
    fit_idx, hold_idx = np.arange(n_fit), np.arange(n_fit, n)
    from ..chain_field import ChainField

    def resid(el):
        return checks.measured_um - ChainField(machine, el).predict(checks.axes)

    def stats(r):
        return {"held_out": residual_stats(r[hold_idx], ERROR_COLUMNS), "fitting": residual_stats(r[fit_idx], ERROR_COLUMNS)}

    from .plausibility import check_deviations, noise_record
    stated = noise_um if noise_um is not None else checks.stated_noise_um
    pred0 = ChainField(machine, elements).predict(checks.axes)
    check_deviations(checks.path, checks.measured_um, pred0, rows=checks.rows, noise_um=stated, units=units)
    r0 = checks.measured_um - pred0
    stages = {"identified": stats(r0)}
    models = {"identified": elements}
    resid_of = {"identified": r0}
    sigma, prior = None, None
    baseline_resid = {}   # the plain baselines' residuals (n, 3): the kept model must not lose to them
    if cov is not None:
        slot_names, stations, C = cov
        upd = update_elements(elements, slot_names, stations, C, checks.axes[fit_idx], r0[fit_idx], smoothing=smoothing,
                              with_plain=True)
        plain = upd.plain if upd.plain is not None else update_elements(
            elements, slot_names, stations, C, checks.axes[fit_idx], r0[fit_idx], smoothing=0.0)
        stages["baseline_update_sweep_prior"] = stats(resid(plain.elements_))   # the update without the smoothness prior
        stages["baseline_update_sweep_prior"]["gcv"] = plain.gcv_value
        ols_el, ols_gcv = None, float("inf")
        try:
            ols_el, ols_gcv = ols_update(elements, slot_names, stations, checks.axes[fit_idx], r0[fit_idx], return_gcv=True)
            stages["baseline_ols_update"] = stats(resid(ols_el))
            baseline_resid["baseline_ols_update"] = resid(ols_el)
            stages["baseline_ols_update"]["gcv"] = ols_gcv
        except ValueError as exc:  # the unregularised fit left the machine's range: reported, not used
            stages["baseline_ols_update"] = {"failed": str(exc)}
        upd_gcv = fitting_gcv(elements, upd.elements_, checks.axes[fit_idx], r0[fit_idx], upd.dof)
        prior = {"smoothing_weight": upd.smoothing, "chosen_by": "GCV on the fitting checks" if smoothing == "gcv"
                 else "given", "gcv": upd.gcv_value, "gcv_table": upd.gcv, "gcv_chain": upd_gcv,
                 "gcv_ols_update": ols_gcv if np.isfinite(ols_gcv) else None,
                 "gcv_compared": "n·RSS/(n − dof)² of the chain's own residual on the fitting checks",
                 "kept": "update with the smoothness prior"}
        if ols_el is not None and ols_gcv < upd_gcv:   # never keep a prior that loses to the plain fit
            upd = ChainUpdate(ols_el, upd.sigma_um, float(len(slot_names)), None, 0.0, upd.gcv, ols_gcv)
            prior["kept"] = "the unregularised least-squares update (lower GCV on the fitting checks)"
        r1 = resid(upd.elements_)
        stages["updated"] = stats(r1)
        stages["updated"]["dof"] = upd.dof
        stages["updated"]["smoothing_weight"] = upd.smoothing
        models["updated"], resid_of["updated"] = upd.elements_, r1
        sigma = upd.sigma_um
    from .plausibility import ols_linear_baseline   # the plainest: the residual linear in the axes
    baseline_resid["baseline_ols_linear"] = ols_linear_baseline(checks.axes, r0, fit_idx)
    stages["baseline_ols_linear"] = stats(baseline_resid["baseline_ols_linear"])
    last = "updated" if "updated" in models else "identified"
    accepted, rejected, dropped = [], [], []
    absorbed, response = [], None
    if effects:
        terms = representable_terms(machine, elements, checks.axes, checks.conditions)
        absorbed = [{**t, "note": f"{t['kind']} {t['axis']} on {t['element']}: the element slots represent this term "
                     f"over the checks (rank {t['rank_slots']} with and without it; "
                     f"{t['outside_fraction']:.1e} of it outside their span), so the element update absorbs it: "
                     "it is in the updated elements, not a missed effect"} for t in terms if t["represented"]]
        exclude = [(t["kind"], tuple(t["axis"].split("*"))) for t in absorbed]
        if last == "updated" and upd.gain is not None:   # what the update leaves of an effect's columns
            Mall = parameter_matrix(machine, elements, checks.axes, slot_names, stations).reshape(-1, len(slot_names))
            Mfit = Mall.reshape(n, 3, -1)[fit_idx].reshape(-1, len(slot_names))
            gain = upd.gain

            def response(Cols, fit_only=False):
                Cf = Cols[fit_idx].reshape(-1, Cols.shape[2])
                if fit_only:
                    return (Cf - Mfit @ (gain @ Cf)).reshape(len(fit_idx), 3, -1)
                return Cols - (Mall @ (gain @ Cf)).reshape(Cols.shape)
        bands = shape_band(elements)
        accepted, rejected, r2 = effect_search(machine, checks, resid_of[last], fit_idx, hold_idx, max_effects,
                                               exclude=exclude, response=response, bands=bands)
        def joint(terms):   # the update made jointly with the terms (their columns free), each term's Wald χ²
            E = np.concatenate([effect_columns(machine, t.kind, t.axes, checks.axes, checks.conditions, t.shape or None)[0]
                                for t in terms], axis=2)
            shift = np.concatenate([sweep_shift(machine, elements, t, slot_names, stations, C) for t in terms], axis=1)
            u = update_elements(elements, slot_names, stations, C, checks.axes[fit_idx], r0[fit_idx], extra=E[fit_idx],
                                extra_shift=shift, smoothing=smoothing)
            k = 0
            for t in terms:
                c = t.coefficients.size
                t.coefficients, k = u.extra_coef[k:k + c], k + c
                cv = u.extra_cov[k - c:k, k - c:k]
                t.joint_chi2 = float(t.coefficients @ np.linalg.pinv(cv) @ t.coefficients)
            return u, resid(u.elements_) - np.einsum("nic,c->ni", E, u.extra_coef)

        dropped = []
        pending, rounds_left = bool(accepted), ROUNDS - 1
        while pending and last == "updated":  # joint fit, the weak terms dropped, then the search goes on (once)
            u, r_joint = joint(accepted)
            weak = [t for t in accepted if t.joint_chi2 <= joint_threshold(t)]
            if weak:
                dropped += [{"kind": t.kind, "axis": "*".join(t.axes), "shape": t.shape, "held_out_gain_z": t.gain_z,
                             "joint_chi2": t.joint_chi2, "joint_chi2_threshold": joint_threshold(t)} for t in weak]
                accepted = [t for t in accepted if t not in weak]
                u, r_joint = joint(accepted) if accepted else (None, resid_of["updated"])
            if u is not None:
                models["joint"], sigma = u.elements_, u.sigma_um
            else:
                models.pop("joint", None)
                sigma = upd.sigma_um
            r2 = r_joint
            if rounds_left == 0:
                break
            rounds_left -= 1
            more, rejected, r_more = effect_search(
                machine, checks, r_joint, fit_idx, hold_idx, max_effects - len(accepted),
                exclude=exclude + [(t.kind, t.axes) for t in accepted] + [(d["kind"], tuple(d["axis"].split("*"))) for d in dropped],
                response=response, bands=bands)
            accepted += more
            pending = bool(more)
            if not more:
                r2 = r_more
        if accepted and "joint" in models:
            models["updated_plus_effects"] = models["joint"]
        stages["updated_plus_effects" if last == "updated" else "identified_plus_effects"] = stats(r2)
        resid_of["plus_effects"] = r2
    final = "plus_effects" if effects else last
    kept, why = final, "kept: no plainer stage is better on the held-out checks by more than "\
                       f"{FALLBACK_Z} paired standard errors"
    for plain in ("identified", "updated"):
        if plain in resid_of and plain != final:
            z = _paired_z(resid_of[kept][hold_idx], resid_of[plain][hold_idx])
            if z > FALLBACK_Z:
                kept, why = plain, f"fell back to {plain}: better on the held-out checks by paired z = {z:.2f}"
    sig = noise_um if noise_um is not None else sigma
    refit = None
    if kept in ("updated", "plus_effects") and last == "updated":
        ols_kept = prior is not None and prior["kept"] != "update with the smoothness prior"

        def refit(terms, offset_um, idx):
            """The kept stage's update re-estimated on the checks ``idx`` with ``offset_um`` (n, 3) μm taken off the
            identified model's residual (what another part of the model explains: the learned residual's
            backfitting, :func:`compensation.hybrid.learned_stage`) — jointly with ``terms`` (copies, their
            coefficients re-estimated) when there are any, else the update the loop kept (with the smoothness prior,
            its weight by the loop's rule, or the unregularised one when the loop kept that). → ``(elements, terms,
            residual at every check (n, 3))``."""
            import copy
            idx = np.asarray(idx)
            t = r0 - np.asarray(offset_um, dtype=float)
            if not terms:
                if ols_kept:
                    el = ols_update(elements, slot_names, stations, checks.axes[idx], t[idx])
                else:
                    el = update_elements(elements, slot_names, stations, C, checks.axes[idx], t[idx],
                                         smoothing=smoothing).elements_
                return el, [], resid(el)
            E = np.concatenate([effect_columns(machine, q.kind, q.axes, checks.axes, checks.conditions, q.shape or None)[0]
                                for q in terms], axis=2)
            shift = np.concatenate([sweep_shift(machine, elements, q, slot_names, stations, C) for q in terms], axis=1)
            u = update_elements(elements, slot_names, stations, C, checks.axes[idx], t[idx], extra=E[idx],
                                extra_shift=shift, smoothing=smoothing)
            out, k = [], 0
            for q in terms:
                c = q.coefficients.size
                q = copy.copy(q)
                q.coefficients, k = np.array(u.extra_coef[k:k + c]), k + c
                out.append(q)
            return u.elements_, out, resid(u.elements_) - np.einsum("nic,c->ni", E, u.extra_coef)
    kept_name = {"plus_effects": "updated_plus_effects" if last == "updated" else "identified_plus_effects"}.get(kept, kept)
    held = stages[kept_name]["held_out"]["rms_um"]
    baselines = {k: {"held_out_rms_um": stages[k]["held_out"]["rms_um"],
                     "paired_z_over_kept": _paired_z(resid_of[kept][hold_idx], r[hold_idx])}
                 for k, r in baseline_resid.items()}
    return {"machine": machine.name, "machine_sha256": machine.sha256, "n_checks": n, "n_fit": n_fit, "n_held_out": n - n_fit,
            "split": f"blocked by seq: first {fit_fraction:g} fit, the rest held out",
            "stages": stages, "kept_stage": kept_name, "kept_why": why, "update_prior": prior,
            "effects": [t.to_dict() for t in accepted], "effects_rejected": rejected, "effects_absorbed": absorbed,
            "effects_dropped_in_joint_fit": dropped,
            "noise_sigma_um": sig, "baselines_vs_kept": baselines, "held_out_rms_um": held,
            **noise_record(noise_um, sigma, held, stated),
            "_models": {"elements": models.get("updated_plus_effects" if kept == "plus_effects" else kept,
                                               models.get("updated", elements)), "terms": accepted,
                        "refit": refit}}
