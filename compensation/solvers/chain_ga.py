"""The batched GA on a machine-tool chain (``kind = "machine-tool"``): the generic chain fitness.

Same GA as :mod:`compensation.solvers.batched_ga` (the paper's population, generations and
PyGAD operators, :class:`~compensation.solvers.batched_ga._BatchGA`), on offsets ``d`` (μm) of
the commanded tool point around each target ``p_d``. What differs is the fitness, written for
any chain instead of the grinder's hand-written inverse kinematics:

    q(d) = q_d  with the linear axes  q_lin = q_d,lin + A⁻¹·(1e-3·d)
    fitness(d) = −|d + E(q(d))|²          (μm²)

with ``q_d`` the program's axes of the target, ``A = dfwd/dq_lin`` the machine's nominal axis
Jacobian at ``q_d`` (:func:`compensation.solvers.chain_exact.nominal_and_jacobian`). As in the
exact chain solver on a machine with three linear axes the **tool-tip position** is compensated
with them and the rotary axes are **kept as programmed** (a machine without three linear axes,
the lathe, is refused here; the exact chain solver moves its X, Z and C); with them fixed the nominal tool point is
affine in the linear axes, so ``q(d)`` is the exact nominal inverse of ``p_d + 1e-3·d`` (one
3×3 inverse per point, computed once). ``E`` is the field's ``predict`` over
``machine.axis_columns`` (float64 numpy; any chain field: the element set's
:class:`errormap.mt_field.ChainField` or a trained network).

After the generations, points above ``tol_um`` are retried (GA re-runs from a fresh population
around their best, radii as :mod:`._converge`) and then polished by the exact chain solver's
Newton iteration (:func:`compensation.solvers.chain_exact.solve_exact_chain`'s loop); per
point the candidate with the smaller float64 model residual is kept. ``success``: |model
residual| ≤ ``tol_um`` and inside the ball. Shapes: targets (n, 3) mm, axes (n, k).
"""
from __future__ import annotations

import time

import numpy as np

from errormap.field import check_field
from errormap.mt_kernel import NominalChain
from errormap.transforms import check_points

from ._common import MM_PER_UM, UM_PER_MM, make_result, project_to_ball
from ._converge import RETRY_ROUNDS, retry_radius_um
from .base import BALL_RADIUS_UM
from .batched_ga import _BatchGA, _LockedProgress
from .chain_exact import KEPT_NOTE, _newton, linear_axes, nominal_and_jacobian, target_axes_of
from .ga import DEFAULT_TOL_UM, PAPER_GA, check_ga_options, uniform_in_ball


class ChainOffsetFitness:
    """``fitness(points (k,) int64, offsets_um (3, k) float32) -> (k,) float32`` on a chain.

    ``axes_d`` (n, k) the targets' program axes, ``lin`` the linear axes' indices, ``Ainv``
    (n, 3, 3) the inverse nominal axis Jacobian of the linear axes (mm per mm) at ``axes_d``.
    """

    def __init__(self, field, axes_d, lin, Ainv, delta0_mm):
        self.field, self.axes_d, self.lin, self.Ainv = field, axes_d, lin, Ainv
        self.delta0_mm = delta0_mm  # (n, 3) target minus the nominal point of axes_d (round-off)

    def axes(self, pts, d_um) -> np.ndarray:
        """Axes (m, k) reaching ``p_d + 1e-3·d`` nominally, rotary axes as programmed."""
        q = self.axes_d[pts].copy()
        q[:, self.lin] += np.einsum("nij,nj->ni", self.Ainv[pts], self.delta0_mm[pts] + MM_PER_UM * d_um)
        return q

    def residual_um(self, pts, d_um) -> np.ndarray:
        """Model residual ``d + E(q(d))`` (m, 3) μm, float64."""
        return d_um + self.field.predict(self.axes(pts, d_um))

    def __call__(self, pts: np.ndarray, dT: np.ndarray) -> np.ndarray:
        r = self.residual_um(pts, dT.T.astype(float))
        f = -np.einsum("ij,ij->i", r, r)
        return np.where(np.isnan(f), -np.inf, f).astype(np.float32)


