"""Assemble BENCHMARKS.md from the per-topic result files that each benchmark script writes.

Run after the benchmark scripts: ``python benchmarks/collect.py``. Nothing here measures;
it only gathers ``benchmarks/*_results.md`` in a fixed order under a common header.
"""
from __future__ import annotations

import argparse
import pathlib

HERE = pathlib.Path(__file__).resolve().parent
ORDER = ["demo", "suite", "benchmark", "foundation", "training", "solvers", "identification", "diagnosis", "sweeps_band", "sweeps_gauge", "hybrid", "hybrid_budget", "hybrid_oracle", "hybrid_chain", "hybrid_dev", "surrogate", "chain", "grinder_chain", "mt_solve", "lathe", "lathe_solve", "gcode_words", "mt_train", "mt_loop", "drift_regime", "drift_deploy", "drift_dev", "drift_dev_range", "drift_dev_gate", "drift_dev_horizon", "drift_dev_scale", "drift_ties", "arms", "pkm",
         "pkm_path", "toolpath", "export", "export_drift", "cli_startup", "house",
         "scale_out", "scale_gcode", "solve_scale", "cluster"]
# raw tables of a script whose section (named in ORDER) quotes them: not repeated in BENCHMARKS.md
QUOTED = {"htm_field", "scale_io"}  # in scale_out
HEADER = """# BENCHMARKS

Figures measured on this project's machine (2 cores, 24 GiB, no GPU) by the scripts in
`benchmarks/`; each section names its script, its data and which residual it shows
(model / true / measured, docs/explanation/kinematics.md). Speed figures are medians, and ratios are measured
side by side in one run. Regenerate a section by running its script, then
`python benchmarks/collect.py`.
"""


def main() -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()  # --help answers, writes nothing
    files = {p.name[: -len("_results.md")]: p for p in HERE.glob("*_results.md")}
    names = [n for n in ORDER if n in files] + sorted(set(files) - set(ORDER) - QUOTED)
    parts = [HEADER] + [files[n].read_text().strip() + "\n" for n in names]
    out = HERE.parent / "BENCHMARKS.md"
    tmp = out.with_suffix(".md.tmp")
    tmp.write_text("\n".join(parts))
    tmp.replace(out)
    print(f"wrote {out} from {', '.join(names)}")


if __name__ == "__main__":
    main()
