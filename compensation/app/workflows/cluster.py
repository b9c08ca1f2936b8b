"""Ray scale-out: batch compensation on a cluster, and the fleet (identify → train → diagnose).

Ray is imported here only, and lazily (``pip install 'volcomp[cluster]'``). :class:`RayExecutor` (``volcomp
compensate --cluster ray``) solves the chunks of :mod:`compensation.batch` (fixed boundaries, per-chunk seeds)
on Ray actors, one per worker CPU, each holding the batch's fields and machines and running torch on one thread;
the driver keeps every result and then guards, renders and writes, so the bytes equal the in-process run's. A
dead actor is restarted and its chunk retried (:data:`MAX_RETRIES`), then the batch fails with one
:class:`ClusterError` line and nothing written. Without ``address`` a local instance of ``workers`` CPUs is
started and shut down; with it (``HOST:PORT`` or ``auto``) a cluster is joined and left running; an
initialised session is used as it is. docs/how-to/scale-out.md.
"""
from __future__ import annotations

import os
import sys
import time
from collections import deque
from dataclasses import dataclass

from errormap.threads import limit_threads

from compensation.batch import CHUNK_POINTS, LocalExecutor, default_workers, solve_chunk

EXIT_CLUSTER = 4
"""Exit status of a command whose work the cluster could not finish (nothing written)."""

CLUSTERS = ("ray",)

MAX_RETRIES = 2
"""Restarts of a dead actor and retries of the chunk it was solving, before the batch fails."""

IN_FLIGHT_PER_ACTOR = 2  # chunks queued on an actor: the next one's transfer overlaps the solve

FAULT_ENV = "VOLCOMP_CLUSTER_FAULT"
"""Test hook (fault injection): ``exit:FILE:CHUNK`` makes the worker that solves chunk CHUNK
of input FILE (0-based) exit at once; ``exit-once:FILE:CHUNK:MARKER`` does so only while the
file MARKER does not exist (it is created first), so a retry succeeds. The worker dies
:data:`FAULT_AFTER_S` into the chunk, as a crash mid-solve does."""

FAULT_AFTER_S = 0.5
"""Seconds into the faulty chunk before the worker exits: dying the instant a chunk starts can
lose the reply of the chunk before it, still on its way out (Ray then retries that one too)."""


class ClusterError(RuntimeError):
    """The cluster could not finish the work (after retries); nothing was written."""


