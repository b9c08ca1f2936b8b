"""The GA on a machine-tool chain (``kind = "machine-tool"``): the generic chain fitness.

The GA of :mod:`compensation.solvers.batched_ga` (``batched-ga``) and PyGAD one point at a time (``ga``), on
three genes in the 250 μm ball that move the axes the exact chain solver moves
(:func:`compensation.solvers.chain_exact.solved_and_kept`): tool-point offsets on three linear axes
(:class:`ChainOffsetFitness`), scaled axis offsets where a rotary axis is solved
(:class:`ChainAxisFitness`), or the network's fused float32 fitness (:class:`FusedChainFitness`). After the
generations, points above ``tol_um`` are retried and Newton-polished (:mod:`._converge`). ``success``:
|model residual| ≤ ``tol_um`` and inside the ball. Shapes: targets (n, 3) mm, axes (n, k). Derivation and
measurements: docs/explanation/solvers.md ("The GA on a chain")."""
from __future__ import annotations

import time

import numpy as np

from ._common import MM_PER_UM, UM_PER_MM, make_result, project_to_ball
from ._converge import RETRY_ROUNDS, retry_radius_um
from .base import BALL_RADIUS_UM
from .batched_ga import _BatchGA, _LockedProgress
from .chain_exact import (KEPT_NOTE, SOLVED_NOTE, _newton, check_chain_call, check_rotary_limit, linear_axes, nominal_and_jacobian,
                          rotary_bound_deg, rotary_guard, rotary_radius_mm, solved_and_kept, target_axes_of)
from .ga import DEFAULT_TOL_UM, PAPER_GA, check_ga_options, uniform_in_ball


class ChainOffsetFitness:
    """``fitness(points (k,) int64, offsets_um (3, k) float32) -> (k,) float32`` on a chain.

    ``axes_d`` (n, k) the targets' program axes, ``lin`` the linear axes' indices, ``Ainv``
    (n, 3, 3) the inverse nominal axis Jacobian of the linear axes (mm per mm) at ``axes_d``:
    ``q_lin(d) = q_d,lin + Ainv·(1e-3·d)``, fitness ``−|d + E(q(d))|²`` (μm²).
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

    def fitness64(self, pts, d_um) -> np.ndarray:
        """``−|d + E(q(d))|²`` (m,) μm², float64 (NaN → −inf)."""
        r = self.residual_um(pts, d_um)
        f = -np.einsum("ij,ij->i", r, r)
        return np.where(np.isnan(f), -np.inf, f)

    def genes_of(self, pts, q, commands_mm, targets_mm, ball_um) -> np.ndarray:
        """Genes (m, 3) of a Newton polish's axes ``q`` / commands: the tool-point offset in the ball."""
        return project_to_ball((commands_mm - targets_mm) * UM_PER_MM, ball_um)

    def __call__(self, pts: np.ndarray, dT: np.ndarray) -> np.ndarray:
        r = self.residual_um(pts, dT.T.astype(float))
        f = -np.einsum("ij,ij->i", r, r)
        return np.where(np.isnan(f), -np.inf, f).astype(np.float32)


class FusedChainFitness(ChainOffsetFitness):
    """The genes and fitness of :class:`ChainOffsetFitness` (tool-point offsets ``d`` μm) on a chain of two linear
    axes and a rotary one whose nominal inverse the network's fused kernel runs in closed form (the field's
    ``offset_fitness`` builds only for such a chain, the grinder's): the generations run that kernel (one float32
    pipeline, inverse and network); the retries, the polish and the result the same fitness in float64
    (``axes``: the chain's closed-form inverse, :func:`errormap.chain_kernel.closed_form_solver`, the rotary axis
    on the program's turn). ``fused`` the field's kernel over all targets."""

    def __init__(self, field, targets, axes_d, fused, solve):
        super().__init__(field, axes_d, None, None, None)
        self.targets, self.fused, self.solve = targets, fused, solve

    def axes(self, pts, d_um) -> np.ndarray:
        """Axes (m, 3) reaching ``p_d + 1e-3·d`` nominally (closed form, float64)."""
        q = self.solve(self.targets[pts] + MM_PER_UM * d_um)
        r = self.solve.k.rotary
        q[:, r] += 360.0 * np.round((self.axes_d[pts, r] - q[:, r]) / 360.0)
        return q

    def __call__(self, pts: np.ndarray, dT: np.ndarray) -> np.ndarray:
        return self.fused(pts, dT)


