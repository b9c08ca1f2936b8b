"""Benchmark: the plain traditional baseline beside ``exact`` on machine-tool chains (TRUE residual).

``volcomp compensate --method traditional`` and ``--method exact`` (the CLI, one process) on

* ``mill-xyz``: ``tests/data/mill_pocket.nc`` (the pocket program; ``--work-offsets machine``);
* ``five-axis-ac``: a short five-axis program (below; linear moves, an arc, A and C changing),

each with a seeded smooth element set of the chain (±``--scale`` μm / μrad at 11 stations per axis) as
BOTH the model and the truth (``--truth``), so the TRUE residual is what each method itself leaves:
exact's is round-off, traditional's the field's gradient times the correction. Printed per machine:
the TRUE max (μm) of the program as written (uncompensated), traditional and exact, from each run's
``compensate_summary.json``.

    python benchmarks/bench_chain_traditional.py [--seed 0] [--scale 20]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
MILL_PROGRAM = HERE.parent / "tests" / "data" / "mill_pocket.nc"
FIVE_AXIS_PROGRAM = ("(5-AXIS TEST)\nG21 G90 G17\nT3 M6\nG0 X0. Y0. Z-200. A0. C0.\n"
                     "G1 X50. Y20. Z-250. A-30. C45. F500.\nG1 X60. C90.\nG1 Y30. A-30. C90.\nG2 X80. Y30. I10. J0.\n"
                     "G1 X120. Y-40. Z-300. A-45. C180.\nM30\n")


def run(machine_name, program, seed, scale, tmp):
    from compensation.app.cli import main
    from errormap.machine import load_machine
    from errormap.chain_elements import ChainElementSet
    mt = load_machine(machine_name)
    truth = ChainElementSet.random(mt, seed, scale, 11).save(tmp / f"{machine_name}_truth.json")
    row = {}
    for method in ("traditional", "exact"):
        out = tmp / f"{machine_name}_{method}"
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            rc = main(["compensate", str(program), "--machine", machine_name, "--model", str(truth), "--method", method,
                       "--out", str(out), "--truth", str(truth), "--work-offsets", "machine"])
        if rc != 0:
            raise SystemExit(f"{machine_name} {method}: compensate exited {rc}")
        e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
        row["uncompensated"] = e["true_uncompensated"]["max_um"]
        row[method] = e["true"]["max_um"]
        row["points"] = e["points"]
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scale", type=float, default=20.0, help="element scale, μm / μrad (1 σ)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        five = tmp / "five.nc"
        five.write_text(FIVE_AXIS_PROGRAM)
        print("| machine, program | points | uncompensated TRUE max μm | traditional TRUE max μm | exact TRUE max μm |")
        print("|---|---|---|---|---|")
        for name, prog in (("mill-xyz", MILL_PROGRAM), ("five-axis-ac", five)):
            r = run(name, prog, a.seed, a.scale, tmp)
            print(f"| {name}, {prog.name} | {r['points']} | {r['uncompensated']:.3f} | {r['traditional']:.4f} | "
                  f"{r['exact']:.2e} |")


if __name__ == "__main__":
    main()
