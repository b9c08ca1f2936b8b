"""No assumed zero: how the repository's own G-code programs are read without a work-offset table.

For every program of ``tests/data/gcode_corpus`` that the corpus expects compensated (the grinder's,
``c*``) and every program of ``tests/data/dialects`` plus ``tests/data/mill_pocket.nc`` (mill-xyz),
read it (parse + frames + plan, as ``volcomp compensate`` does before solving) with no table and
with ``--work-offsets machine``, and count: read (placed at some zero), refused naming a line. Run
against a checkout with ``--root`` to count an older revision (before it, the programs that select no
work system were read at machine zero: silently, a part-coordinate program would land elsewhere).

    python benchmarks/bench_no_assumed_zero.py [--root CHECKOUT]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def count(root: Path) -> dict:
    sys.path.insert(0, str(root))
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.pathio import read_path
    from errormap.io import InputError
    from errormap.machine import load_machine
    try:
        from compensation.nc_state import MACHINE, read_work_offsets
        machine_frame = read_work_offsets(MACHINE)
    except ImportError:
        machine_frame = None
    grinder, mill = load_machine(), load_machine("mill-xyz")
    corpus = sorted(p for p in (HERE / "tests" / "data" / "gcode_corpus").iterdir() if p.name.startswith("c"))
    mills = sorted((HERE / "tests" / "data" / "dialects").iterdir()) + [HERE / "tests" / "data" / "mill_pocket.nc"]
    out = {}
    for frame_name, frame in (("no table", None), ("--work-offsets machine", machine_frame)):
        read = refused = 0
        for p in corpus + mills:
            try:
                if p in corpus:
                    opts = {"block_delete": "off"} if "block-delete=off" in p.read_text("latin-1") else {}
                    if "block-delete=on" in p.read_text("latin-1"):
                        opts = {"block_delete": "on"}
                    read_path(p, grinder, work_offsets=frame, **opts)
                else:
                    read_tool_path(p, mill, CompensateSettings("exact", "", Path("."), work_offsets=frame))
                read += 1
            except InputError:
                refused += 1
        out[frame_name] = (len(corpus) + len(mills), read, refused)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", default=str(HERE))
    for k, (n, read, refused) in count(Path(ap.parse_args().root)).items():
        print(f"{k}: {n} programs, {read} read, {refused} refused")
