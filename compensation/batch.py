"""One chunk plan for solving a batch of tool paths, whoever runs the chunks.

``volcomp compensate`` solves every input through this module, in-process or on a Ray cluster
(``compensation.app.workflows.cluster``), and both give the same bytes because they share everything that
decides a result: fixed chunk boundaries (``chunk_points``, never the number of workers), per-chunk seeds
(chunk ``j`` of a file's ``k`` gets ``numpy.random.SeedSequence(seed).spawn(k)[j]``) and one torch thread
per chunk solve (docs/reference/tool-paths.md). A path whose points need another ``(field, machine)``
context names it (``path.context``); the contexts travel to a worker once per batch. :class:`LocalExecutor`
runs the chunks in threads of this process; an executor is anything with ``run(method, contexts, tasks,
options, progress) -> list[SolveResult]`` in task order. The library never imports Ray."""
from __future__ import annotations

import inspect
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field as dc_field

import numpy as np

from errormap.threads import limit_threads

from .solvers import GA_METHODS, SolveResult, get_solver, solve, solver_spec  # GA_METHODS: for the workflows
from .solvers._converge import merge_stats

CHUNK_POINTS = 65_536
"""Points per chunk (default): large enough that a chunk's fixed costs (a task, a field call)
are small beside its solve, small enough that a 1M-point path gives 16 chunks to share out."""



@dataclass(frozen=True)
class Chunk:
    """Points ``[lo, hi)`` of file ``file``, chunk ``index`` of that file, with its seed."""

    file: int
    index: int
    lo: int
    hi: int
    seed: np.random.SeedSequence = dc_field(compare=False, repr=False)

    def __len__(self) -> int:
        return self.hi - self.lo


@dataclass
class ChunkTask:
    """What a worker needs to solve one chunk: its targets (m, 3) mm, their nominal axes
    (m, k), the chunk's seed; ``chunk`` says where the result goes, ``label`` names its file,
    ``context`` the batch's (field, machine) pair it is solved with."""

    chunk: Chunk
    targets_mm: np.ndarray
    target_axes: np.ndarray
    label: str = ""
    context: int = 0


def check_chunk_points(chunk_points) -> int:
    if not (isinstance(chunk_points, (int, np.integer)) and not isinstance(chunk_points, bool) and chunk_points >= 1):
        raise ValueError(f"Expected chunk_points ≥ 1 (an integer), got {chunk_points!r}")
    return int(chunk_points)


def plan_chunks(sizes, chunk_points: int = CHUNK_POINTS, seed: int = 0) -> list[Chunk]:
    """The chunks of a batch of files with ``sizes[f]`` points each (every file ≥ 1 chunk).

    Boundaries are ``0, c, 2c, …, n`` (``c = chunk_points``); seeds
    ``SeedSequence(seed).spawn(k)`` per file. Depends on nothing else.
    """
    c = check_chunk_points(chunk_points)
    out = []
    for f, n in enumerate(int(s) for s in sizes):
        if n < 0:
            raise ValueError(f"Expected sizes ≥ 0, got {n} for file {f}")
        bounds = list(range(0, n, c)) + [n]
        if len(bounds) == 1:
            bounds = [0, 0]
        seeds = np.random.SeedSequence(seed).spawn(len(bounds) - 1)
        out += [Chunk(f, j, bounds[j], bounds[j + 1], seeds[j]) for j in range(len(bounds) - 1)]
    return out


def chunk_tasks(chunks, paths) -> list[ChunkTask]:
    """One :class:`ChunkTask` per chunk; ``paths[f]`` has ``targets_mm`` (n, 3) and ``axes`` (n, k),
    and may name its ``context`` (default 0)."""
    return [ChunkTask(c, np.ascontiguousarray(paths[c.file].targets_mm[c.lo:c.hi]),
                      np.ascontiguousarray(paths[c.file].axes[c.lo:c.hi]),
                      str(getattr(paths[c.file], "path", "") or f"input {c.file + 1}"),
                      int(getattr(paths[c.file], "context", 0))) for c in chunks]


def solve_chunk(method: str, contexts, task: ChunkTask, options: dict | None = None) -> SolveResult:
    """Solve one chunk with its context ``contexts[task.context]`` (a (field, machine) pair) as every
    executor does (call it under :func:`errormap.threads.limit_threads` (1)).

    The GA methods get a Generator on the chunk's own seed; ``batched-ga`` evolves the chunk
    as one block (one stream, no threads of its own); progress bars are off (the executor
    shows one for the batch).
    """
    field_, machine = contexts[task.context]
    takes = inspect.signature(get_solver(method)).parameters
    opts = dict(options or {})
    opts.pop("seed", None)
    spec = solver_spec(method)
    if spec.seeded:
        opts["seed"] = np.random.default_rng(task.chunk.seed)
    if spec.blockwise:
        opts.update({k: v for k, v in (("workers", 1), ("chunk", max(1, len(task.chunk)))) if k in takes})
    if "progress" in takes:
        opts["progress"] = False
    if "stop" not in takes:  # the local executor's Ctrl-C event: for the solvers that poll it
        opts.pop("stop", None)
    return solve(method, field_, task.targets_mm, machine, target_axes=task.target_axes, **opts)


SHARED_INFO = ("ball_um", "tol_um", "compensated_axes", "kept_axes", "note", "rotary_limit_deg")
"""Solver ``info`` entries that are the same for every chunk (what the guards and the summary read)."""
INDEX_INFO = ("outside_ball", "rotary_refused")
"""``info`` entries listing point indices (placed where their chunk's points go)."""
ALIGNED_INFO = {"rotary_reasons": "rotary_refused"}
"""``info`` lists with one entry per index of another entry."""


