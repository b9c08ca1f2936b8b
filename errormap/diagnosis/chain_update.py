"""The element update of the closed loop on a machine-tool chain: the station values (spline basis) and constants
re-estimated from the fitting checks with the sweep identification's covariance as the prior and a smoothness
prior chosen by GCV (:func:`update_elements`), the unregularised least-squares baseline (:func:`ols_update`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from scipy.interpolate import make_interp_spline

from ..machine_tool import MachineTool
from ..chain_elements import ChainElementSet

SIGMA_ITERATIONS = 8
"""Fixed-point steps of the check-noise estimate in the update (converges in a few)."""
SMOOTH_GRID = np.r_[0.0, np.geomspace(0.1, 1e4, 21)]
"""Weights of the update's smoothness prior tried by GCV on the fitting checks: 0 (the sweep prior alone)
and 0.1–10⁴, a factor 1.78 apart (on the 5-axis machine GCV picks 3–200; the GCV curve is flat within a
factor 2 of its minimum)."""
OLS_RCOND = 1e-6
"""The plain least-squares baseline drops directions whose singular value is below this fraction of the
largest (numerically undetermined by the checks; min-norm there), else it returns values beyond any machine."""


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
