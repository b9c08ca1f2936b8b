"""``compensate --cluster ray --workers 2`` on machine tools (the built-in grinder on its chain, ``mill-xyz``,
``five-axis-ac``, a
two-tool mill program: two batch contexts on every actor, and a ``lathe-xzc`` program whose turning
points stay on the driver) writes the bytes of the one-process run: the
chain path solves through the grinder's chunk plan and executors (compensation/batch.py,
compensation/app/workflows/cluster.py). Skipped only when Ray is not importable."""
from __future__ import annotations

import json

import pytest

ray = pytest.importorskip("ray")

from compensation.app.cli import main  # noqa: E402
from tests.test_chain_scaleout import (FIVE_AXIS_PROGRAM, MILL_PROGRAM, TOOLS_CSV, TWO_TOOL_PROGRAM,  # noqa: E402
                                       chain_files)
from tests.test_turning import MIXED  # noqa: E402  (a lathe program: turning and C-axis points)

pytestmark = pytest.mark.slow

CHUNK = 64
"""Points per chunk on Ray: the mill pocket (1554 points) in 25 chunks, shared by the two actors."""
LATHE_CHUNK = 8
"""The lathe program's points the method solves (its C-axis moves: a few dozen) in several chunks."""


@pytest.mark.parametrize("machine, program, seed, tools", [
    ("mill-xyz", None, 101, False), ("five-axis-ac", FIVE_AXIS_PROGRAM, 7, False),
    ("mill-xyz", TWO_TOOL_PROGRAM, 101, True), ("lathe-xzc", MIXED, 51, False)])
def test_ray_two_workers_write_the_one_process_bytes(ray_session, tmp_path, machine, program, seed, tools,
                                                     capsys):
    _, model = chain_files(tmp_path, machine, seed)
    prog = MILL_PROGRAM
    if program is not None:
        prog = tmp_path / "prog.nc"
        prog.write_text(program)
    base = ["compensate", str(prog), "--machine", machine, "--model", str(model), "--method", "exact",
            "--work-offsets", "machine", "--truth", str(model)]
    if tools:
        (tmp_path / "tools.csv").write_text(TOOLS_CSV)
        base += ["--tool-table", str(tmp_path / "tools.csv")]
    assert main(base + ["--out", str(tmp_path / "one")]) == 0
    assert main(base + ["--out", str(tmp_path / "ray"), "--cluster", "ray", "--workers", "2",
                        "--chunk-points", str(LATHE_CHUNK if machine == "lathe-xzc" else CHUNK)]) == 0
    assert (tmp_path / "one" / prog.name).read_bytes() == (tmp_path / "ray" / prog.name).read_bytes()
    one, on_ray = (json.loads((tmp_path / d / "compensate_summary.json").read_text()) for d in ("one", "ray"))
    assert on_ray["solved_on"].startswith("Ray") and on_ray["files"][0]["chunks"] > 1
    for key in ("true", "true_uncompensated", "true_path"):  # the TRUE residuals: the same numbers
        assert one["files"][0].get(key) == on_ray["files"][0].get(key)


@pytest.mark.parametrize("method", ["exact", "batched-ga"])
def test_ray_two_workers_write_the_one_process_bytes_on_the_grinder(ray_session, tmp_path, method):
    """The built-in grinder compensates on its chain through the same chunk plan: Ray's bytes are the one
    process's (the seeded GA too: the chunks and their seeds are the same with the same --chunk-points)."""
    from compensation.pathio import write_axes_gcode
    from compensation.toolpath import flute_path
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    g = load_machine()
    el = make_chain_truth(g, 7).elements.save(tmp_path / "el.json")
    prog = write_axes_gcode(tmp_path / "flute.nc", flute_path(turns=2, points_per_turn=100).axes(g))
    base = ["compensate", str(prog), "--model", str(el), "--method", method, "--work-offsets", "machine",
            "--chunk-points", str(CHUNK)]
    assert main(base + ["--out", str(tmp_path / "one")]) == 0
    assert main(base + ["--out", str(tmp_path / "ray"), "--cluster", "ray", "--workers", "2"]) == 0
    assert (tmp_path / "one" / prog.name).read_bytes() == (tmp_path / "ray" / prog.name).read_bytes()
    on_ray = json.loads((tmp_path / "ray" / "compensate_summary.json").read_text())
    assert on_ray["solved_on"].startswith("Ray") and on_ray["files"][0]["chunks"] > 1
