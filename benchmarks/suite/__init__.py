"""The registered benchmarks, in the page's order. A new benchmark: write ``benchmarks/suite/NAME.py`` with
``TITLE``, ``DATA`` and ``run(quick: bool, seed: int) -> dict`` (see ``benchmarks/run.py``), add NAME here,
run ``python -m benchmarks.run NAME`` (full figures) and ``python -m benchmarks.run --write-md``, and commit
``benchmarks/results/NAME.json`` with ``BENCHMARKS.md``. Keep ``--quick`` within a few CPU seconds: CI runs
the whole suite quick (tests/test_benchmarks_suite.py)."""

REGISTRY = [
    "identification",
    "sweeps",
    "closed_loop",
    "hybrid",
    "surrogate",
    "spatial_error",
    "solvers",
    "drift",
    "gcode_corpus",
    "large_inputs",
    "lathe",
    "tcp",
    "work_offsets",
    "export",
    "export_drift",
    "toolpath",
    "arms",
    "pkm",
    "cluster",
    "statistical",
    "demo",
    "cli_startup",
]
