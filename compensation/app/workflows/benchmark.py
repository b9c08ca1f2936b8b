"""Learned vs parametric, side by side, on the same machines and the same measurements.

``run_benchmark(machines, out_dir, settings)`` runs both compensation paths on each machine under a set of
measurement conditions, judges them by the TRUE residual (residual 2 of docs/explanation/kinematics.md: the
simulated truth machine driven with the compensated commands, minus the target; μm) along the test paths,
records every run in MLflow under one parent run, and writes ``DIR/benchmark.json`` and ``DIR/report.html``
(:mod:`compensation.app.reports.benchmark`). The paths, conditions, settings and rows per machine family are
described in docs/reference/benchmark.md.

The rows are in :mod:`.chain_benchmark` (every machine-tool chain, the built-in grinder included; its test parts in
:mod:`.benchmark_paths`), :mod:`.benchmark_parallel` and :mod:`.arm_benchmark` (one signature,
:data:`BENCH_BY_TARGET`); what they share in :mod:`.benchmark_common`. Every figure is measured in this run; a part that cannot run is reported as not
available with the reason, never filled in.
"""
from __future__ import annotations

import platform
import time
from pathlib import Path

from errormap.io import write_json

from ..families import family_of
from .arm_benchmark import run_arm
from .benchmark_common import PATH_CONDITIONS, BenchmarkSettings, RowLog, Tracker, quick_settings, say
from .benchmark_parallel import run_pkm
from .chain_benchmark import run_chain

BENCH_BY_TARGET = {"parallel": run_pkm, "chain": run_chain, "arm": run_arm}
"""Each family's benchmark (its registry target, :mod:`compensation.app.families`):
``(machine, settings, row log, out_dir) -> skipped conditions``, the rows added to the log."""


def run_benchmark(machines, out_dir, settings: BenchmarkSettings | None = None, tracking_uri: str | None = None,
                  track: bool = True) -> dict:
    """Run the benchmark on ``machines`` (loaded machine objects) and write the outputs.

    Returns the ``benchmark.json`` document (``rows``, ``settings``, ``environment``, ``paths``).
    """
    from ..reports.benchmark import render_html
    from ..reports.toolkit import write_page
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
               "machines": [{"name": m.name, "kind": m.kind, "file": getattr(m, "path", ""),
                             "sha256": getattr(m, "sha256", "")} for m in machines]}
        out.mkdir(parents=True, exist_ok=True)
        json_path = write_json(out / "benchmark.json", doc)
        html_path = write_page(out / "report.html", render_html(doc))
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
    log, skipped = RowLog(tracker), []
    for m in machines:
        t0 = time.perf_counter()
        skipped += BENCH_BY_TARGET[family_of(m).target("benchmark")](m, s, log, out_dir)
        say(f"{m.name} done in {time.perf_counter() - t0:.0f} s")
    return log.rows, skipped


def _cpus() -> int:
    import os
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        return os.cpu_count() or 0


__all__ = ["BenchmarkSettings", "quick_settings", "run_benchmark"]