def _fused(field, machine, targets, axes_d, rotary_limit_deg):
    """:class:`FusedChainFitness` where the field offers ``offset_fitness`` for this chain (its kernel refuses a
    chain of another form) and no rotary limit is asked (the offsets move the rotary axis freely within the
    ball), else None."""
    from errormap.chain_kernel import closed_form_solver
    from errormap.field import OFFSET_FITNESS
    if rotary_limit_deg is not None or OFFSET_FITNESS not in field.capabilities:
        return None
    try:
        solve = closed_form_solver(machine)
        fused = field.offset_fitness(machine, targets)
    except ValueError:
        return None
    return FusedChainFitness(field, targets, axes_d, fused, solve)


class ChainAxisFitness:
    """``fitness(points (k,) int64, genes (3, k) float32) -> (k,) float32`` on a chain whose solved
    axes include a rotary one: genes ``g`` are the solved axes' offsets scaled by ``scale``, fitness
    ``−(|r(g)| + max(0, |p(g) − p_d|·1e3 − b))²``, ``r(g) = (fwd(q(g)) − p_d)·1e3 + E(q(g))``.

    ``compiled`` the machine's :class:`errormap.chain_kernel.NominalChain`, ``targets`` (n, 3) mm,
    ``axes_d`` (n, k) programmed axes, ``sol`` (3,) solved axes, ``scale`` (n, 3) axis units per gene
    unit, ``ball_um`` the tool point's ball.
    """

    def __init__(self, field, compiled, targets, axes_d, sol, scale, ball_um):
        self.field, self.compiled, self.targets, self.axes_d = field, compiled, targets, axes_d
        self.sol, self.scale, self.ball_um = sol, scale, float(ball_um)

    def axes(self, pts, g) -> np.ndarray:
        """Axes (m, k): the programmed ones with the solved axes moved by ``scale·g``."""
        q = self.axes_d[pts].copy()
        q[:, self.sol] += self.scale[pts] * g
        return q

    def commands_mm(self, pts, g) -> np.ndarray:
        """Nominal tool point (m, 3) mm of the axes of genes ``g``."""
        return self.compiled.forward(self.axes(pts, g))

    def residual_um(self, pts, g) -> np.ndarray:
        """Model residual ``(p(g) − p_d)·1e3 + E(q(g))`` (m, 3) μm, float64."""
        q = self.axes(pts, g)
        return (self.compiled.forward(q) - self.targets[pts]) * UM_PER_MM + self.field.predict(q)

    def fitness64(self, pts, g) -> np.ndarray:
        """``−(|r| + max(0, |p − p_d| − b))²`` (m,) μm², float64 (NaN → −inf)."""
        q = self.axes(pts, g)
        d = (self.compiled.forward(q) - self.targets[pts]) * UM_PER_MM
        r = np.linalg.norm(d + self.field.predict(q), axis=1)
        f = -(r + np.maximum(0.0, np.linalg.norm(d, axis=1) - self.ball_um)) ** 2
        return np.where(np.isnan(f), -np.inf, f)

    def genes_of(self, pts, q, commands_mm, targets_mm, ball_um) -> np.ndarray:
        """Genes (m, 3) of a Newton polish's axes ``q`` (projected onto the gene ball)."""
        return project_to_ball((q[:, self.sol] - self.axes_d[pts][:, self.sol]) / self.scale[pts], ball_um)

    def __call__(self, pts: np.ndarray, dT: np.ndarray) -> np.ndarray:
        return self.fitness64(pts, dT.T.astype(float)).astype(np.float32)


