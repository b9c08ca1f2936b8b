"""Learned vs parametric, side by side, on the same machines and the same measurements.

``run_benchmark(machines, out_dir, settings)`` runs both compensation paths on each machine
under a set of measurement conditions, evaluates the TRUE residual (residual 2 of docs/explanation/kinematics.md: the
simulated truth machine driven with the compensated commands, minus the target) along the
test paths, records every run in MLflow under one parent run, and writes
``DIR/benchmark.json`` and ``DIR/report.html`` (:mod:`compensation.app.reports.benchmark`).

**Grinder** (one simulated truth machine, seed ``truth_seed``):

* measurements: laser-tracker sweeps (``errormap.chain_sweeps.simulate_mt_sweeps``) with ``stations``
  stations per axis and tracker noise ``noise_um``; ``n_measurements = stations × 3 balls × 3 axes``
  (ball-centre measurements); the closed loop adds ``n_checks`` check measurements;
* parametric: identified 23 elements → :class:`errormap.chain_field.ChainField` → ``exact`` solver;
* learned: the same identified elements → 11×11×11 feature points → the BP network
  (``training.fit_field``, LM, ``train_iter`` iterations) → ``batched-ga`` (the paper's GA,
  vectorised) on ``ga_points`` evenly spaced flute points and ``exact`` on the whole flute;
  the row's headline numbers are the ``exact`` ones (whole path), the GA subset is beside them;
* test path: the variable-helix flute (``compensation.toolpath.flute_path``), under the path
  condition :data:`PATH_CONDITIONS` (a warm machine at 24 °C, X and A approached from below as
  the path moves, Z from above because the wheel plunges to the flute-bottom radius);
* conditions: sweep density (stations), tracker noise, and each undeclared effect of the
  simulator in the truth, before and after the closed loop (check measurements → the effect search
  on the identified element set, :func:`errormap.diagnosis.chain_loop.closed_loop_chain` without its
  element update → the elements plus the found terms → compensate with it). The learned path has no
  element set: its row after the loop says so;
* out-of-catalogue conditions (``ooc_effects`` × ``ooc_checks``, and the same machine without an
  effect): after the loop the parametric path runs the user's path instead — the sweeps identified as
  ``volcomp identify`` does (smoothing, element covariance), then ``volcomp diagnose``'s closed loop on
  the checks (:func:`compensation.app.workflows.measurement.diagnose_chain`: element update, effects,
  the learned residual backfitted with the update, all re-estimated on all checks); its loop alone is
  the parametric row, its kept model (``model.json``) the hybrid row. Each row says which loop ran
  (``loop_method``: :data:`USER_LOOP` or :data:`EFFECTS_LOOP`).

**Hexapod** (and the tripod): simulated pose measurements (``simulate_poses``, known instrument
frame), ``n_poses`` poses with noise ``noise_um``;

* parametric: ``PKMCalibrator`` (Tikhonov + Morozov) → corrected inverse kinematics in the
  interpolation (``true_path_residual``);
* learned: :func:`training.pose_field.fit_pose_field` (commanded pose → pose error) →
  compensation by iterating the commanded pose (:func:`learned_pkm_commands`);
* test paths: the paper's sphere and hyperboloid passes (tripod: random workspace points).

**Machine-tool chain files** (``kind = "machine-tool"``: mill-xyz, five-axis-ac, a user's file):
per condition (no effect, each undeclared effect the chain has axes for) the user's path —
simulate a hidden truth → sweeps → identify → diagnose → exact compensation of the four body
diagonals with the identified set and with the loop's model — judged by the TRUE residual
(:mod:`compensation.app.workflows.chain_benchmark`).

The rows are in :mod:`.benchmark_flute` (the built-in machine's flute), :mod:`.benchmark_parallel`,
:mod:`.chain_benchmark` and :mod:`.arm_benchmark`; what they share in :mod:`.benchmark_common`.

Every figure is measured in this run; a part that cannot run is reported as not available
with the reason, never filled in.
"""
from __future__ import annotations

import platform
import time
from pathlib import Path

from errormap.io import write_json

from ..families import family_kind, family_of
from .benchmark_common import (PATH_CONDITIONS, BenchmarkSettings, RowLog, Tracker, bench_row, quick_settings,
                               rng_streams, say)
from .benchmark_flute import run_grinder
from .benchmark_parallel import run_pkm


def _bench_grinder(m, s, tracker, out_dir):
    return run_grinder(m, s, tracker), []