def gather_results(parts: list[SolveResult], positions: list) -> SolveResult:
    """One result of ``n = sum(len(positions[k]))`` points from ``parts``, part ``k``'s points
    placed at ``positions[k]`` (int arrays; together a permutation of ``range(n)``): arrays,
    :data:`SHARED_INFO` (from the first part that has it), :data:`INDEX_INFO` (mapped, in
    increasing order, with their :data:`ALIGNED_INFO`) and the GA's retry counts. ``seconds`` is
    the sum of the parts' solve times (CPU-side work, not the batch's wall time)."""
    positions = [np.asarray(p, dtype=np.intp) for p in positions]
    n = int(sum(len(p) for p in positions))
    first = parts[0]
    info = {}
    for key in SHARED_INFO:
        has = [p.info[key] for p in parts if key in (p.info or {})]
        if has:
            info[key] = has[0]
    retry = [p.info["retry"] for p in parts if "retry" in (p.info or {})]
    if retry:  # the GA's retries and Newton polish (compensation.solvers._converge)
        info["retry"] = merge_stats(retry)
    for key in INDEX_INFO:
        if any(key in (p.info or {}) for p in parts):
            idx = [pos[np.asarray(p.info.get(key, ()), dtype=np.intp)] for p, pos in zip(parts, positions)]
            order = np.argsort(np.concatenate(idx), kind="stable")
            info[key] = np.concatenate(idx)[order]
            for aligned, of in ALIGNED_INFO.items():
                if of == key:
                    vals = [v for p in parts for v in (p.info or {}).get(aligned, ())]
                    info[aligned] = [vals[i] for i in order]

    def place(name):
        a = getattr(first, name)
        out = np.empty((n,) + a.shape[1:], dtype=a.dtype)
        for p, pos in zip(parts, positions):
            out[pos] = getattr(p, name)
        return out

    messages = [p.message for p in parts if p.message]
    return SolveResult(first.method, place("targets_mm"), place("commands_mm"), place("axes"), place("residual_um"),
                       place("correction_um"), place("success"), int(sum(p.nfev for p in parts)),
                       float(sum(p.seconds for p in parts)), messages[0] if messages else "", info)


def merge_results(parts: list[SolveResult], chunk_points: int) -> SolveResult:
    """One file's result from its chunks' results (in chunk order): :func:`gather_results` of
    consecutive positions, with the chunk count."""
    sizes = np.cumsum([0] + [len(p.targets_mm) for p in parts])
    r = gather_results(parts, [np.arange(a, b) for a, b in zip(sizes[:-1], sizes[1:])])
    r.info.update(chunks=len(parts), chunk_points=chunk_points)
    return r


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


STOPPABLE = ("batched-ga",)
"""Methods that take a ``stop`` event (polled at least once a generation) from the local executor."""


class LocalExecutor:
    """Chunks solved in ``workers`` threads of this process, torch on one thread.

    The result does not depend on ``workers`` (each chunk is solved on its own, the same way).
    """

    name = "local"

    def __init__(self, workers: int | None = None):
        if workers is not None and not (isinstance(workers, (int, np.integer)) and workers >= 1):
            raise ValueError(f"Expected workers ≥ 1, got {workers!r}")
        self.workers = default_workers() if workers is None else int(workers)

    def describe(self) -> str:
        return f"this process, {self.workers} thread(s)"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def run(self, method, contexts, tasks, options=None, progress=None) -> list[SolveResult]:
        stop = threading.Event()  # Ctrl-C: the batched GA in the worker threads stops within a generation
        opts = dict(options or {}, stop=stop) if method in STOPPABLE else options

        def one(task):
            r = solve_chunk(method, contexts, task, opts)
            if progress is not None:
                progress(len(task.chunk))
            return r

        with limit_threads(1):
            if self.workers == 1 or len(tasks) <= 1:
                return [one(t) for t in tasks]
            with ThreadPoolExecutor(min(self.workers, len(tasks))) as pool:
                try:
                    return list(pool.map(one, tasks))
                except BaseException:
                    stop.set()  # before the pool waits for its threads; queued chunks are cancelled
                    raise


def solve_batch(method: str, field_, machine, paths, *, seed: int = 0, options: dict | None = None,
                chunk_points: int = CHUNK_POINTS, executor=None, progress=None, contexts=()) -> list[SolveResult]:
    """Solve every path of a batch (objects with ``targets_mm`` (n, 3) and ``axes`` (n, k)):
    one :class:`SolveResult` per path, in order. A path with ``context = j`` (default 0) is solved
    with ``((field_, machine), *contexts)[j]`` (``contexts``: more (field, machine) pairs).
    ``executor``: :class:`LocalExecutor` by default; ``progress(points)`` is called as chunks
    finish (from worker threads)."""
    chunk_points = check_chunk_points(chunk_points)
    all_contexts = ((field_, machine), *contexts)
    chunks = plan_chunks([len(p.targets_mm) for p in paths], chunk_points, seed)
    tasks = chunk_tasks(chunks, paths)
    bad = sorted({t.context for t in tasks} - set(range(len(all_contexts))))
    if bad:
        raise ValueError(f"Expected path contexts in [0, {len(all_contexts) - 1}], got {bad}")
    executor = LocalExecutor() if executor is None else executor
    results = executor.run(method, all_contexts, tasks, options, progress)
    if len(results) != len(tasks):
        raise RuntimeError(f"Expected {len(tasks)} chunk results from the {executor.name} executor, got {len(results)}")
    per_file = [[] for _ in paths]
    for c, r in zip(chunks, results):
        per_file[c.file].append(r)
    return [merge_results(parts, chunk_points) for parts in per_file]