def chain_fitness(field, machine, compiled, targets, axes_d, ball_um, rotary_limit_deg=None):
    """The GA's fitness on ``machine`` and the axes it moves: ``(fitness, moved (3,), kept, note)``.
    Three linear axes: :class:`ChainOffsetFitness` (rotary axes kept); else the exact solver's axes
    (:func:`~compensation.solvers.chain_exact.solved_and_kept`) and :class:`ChainAxisFitness`, the
    rotary genes' range ``Δθ_max`` from the ball and the target's radius (ValueError if neither)."""
    names = machine.axis_columns
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    if len(lin) == 3:
        if rotary_limit_deg is not None:
            raise ValueError("a rotary correction limit applies only where the solver moves a rotary axis")
        lin, rot = linear_axes(machine)
        P0, J0 = nominal_and_jacobian(machine, axes_d, compiled)
        fit = ChainOffsetFitness(field, axes_d, lin, np.linalg.inv(J0[:, :, lin]), targets - P0)
        note = (KEPT_NOTE.format(lin=", ".join(names[j] for j in lin), rot=", ".join(names[j] for j in rot))
                if len(rot) else None)
        return fit, lin, rot, note
    sol, kept = solved_and_kept(machine, compiled)
    note = SOLVED_NOTE.format(sol=", ".join(names[j] for j in sol),
                              rot=", ".join(names[j] for j in sol if compiled.kinds[j] != "linear"))
    fused = _fused(field, machine, targets, axes_d, rotary_limit_deg) if list(sol) == [0, 1, 2] else None
    if fused is not None:
        return fused, sol, kept, note
    _, J = nominal_and_jacobian(machine, axes_d, compiled)
    scale = np.empty((len(targets), 3))
    for c, j in enumerate(sol):
        if compiled.kinds[j] == "linear":
            scale[:, c] = MM_PER_UM
        else:
            scale[:, c] = rotary_bound_deg(rotary_radius_mm(J[:, :, j]), ball_um, rotary_limit_deg) / ball_um
    return ChainAxisFitness(field, compiled, targets, axes_d, sol, scale, ball_um), sol, kept, note


def _setup(field, targets_mm, machine, target_axes, ball_um, population, generations, selection_probability,
           crossover_probability, mutation_probability, mutation_step_um, tol_um, retries, rotary_limit_deg, chunk=1):
    """Shared validation and set-up of the chain GAs: ``(compiled chain, targets (n, 3) mm, mating parents,
    program axes (n, k), fitness, moved axes, kept axes, note)`` (:func:`chain_fitness`)."""
    compiled, _, _, targets = check_chain_call(field, targets_mm, machine, ball_um)
    n_parents = check_ga_options(population, generations, selection_probability, crossover_probability,
                                 mutation_probability, mutation_step_um, tol_um)
    if not (isinstance(retries, (int, np.integer)) and 0 <= retries <= 10):
        raise ValueError(f"Expected retries in 0..10, got {retries!r}")
    check_rotary_limit(rotary_limit_deg)
    if not (isinstance(chunk, (int, np.integer)) and chunk >= 1):
        raise ValueError(f"Expected chunk ≥ 1, got {chunk!r}")
    axes_d = target_axes_of(machine, targets, target_axes, compiled)
    fit, moved, kept, note = chain_fitness(field, machine, compiled, targets, axes_d, ball_um, rotary_limit_deg)
    return compiled, targets, n_parents, axes_d, fit, moved, kept, note