def _bench_pkm(m, s, tracker, out_dir):
    conds = None
    if not family_of(m).facts.paper_paths:  # one condition: the tripod has no paper test path
        conds = {(s.pkm_base_poses, s.pkm_base_noise_um): "baseline"}
    return run_pkm(m, s, tracker, conds), []


def _bench_chain(m, s, tracker, out_dir):
    """A chain file: the user's path per condition (workflows/chain_benchmark.py)."""
    from .chain_benchmark import run_chain
    log = RowLog(tracker)
    skipped = run_chain(m, s, log, out_dir, bench_row, rng_streams(s.seed), say)
    return log.rows, skipped


def _bench_arm(m, s, tracker, out_dir):
    """An arm: simulate → calibrate → compensate per condition (workflows/arm_benchmark.py)."""
    from .arm_benchmark import run_arm
    log = RowLog(tracker)
    run_arm(m, s, log, out_dir, bench_row, say)
    return log.rows, []


BENCH_BY_TARGET = {"grinder": _bench_grinder, "parallel": _bench_pkm, "chain": _bench_chain, "arm": _bench_arm}
"""Each family's benchmark (its registry target, :mod:`compensation.app.families`):
``(machine, settings, tracker, out_dir) -> (rows, skipped)``."""


def run_benchmark(machines, out_dir, settings: BenchmarkSettings | None = None, tracking_uri: str | None = None,
                  track: bool = True) -> dict:
    """Run the benchmark on ``machines`` (loaded machine objects) and write the outputs.

    Returns the ``benchmark.json`` document (``rows``, ``settings``, ``environment``, ``paths``).
    """
    from ..reports.benchmark import render_html
    s = settings or BenchmarkSettings()
    for m in machines:  # a kind no family holds, or one that does not run it: refused before any work
        try:
            family_of(m).target("benchmark")
        except ValueError as exc:
            from ..validate import UsageError
            raise UsageError(f"benchmark: machine {m.name!r} ({getattr(m, 'path', '') or 'built in'}): {exc}") from None
    out = Path(out_dir)
    t_start = time.perf_counter()
    tracker = Tracker(tracking_uri, enabled=track, run_name="benchmark (quick)" if s.quick else "benchmark")
    tracker.log_params({f"settings.{k}": v for k, v in s.to_dict().items()})
    rows, skipped = [], []
    status = "FAILED"
    from errormap.threads import limit_threads
    try:
        with limit_threads(s.torch_threads):
            rows, skipped = _run_machines(machines, s, tracker, out)
        total_s = time.perf_counter() - t_start
        doc = {"format": "volcomp-benchmark/1", "rows": rows, "skipped": skipped, "settings": s.to_dict(),
               "path_conditions": PATH_CONDITIONS, "seconds": total_s, "parent_run_id": tracker.parent_id,
               "tracking_uri": getattr(tracker, "uri", None),
               "environment": {"python": platform.python_version(), "machine": platform.machine(),
                               "cpus": _cpus()},
               "residual": "true residual (simulated truth machine driven with the compensated commands, minus the "
                           "target), vector norm per point, um",
               "machines": [{"name": m.name, "kind": family_kind(m), "file": getattr(m, "path", ""),
                             "sha256": getattr(m, "sha256", "")} for m in machines]}
        out.mkdir(parents=True, exist_ok=True)
        json_path = write_json(out / "benchmark.json", doc)
        from errormap.io import atomic_write
        html_path = out / "report.html"
        page = render_html(doc)
        with atomic_write(html_path, "w", encoding="utf-8") as fh:
            fh.write(page)
        doc["paths"] = {"json": str(json_path), "html": str(html_path)}
        status = "FINISHED"
        avail = [r for r in rows if r["available"]]
        tracker.finish({"seconds": total_s, "rows": len(rows), "rows_available": len(avail)},
                       artifacts=(json_path, html_path), status=status)
        return doc
    finally:
        if status != "FINISHED":
            try:
                tracker.finish({}, status="FAILED")
            except Exception:  # pragma: no cover - keep the original error
                pass


def _run_machines(machines, s: BenchmarkSettings, tracker: Tracker, out_dir):
    rows, skipped = [], []
    for m in machines:
        t0 = time.perf_counter()
        r, k = BENCH_BY_TARGET[family_of(m).target("benchmark")](m, s, tracker, out_dir)
        rows += r
        skipped += k
        say(f"{family_kind(m)} done in {time.perf_counter() - t0:.0f} s")
    return rows, skipped


def _cpus() -> int:
    import os
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        return os.cpu_count() or 0


__all__ = ["BenchmarkSettings", "quick_settings", "run_benchmark"]