def import_ray():
    """``ray``, or a :class:`ClusterError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ClusterError("--cluster ray needs Ray: pip install 'volcomp[cluster]'") from None
    return ray


def _parse_fault(text):
    if not text:
        return None
    parts = text.split(":", 3)
    try:
        kind, f, c = parts[0], int(parts[1]), int(parts[2])
    except (IndexError, ValueError):
        raise ClusterError(f"${FAULT_ENV}: expected exit:FILE:CHUNK or exit-once:FILE:CHUNK:MARKER, got {text!r}") \
            from None
    if kind not in ("exit", "exit-once") or (kind == "exit-once" and len(parts) != 4):
        raise ClusterError(f"${FAULT_ENV}: expected exit:FILE:CHUNK or exit-once:FILE:CHUNK:MARKER, got {text!r}")
    return (kind, f, c, parts[3] if kind == "exit-once" else None)


class ChunkSolver:
    """A Ray actor's body: the batch's (field, machine) contexts loaded once, chunks solved on one
    torch thread."""

    def __init__(self, payload, fault=None):
        self.contexts = payload
        self.fault = fault
        torch = sys.modules.get("torch")
        if torch is not None:  # else limit_threads(1) sets it when a solver loads torch
            torch.set_num_threads(1)

    def solve(self, i, method, task, options):
        if self.fault is not None:
            kind, f, c, marker = self.fault
            if (task.chunk.file, task.chunk.index) == (f, c) and (kind == "exit" or not os.path.exists(marker)):
                if kind == "exit-once":
                    open(marker, "w").close()
                time.sleep(FAULT_AFTER_S)
                os._exit(17)
        with limit_threads(1):
            return i, solve_chunk(method, self.contexts, task, options)

    def pid(self):
        return os.getpid()


def _chunk_it_died_on(ray, refs, i, actor, wait_s: float = 60.0) -> int:
    """The task a dead actor was solving, given task ``i`` failed on it: an actor runs its chunks
    one at a time in the order they were sent (the queue's order), so the chunks queued behind
    the one it died on fail with it and Ray may report any of them first. It is the earliest
    sent of ``i`` and the actor's other tasks in ``refs`` (``{ref: (task, actor)}``) that failed;
    those still running are waited for (up to ``wait_s``: a dead actor's fail at once) — one
    that finished before the death is not the culprit even if its reply is still on the way."""
    from ray.exceptions import RayError
    others = {ref: k for ref, (k, a) in refs.items() if a is actor}
    back = set(ray.wait(list(others), num_returns=len(others), timeout=wait_s)[0]) if others else set()
    culprits = [i]
    for ref, k in others.items():
        if ref in back:
            try:
                ray.get(ref)
                continue
            except RayError:
                pass
        culprits.append(k)  # failed, or still not back after wait_s: it may be the one
    return min(culprits)


class RayExecutor:
    """Solve chunk tasks on Ray (see the module docstring); a context manager that starts
    (and stops) a local Ray instance when none is running and no ``address`` is given."""

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None, max_retries: int = MAX_RETRIES):
        if workers is not None and workers < 1:
            raise ValueError(f"Expected workers ≥ 1, got {workers!r}")
        self.address = address
        self.workers = workers
        self.max_retries = int(max_retries)
        self._owned = False
        self._actor_cls = None
        self._pool = None

    # -- the session ----------------------------------------------------------------
    def __enter__(self):
        ray = import_ray()
        if not ray.is_initialized():
            if self.address:
                try:
                    ray.init(address=self.address, log_to_driver=False)
                except (ConnectionError, RuntimeError, ValueError) as exc:
                    raise ClusterError(f"--address {self.address}: cannot join the Ray cluster ({exc})") from None
            else:
                # "local": a new instance even where `ray start` left one running or RAY_ADDRESS is set
                ray.init(address="local", num_cpus=self.workers or default_workers(), include_dashboard=False,
                         log_to_driver=False)
            self._owned = True
        return self

    def __exit__(self, *exc):
        if "ray" in sys.modules:
            self._drop_actors()
        if self._owned:
            import ray
            ray.shutdown()
            self._owned = False
        return False

    def cpus(self) -> int:
        """Worker slots: ``workers`` if given, else the cluster's CPUs."""
        import ray
        return self.workers or max(1, int(ray.cluster_resources().get("CPU", 1)))

    def describe(self) -> str:
        import ray
        res = ray.cluster_resources()
        return (f"Ray {ray.__version__}, {len(ray.nodes())} node(s), {int(res.get('CPU', 0))} CPU(s)"
                f"{' (joined ' + self.address + ')' if self.address else ' (local)'}")

    # -- the work -------------------------------------------------------------------
    def _actor(self):
        import ray
        if self._actor_cls is None:
            self._actor_cls = ray.remote(num_cpus=1, max_restarts=self.max_retries,
                                         max_task_retries=self.max_retries)(ChunkSolver)
        return self._actor_cls

    def run(self, method, contexts, tasks, options=None, progress=None) -> list:
        """Results of ``tasks`` (:class:`compensation.batch.ChunkTask`) in task order, each solved with
        its context of ``contexts`` ((field, machine) pairs)."""
        import ray
        from ray.exceptions import RayError, RayTaskError
        if not tasks:
            return []
        actors = self._actors(tuple(contexts), len(tasks))
        results = [None] * len(tasks)
        queue = deque(range(len(tasks)))
        refs = {}

        def submit(actor):
            i = queue.popleft()
            refs[actor.solve.remote(i, method, tasks[i], options)] = (i, actor)

        try:
            for _ in range(IN_FLIGHT_PER_ACTOR):
                for a in actors:
                    if queue:
                        submit(a)
            while refs:
                done, _ = ray.wait(list(refs), num_returns=1)
                i, actor = refs.pop(done[0])
                try:
                    j, res = ray.get(done[0])
                except RayTaskError as exc:  # the solver raised: the same error as in-process
                    cause = getattr(exc, "cause", None)
                    if isinstance(cause, Exception):
                        raise cause from None
                    raise
                except RayError as exc:  # the worker died (after the retries) or the cluster failed
                    i = _chunk_it_died_on(ray, refs, i, actor)
                    c = tasks[i].chunk
                    why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                    raise ClusterError(f"chunk {c.index} (points {c.lo}-{c.hi - 1}) of {tasks[i].label} failed on "
                                       f"the Ray cluster after {self.max_retries} retries: {type(exc).__name__}: "
                                       f"{why}") from None
                results[j] = res
                if progress is not None:
                    progress(len(tasks[j].chunk))
                if queue:
                    submit(actor)
        except BaseException:
            self._drop_actors()  # a failed or interrupted batch leaves no actor busy behind it
            raise
        return results

    def _actors(self, contexts, n_tasks):
        """The actors holding these contexts (made on first use, kept for the session's next batch)."""
        fault = _parse_fault(os.environ.get(FAULT_ENV))
        n = min(self.cpus(), n_tasks)
        key = (tuple((id(f), id(m)) for f, m in contexts), fault)
        if self._pool is not None and self._pool[0] == key and len(self._pool[1]) >= n:
            return self._pool[1]
        self._drop_actors()
        # the fields and machines go by value into each actor's creation (a few kB to a few MB): each
        # actor deserialises them once, and a restarted actor gets them again from its creation spec
        actors = [self._actor().remote(contexts, fault) for _ in range(n)]
        self._pool = (key, actors, contexts)  # the objects held: their ids stay theirs
        return actors

    def _drop_actors(self):
        if self._pool is not None:
            import ray
            for a in self._pool[1]:
                ray.kill(a, no_restart=True)
            self._pool = None

    def map_function(self, fn, arg_tuples, labels=None, on_done=None) -> list:
        """``fn(*args)`` as one Ray task (one CPU) per tuple, results in order. A task whose
        worker died is retried (:data:`MAX_RETRIES` times); after that its entry is a
        :class:`ClusterError` (the others still finish). ``fn`` should report its own errors
        in its result (an exception it raises is re-raised here). ``on_done(label, result)``
        is called as tasks finish."""
        import ray
        from ray.exceptions import RayError, RayTaskError
        labels = labels or [str(i) for i in range(len(arg_tuples))]
        remote = ray.remote(num_cpus=1, max_retries=self.max_retries)(fn)
        refs = {remote.remote(*args): i for i, args in enumerate(arg_tuples)}
        results = [None] * len(arg_tuples)
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            i = refs.pop(done[0])
            try:
                results[i] = ray.get(done[0])
            except RayTaskError as exc:
                cause = getattr(exc, "cause", None)
                if isinstance(cause, Exception):
                    raise cause from None
                raise
            except RayError as exc:
                why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                results[i] = ClusterError(f"{labels[i]}: lost on the Ray cluster after {self.max_retries} retries: "
                                          f"{type(exc).__name__}: {why}")
            if on_done is not None:
                on_done(labels[i], results[i])
        return results


@dataclass(frozen=True)
class ClusterSettings:
    """Where the work runs: ``cluster`` (None: this process; ``"ray"``), ``address`` (``HOST:PORT`` or ``auto``:
    join a running Ray cluster; None: start a local one), ``workers`` (threads in this process, or the CPUs of the
    local Ray instance; None: this machine's cores, a joined cluster all its CPUs), ``chunk_points`` (points per
    chunk, :data:`compensation.batch.CHUNK_POINTS`: fixed whatever the workers, so results do not depend on them)."""
    cluster: str | None = None
    address: str | None = None
    workers: int | None = None
    chunk_points: int = CHUNK_POINTS

    def check(self) -> None:
        """Refuse (UsageError, one line naming the option) settings that cannot run, Ray not installed included."""
        from ..validate import UsageError
        if self.cluster not in (None, *CLUSTERS):
            raise UsageError(f"--cluster {self.cluster}: expected one of {', '.join(CLUSTERS)}")
        if self.workers is not None and self.workers < 1:
            raise UsageError(f"--workers must be >= 1, got {self.workers}")
        if self.address is not None and self.cluster is None:
            raise UsageError("--address needs --cluster ray")
        if self.address is not None and self.workers is not None:
            raise UsageError("--workers sets the size of a local Ray instance; a joined cluster (--address) "
                             "uses all its CPUs")
        if self.chunk_points < 1:
            raise UsageError(f"--chunk-points must be >= 1, got {self.chunk_points}")
        if self.cluster == "ray":
            try:
                import_ray()
            except ClusterError as exc:
                raise UsageError(str(exc)) from None

    def executor(self):
        """The executor these settings name (a context manager, checked first): :class:`RayExecutor` for
        ``cluster="ray"``, else :class:`compensation.batch.LocalExecutor`."""
        self.check()
        if self.cluster == "ray":
            return RayExecutor(address=self.address, workers=self.workers)
        return LocalExecutor(self.workers)
