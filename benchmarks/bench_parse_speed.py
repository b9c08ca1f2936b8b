"""Reader speed on a 1,000,001-line plain program (``G1 X Y Z`` on ``mill-xyz``): best of 7
``parse_program`` (the block-wise path). docs/decisions/020-benchmark-notebook.md, "Programs as shops write them".

    PYTHONPATH=. python benchmarks/bench_parse_speed.py [label]
"""
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from compensation.gcode import AxisWords, parse_program
from errormap.machine import load_machine

N_LINES = 1_000_000
REPEATS = 7


def main() -> int:
    p = Path(tempfile.gettempdir()) / "volcomp_parse_1m.nc"
    if not p.exists():
        rng = np.random.default_rng(0)
        xyz = np.cumsum(rng.normal(0, 0.05, (N_LINES, 3)), axis=0) + [300, 200, -200]
        body = "\n".join(f"G1 X{a:.4f} Y{b:.4f} Z{c:.4f}" for a, b, c in xyz)
        p.write_text("%\nO1 (SPEED)\nG21 G90 G17\nG0 X300 Y200 Z-200\n" + body + "\nM30\n%\n")
    aw = AxisWords.of(load_machine("mill-xyz"))
    best = float("inf")
    for _ in range(REPEATS):
        t = time.perf_counter()
        prog = parse_program(p, axis_words=aw)
        best = min(best, time.perf_counter() - t)
    print(f"{sys.argv[1] if len(sys.argv) > 1 else ''} parse best of {REPEATS}: {best:.3f} s, {len(prog.moves)} moves")
    return 0


if __name__ == "__main__":
    sys.exit(main())