def solve_batched_ga_chain(field, targets_mm, machine, *, target_axes=None, ball_um: float = BALL_RADIUS_UM,
                           seed: int = 0, population: int = PAPER_GA["population"],
                           generations: int = PAPER_GA["generations"],
                           selection_probability: float = PAPER_GA["selection_probability"],
                           crossover_probability: float = PAPER_GA["crossover_probability"],
                           mutation_probability: float = PAPER_GA["mutation_probability"],
                           mutation_step_um: float = PAPER_GA["mutation_step_um"], tol_um: float = DEFAULT_TOL_UM,
                           chunk: int = 8192, retries: int = RETRY_ROUNDS, polish: bool = True,
                           progress: bool = True):
    """Batched GA over WCS targets (n, 3) mm on a machine-tool chain (module docstring).

    ``target_axes`` (n, k): the program's axes of each target (required when the machine has
    rotary axes: they are kept). Chunks of at most ``chunk`` points evolve one after another,
    each from its own child Generator of ``seed``. Returns a
    :class:`~compensation.solvers.base.SolveResult` with ``axes`` (n, k); ``info``:
    ``compensated_axes``, ``kept_axes``, ``note``, ``retry`` (retried / polished / unconverged).
    """
    t0 = time.perf_counter()
    check_field(field, machine.axis_columns)
    lin, rot = linear_axes(machine)
    targets = check_points(targets_mm, "WCS targets (px_mm, py_mm, pz_mm)")
    if not (np.isfinite(ball_um) and ball_um > 0):
        raise ValueError(f"Expected a positive ball radius in μm, got {ball_um!r}")
    n_parents = check_ga_options(population, generations, selection_probability, crossover_probability,
                                 mutation_probability, mutation_step_um, tol_um)
    if not (isinstance(chunk, (int, np.integer)) and chunk >= 1):
        raise ValueError(f"Expected chunk ≥ 1, got {chunk!r}")
    if not (isinstance(retries, (int, np.integer)) and 0 <= retries <= 10):
        raise ValueError(f"Expected retries in 0..10, got {retries!r}")
    compiled = NominalChain(machine)
    axes_d = target_axes_of(machine, targets, target_axes, compiled)
    n = len(targets)
    P0, J0 = nominal_and_jacobian(machine, axes_d, compiled)
    Ainv = np.linalg.inv(J0[:, :, lin])
    fit = ChainOffsetFitness(field, axes_d, lin, Ainv, targets - P0)
    ga = _BatchGA(ball_um, population, n_parents, crossover_probability, mutation_probability, mutation_step_um)
    n_chunks = max(1, -(-n // chunk))
    bounds = np.linspace(0, n, n_chunks + 1).round().astype(int)
    rngs = np.random.default_rng(seed).spawn(n_chunks)
    bar = _LockedProgress(n * generations, "batched-ga chain (point-generations)", enabled=progress)
    best = np.empty((n, 3))
    nfev = 0
    stats = {"retried": 0, "retry_rounds": 0, "polished": 0, "unconverged": 0}
    for i in range(n_chunks):
        lo, hi = bounds[i], bounds[i + 1]
        if hi <= lo:
            continue
        idx = np.arange(lo, hi)
        b, fe = ga.run(lambda pts, dT, _o=lo: fit(pts + _o, dT), hi - lo, rngs[i], generations, bar)
        nfev += fe
        res = np.linalg.norm(fit.residual_um(idx, b), axis=1)
        bad = np.flatnonzero(~(res <= tol_um))
        stats["retried"] += int(bad.size)
        for r in range(retries):
            if not bad.size:
                break
            radius = retry_radius_um(np.where(np.isfinite(res[bad]), res[bad], ball_um), r, ball_um)
            init = b[bad][:, None, :] + radius[:, None, None] * uniform_in_ball(rngs[i], (bad.size, population), 1.0)
            init[:, 0] = b[bad]
            init = project_to_ball(init, ball_um).astype(np.float32)
            sub = idx[bad]
            new, fe = ga.run(lambda pts, dT, _s=sub: fit(_s[pts], dT), bad.size, rngs[i], generations, None,
                             init=init)
            nfev += fe
            nr = np.linalg.norm(fit.residual_um(sub, new), axis=1)
            better = nr < res[bad]
            b[bad[better]], res[bad[better]] = new[better], nr[better]
            bad = bad[~(res[bad] <= tol_um)]
            stats["retry_rounds"] = max(stats["retry_rounds"], r + 1)
        if polish and bad.size:
            sub = idx[bad]
            q, commands, _, _, fe = _newton(field, compiled, targets[sub], axes_d[sub], lin, 1e-9, 50)
            nfev += fe
            new = project_to_ball((commands - targets[sub]) * UM_PER_MM, ball_um)
            nr = np.linalg.norm(fit.residual_um(sub, new), axis=1)
            better = nr < res[bad]
            b[bad[better]], res[bad[better]] = new[better], nr[better]
            stats["polished"] += int(bad.size)
            bad = bad[~(res[bad] <= tol_um)]
        stats["unconverged"] += int(bad.size)
        best[lo:hi] = b
    bar.close()
    all_idx = np.arange(n)
    q = fit.axes(all_idx, best)
    commands = targets + MM_PER_UM * best
    E = field.predict(q)
    nfev += n
    res = (commands - targets) * UM_PER_MM + E
    converged = np.linalg.norm(res, axis=1) <= tol_um
    names = machine.axis_columns
    info = {"tol_um": tol_um, "seed": seed if isinstance(seed, (int, np.integer)) else None, "parents": n_parents,
            "chunks": n_chunks, "retry": stats, "compensated_axes": [names[j] for j in lin],
            "kept_axes": [names[j] for j in rot]}
    if len(rot):
        info["note"] = KEPT_NOTE.format(lin=", ".join(info["compensated_axes"]), rot=", ".join(info["kept_axes"]))
    return make_result("batched-ga", targets, commands, q, res, converged, nfev, t0, ball_um, info=info)