def _retry_and_polish(fit, field, compiled, targets, axes_d, moved, idx, b, tol_um, ball_um, retries, polish,
                      rerun, stats):
    """Retries (``rerun(sub_local, init (s, P, 3)) -> (genes (s, 3), evaluations)``) and the Newton polish
    of the points of ``idx`` (m,) whose best genes ``b`` (m, 3) leave a model residual above ``tol_um``;
    ``b`` updated in place; returns the field evaluations (the seconds spent: ``stats["retry_seconds"]``)."""
    t0 = time.perf_counter()
    nfev = 0
    res = np.linalg.norm(fit.residual_um(idx, b), axis=1)
    bad = np.flatnonzero(~(res <= tol_um))
    stats["retried"] += int(bad.size)
    for r in range(retries):
        if not bad.size:
            break
        radius = retry_radius_um(np.where(np.isfinite(res[bad]), res[bad], ball_um), r, ball_um)
        new, fe = rerun(bad, radius)
        nfev += fe
        nr = np.linalg.norm(fit.residual_um(idx[bad], new), axis=1)
        better = nr < res[bad]
        b[bad[better]], res[bad[better]] = new[better], nr[better]
        bad = bad[~(res[bad] <= tol_um)]
        stats["retry_rounds"] = max(stats["retry_rounds"], r + 1)
    if polish and bad.size:
        sub = idx[bad]
        q, commands, _, _, _, fe = _newton(field, compiled, targets[sub], axes_d[sub], moved, 1e-9, 50,
                                           q0=fit.axes(sub, b[bad]))  # from the GA's best
        nfev += fe
        new = fit.genes_of(sub, q, commands, targets[sub], ball_um)
        nr = np.linalg.norm(fit.residual_um(sub, new), axis=1)
        better = nr < res[bad]
        b[bad[better]], res[bad[better]] = new[better], nr[better]
        stats["polished"] += int(bad.size)
        bad = bad[~(res[bad] <= tol_um)]
    stats["unconverged"] += int(bad.size)
    stats["retry_seconds"] += time.perf_counter() - t0
    return nfev


def _chain_result(method, fit, field, compiled, machine, targets, axes_d, best, moved, kept, note, nfev, t0,
                  ball_um, tol_um, rotary_limit_deg, info):
    """The GA's result from its best genes (n, 3): axes, commands, float64 model residual, the rotary
    guard's report (a solved rotary axis; the genes cannot pass its bound, so none is refused)."""
    n = len(targets)
    all_idx = np.arange(n)
    q = fit.axes(all_idx, best)
    if isinstance(fit, ChainOffsetFitness):
        commands = targets + MM_PER_UM * best
    else:
        commands = compiled.forward(q)
    E = field.predict(q)
    nfev += n
    res = (commands - targets) * UM_PER_MM + E
    converged = np.linalg.norm(res, axis=1) <= tol_um
    names = machine.axis_columns
    info = {**info, "compensated_axes": [names[j] for j in moved], "kept_axes": [names[j] for j in kept]}
    if note:
        info["note"] = note
    if isinstance(fit, (ChainAxisFitness, FusedChainFitness)):
        refused, reasons = rotary_guard(compiled, machine, axes_d, q, moved, ball_um, rotary_limit_deg)
        converged &= ~refused
        info["rotary_refused"] = np.flatnonzero(refused)
        info["rotary_reasons"] = [reasons[i] for i in np.flatnonzero(refused).tolist()]
        info["rotary_limit_deg"] = None if rotary_limit_deg is None else float(rotary_limit_deg)
    return make_result(method, targets, commands, q, res, converged, nfev, t0, ball_um, info=info)


def solve_batched_ga_chain(field, targets_mm, machine, *, target_axes=None, ball_um: float = BALL_RADIUS_UM,
                           seed: int = 0, population: int = PAPER_GA["population"],
                           generations: int = PAPER_GA["generations"],
                           selection_probability: float = PAPER_GA["selection_probability"],
                           crossover_probability: float = PAPER_GA["crossover_probability"],
                           mutation_probability: float = PAPER_GA["mutation_probability"],
                           mutation_step_um: float = PAPER_GA["mutation_step_um"], tol_um: float = DEFAULT_TOL_UM,
                           chunk: int = 8192, retries: int = RETRY_ROUNDS, polish: bool = True,
                           rotary_limit_deg=None, progress: bool = True, stop=None):
    """Batched GA over WCS targets (n, 3) mm on a machine-tool chain (module docstring).

    ``stop``: a ``threading.Event`` polled every generation and fitness block (the local executor's Ctrl-C:
    KeyboardInterrupt within a generation, :data:`compensation.batch.STOPPABLE`).

    ``target_axes`` (n, k): the program's axes of each target (required when the machine has
    rotary axes). Chunks of at most ``chunk`` points evolve one after another, each from its own
    child Generator of ``seed``. ``rotary_limit_deg``: a solved rotary axis' limit (as the exact
    chain solver's). Returns a :class:`~compensation.solvers.base.SolveResult` with ``axes`` (n, k);
    ``info``: ``compensated_axes``, ``kept_axes``, ``note``, ``retry`` (retried / polished /
    unconverged), ``rotary_refused`` where a rotary axis is solved.
    """
    t0 = time.perf_counter()
    compiled, targets, n_parents, axes_d, fit, moved, kept, note = _setup(
        field, targets_mm, machine, target_axes, ball_um, population, generations, selection_probability,
        crossover_probability, mutation_probability, mutation_step_um, tol_um, retries, rotary_limit_deg, chunk)
    n = len(targets)
    ga = _BatchGA(ball_um, population, n_parents, crossover_probability, mutation_probability, mutation_step_um)
    n_chunks = max(1, -(-n // chunk))
    bounds = np.linspace(0, n, n_chunks + 1).round().astype(int)
    rngs = np.random.default_rng(seed).spawn(n_chunks)
    bar = _LockedProgress(n * generations, "batched-ga chain (point-generations)", enabled=progress)
    best = np.empty((n, 3))
    nfev = 0
    stats = {"retried": 0, "retry_rounds": 0, "polished": 0, "unconverged": 0, "retry_seconds": 0.0}
    for i in range(n_chunks):
        lo, hi = bounds[i], bounds[i + 1]
        if hi <= lo:
            continue
        idx = np.arange(lo, hi)
        b, fe = ga.run(lambda pts, dT, _o=lo: fit(pts + _o, dT), hi - lo, rngs[i], generations, bar, stop=stop)
        nfev += fe

        def rerun(bad, radius, _b=b, _idx=idx, _rng=rngs[i]):
            init = _b[bad][:, None, :] + radius[:, None, None] * uniform_in_ball(_rng, (bad.size, population), 1.0)
            init[:, 0] = _b[bad]
            init = project_to_ball(init, ball_um).astype(np.float32)
            sub = _idx[bad]
            return ga.run(lambda pts, dT, _s=sub: fit(_s[pts], dT), bad.size, _rng, generations, None, init=init,
                          stop=stop)

        nfev += _retry_and_polish(fit, field, compiled, targets, axes_d, moved, idx, b, tol_um, ball_um, retries,
                                  polish, rerun, stats)
        best[lo:hi] = b
    bar.close()
    info = {"tol_um": tol_um, "seed": seed if isinstance(seed, (int, np.integer)) else None, "parents": n_parents,
            "chunks": n_chunks, "retry": stats}
    return _chain_result("batched-ga", fit, field, compiled, machine, targets, axes_d, best, moved, kept, note, nfev,
                         t0, ball_um, tol_um, rotary_limit_deg, info)


def solve_ga_chain(field, targets_mm, machine, *, target_axes=None, ball_um: float = BALL_RADIUS_UM,
                   seed: int = 0, population: int = PAPER_GA["population"],
                   generations: int = PAPER_GA["generations"],
                   selection_probability: float = PAPER_GA["selection_probability"],
                   crossover_probability: float = PAPER_GA["crossover_probability"],
                   mutation_probability: float = PAPER_GA["mutation_probability"],
                   mutation_step_um: float = PAPER_GA["mutation_step_um"], tol_um: float = DEFAULT_TOL_UM,
                   retries: int = RETRY_ROUNDS, polish: bool = True, rotary_limit_deg=None,
                   progress: bool = True):
    """PyGAD per target on a machine-tool chain (the reference GA, a loop over points on purpose): the
    genes and fitness of :func:`chain_fitness` (module docstring), PyGAD's settings the paper's
    (:data:`compensation.solvers.ga.PAPER_GA`: steady-state selection of 0.7·40 parents, single-point
    crossover 0.7, random mutation ±1 gene unit with probability 0.2, elitism 1, offspring projected
    onto the gene ball). Point i's run depends only on ``(seed, i)`` (its own child Generator, which
    also draws PyGAD's ``random_seed``). Retries and polish as :func:`solve_batched_ga_chain`."""
    import pygad

    t0 = time.perf_counter()
    compiled, targets, n_parents, axes_d, fit, moved, kept, note = _setup(
        field, targets_mm, machine, target_axes, ball_um, population, generations, selection_probability,
        crossover_probability, mutation_probability, mutation_step_um, tol_um, retries, rotary_limit_deg)
    n = len(targets)
    point_rngs = np.random.default_rng(seed).spawn(n)
    counter = [0]

    def run_one(i, init=None):
        rng = point_rngs[i]
        pt = np.array([i], dtype=np.intp)

        def fitness(ga, solutions, indices):
            g = np.asarray(solutions, dtype=float).reshape(-1, 3)
            counter[0] += len(g)
            return list(fit.fitness64(np.repeat(pt, len(g)), g))

        def on_mutation(ga, offspring):
            return project_to_ball(np.asarray(offspring, dtype=float), ball_um)

        pop = uniform_in_ball(rng, (population,), ball_um) if init is None else init
        ga = pygad.GA(num_generations=generations, num_parents_mating=n_parents, fitness_func=fitness,
                      fitness_batch_size=population, initial_population=pop, gene_type=float,
                      parent_selection_type="sss", keep_elitism=1, crossover_type="single_point",
                      crossover_probability=crossover_probability, mutation_type="random",
                      mutation_probability=mutation_probability, mutation_by_replacement=False,
                      random_mutation_min_val=-mutation_step_um, random_mutation_max_val=mutation_step_um,
                      on_mutation=on_mutation, random_seed=int(rng.integers(0, 2**31 - 1)), suppress_warnings=True)
        ga.run()
        solution, _, _ = ga.best_solution(ga.last_generation_fitness)
        return project_to_ball(np.asarray(solution, dtype=float), ball_um)

    bar = _LockedProgress(n, "ga chain (PyGAD)", enabled=progress)
    best = np.empty((n, 3))
    for i in range(n):  # the per-point reference: a loop on purpose
        best[i] = run_one(i)
        bar.update(1)
    bar.close()

    def rerun(bad, radius):
        out = np.empty((bad.size, 3))
        for j, (i, r) in enumerate(zip(bad.tolist(), radius.tolist())):
            init = best[i] + r * uniform_in_ball(point_rngs[i], (population,), 1.0)
            init[0] = best[i]  # the best so far survives (elitism)
            out[j] = run_one(i, project_to_ball(init, ball_um))
        return out, 0

    stats = {"retried": 0, "retry_rounds": 0, "polished": 0, "unconverged": 0, "retry_seconds": 0.0}
    nfev = _retry_and_polish(fit, field, compiled, targets, axes_d, moved, np.arange(n), best, tol_um, ball_um,
                             retries, polish, rerun, stats)
    info = {"tol_um": tol_um, "seed": seed if isinstance(seed, (int, np.integer)) else None, "parents": n_parents,
            "retry": stats, "pygad_version": pygad.__version__}
    return _chain_result("ga", fit, field, compiled, machine, targets, axes_d, best, moved, kept, note,
                         nfev + counter[0], t0, ball_um, tol_um, rotary_limit_deg, info)
