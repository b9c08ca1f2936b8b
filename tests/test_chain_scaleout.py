"""``compensate`` on machine-tool chains through the grinder's batch machinery (compensation/batch.py):
``--chunk-points`` and ``--workers`` give the default's bytes (one chunk plan, per-chunk seeds, tool
lengths as batch contexts); ``--max-segment-mm`` splits a chain's moves by tool-point length, and the
TRUE residual along a long move (``--truth``) is reported before and after the split. The Ray runs
(``--cluster ray --workers 2``, the same bytes) are in tests/test_chain_cluster.py."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from tests.test_lathe_compensate import LATHE_PROGRAM
from tests.test_turning import MIXED

DATA = Path(__file__).resolve().parent / "data"
MILL_PROGRAM = DATA / "mill_pocket.nc"

ELEMENT_SCALE_UM = 10.0
"""Element values of ±10 μm / μrad (1 σ): a real machine tool's geometric errors (tests/test_chain_compensate.py's)."""
SMALL_CHUNK = 7
"""Points per chunk in the identity runs: every file cut into many chunks, the last one short."""

FIVE_AXIS_PROGRAM = ("(5-AXIS TEST)\nG21 G90 G17\nT3 M6\nG0 X0. Y0. Z-200. A0. C0.\n"
                     "G1 X50. Y20. Z-250. A-30. C45. F500.\nG1 X60. C90.\nG1 Y30. A-30. C90.\nG2 X80. Y30. I10. J0.\n"
                     "G1 X120. Y-40. Z-230. A-10. C180.\nM30\n")
TWO_TOOL_PROGRAM = ("%\nO2001 (TWO TOOLS)\nG21 G90 G94 G17 G40 G49 G80\nG54\nT1 M6\nG43 H1\nG0 X50. Y100. Z-150.\n"
                    "G1 Z-200. F300.\nG1 X300. Y300. F1200.\nG1 X320. Y320. Z-210.\nG0 Z-150.\nT2 M6\nG43 H2\n"
                    "G0 X100. Y150.\nG1 Z-220. F300.\nG1 X450. Y350. F1200.\nG0 Z-150.\nM30\n%\n")
TOOLS_CSV = "tool,length_mm\n1,100\n2,135\n"

LONG_MOVE_MM = 400.0
"""The long move of :data:`LONG_MOVE_PROGRAM`: X 100 → 500 on the mill (its X stroke is 600 mm)."""
LONG_MOVE_PROGRAM = ("(ONE LONG MOVE)\nG21 G90 G17\nG0 X100. Y200. Z-300.\nG1 Z-320. F300.\n"
                     "G1 X500. Y220. Z-330. F1500.\nG0 Z-300.\nM30\n")
PLUNGE_MM = 20.0
"""The plunge before it (Z -300 → -320), split too."""
SEGMENT_MM = 2.0
"""The split of the long move: 2 mm pieces (200 of them)."""


def chain_files(tmp_path, name, seed):
    """A seeded element set of ``name`` (the model and, in the residual tests, the truth)."""
    mt = load_machine(name)
    return mt, ChainElementSet.random(mt, seed, ELEMENT_SCALE_UM, 11).save(tmp_path / f"{name}.json")


def compensate(prog, machine, model, out, *extra, truth=None):
    args = ["compensate", str(prog), "--machine", machine, "--model", str(model), "--method", "exact",
            "--out", str(out), "--work-offsets", "machine", *extra]
    if truth is not None:
        args += ["--truth", str(truth)]
    assert main(args) == 0
    return json.loads((out / "compensate_summary.json").read_text())


@pytest.mark.parametrize("machine, program, seed", [
    ("mill-xyz", None, 101), ("five-axis-ac", FIVE_AXIS_PROGRAM, 7),
    ("lathe-xzc", LATHE_PROGRAM, 51), ("lathe-xzc", MIXED, 51)])  # C-axis mode; turning + C-axis points
def test_chunk_points_and_workers_give_the_default_bytes(tmp_path, machine, program, seed, capsys):
    _, model = chain_files(tmp_path, machine, seed)
    prog = MILL_PROGRAM
    if program is not None:
        prog = tmp_path / "prog.nc"
        prog.write_text(program)
    default = compensate(prog, machine, model, tmp_path / "default", truth=model)  # (the truth: turning points counted)
    chunked = compensate(prog, machine, model, tmp_path / "chunked", "--chunk-points", str(SMALL_CHUNK),
                         "--workers", "2", truth=model)
    assert (tmp_path / "default" / prog.name).read_bytes() == (tmp_path / "chunked" / prog.name).read_bytes()
    n = default["files"][0]["points"] - default["files"][0].get("turning", {}).get("points", 0)  # by the method
    assert default["files"][0]["chunks"] == 1 and chunked["files"][0]["chunks"] == -(-n // SMALL_CHUNK)
    assert chunked["chunk_points"] == SMALL_CHUNK and chunked["solved_on"] == "this process, 2 thread(s)"


def test_tool_lengths_are_solved_in_chunks_with_the_default_bytes(tmp_path, capsys):
    """Two tool lengths (G43 H1, H2): two contexts of the batch, the same bytes at any chunk size, and
    a tool-length TRUE residual (the truth at each tool point) of the model's own round-off."""
    _, model = chain_files(tmp_path, "mill-xyz", 101)
    prog, tools = tmp_path / "tools.nc", tmp_path / "tools.csv"
    prog.write_text(TWO_TOOL_PROGRAM)
    tools.write_text(TOOLS_CSV)
    opts = ("--tool-table", str(tools))
    a = compensate(prog, "mill-xyz", model, tmp_path / "a", *opts, truth=model)
    b = compensate(prog, "mill-xyz", model, tmp_path / "b", *opts, "--chunk-points", "5", truth=model)
    assert (tmp_path / "a" / "tools.nc").read_bytes() == (tmp_path / "b" / "tools.nc").read_bytes()
    e = a["files"][0]
    assert e["chunks"] == 2 and b["files"][0]["chunks"] > 2  # one unit per tool, then cut in chunks of 5
    assert e["tools_used"] == {"1": 100.0, "2": 135.0}
    assert e["true"]["max_um"] < MODEL_ROUNDOFF_UM  # the truth is the model: Newton's round-off at every tool
    assert e["true_uncompensated"]["max_um"] > UNCOMPENSATED_MIN_UM


MODEL_ROUNDOFF_UM = 1e-6
"""The exact chain solver's model residual (tests/test_chain_compensate.py TOL_MODEL_RESIDUAL_UM): with the
truth equal to the model, the TRUE residual at the vertices is this round-off."""
UNCOMPENSATED_MIN_UM = 15.0
"""±10 μm / μrad elements through ~0.5 m lever arms: tens of μm along these programs (50 μm observed)."""
CHORD_FACTOR = 0.02
"""Splitting a move into pieces ``k`` times shorter cuts what the field's curvature leaves between the
vertices ``k²``-fold (``κ L² / 8``): from one 400 mm piece to 2 mm pieces that is 40 000-fold; the test asks
for 50-fold (2 %), far inside it, so the field's non-quadratic shape cannot fail it."""


def test_max_segment_splits_a_long_move_and_reports_the_true_residual_along_it(tmp_path, capsys):
    """The truth is the model: at the vertices compensation is exact, so what is left along the move is
    the straight interpolation between compensated vertices — large for the unsplit 400 mm move, small
    once it is cut into 2 mm pieces."""
    _, model = chain_files(tmp_path, "mill-xyz", 101)
    prog = tmp_path / "long.nc"
    prog.write_text(LONG_MOVE_PROGRAM)
    none = compensate(prog, "mill-xyz", model, tmp_path / "none", "--max-segment-mm", "none", truth=model)
    split = compensate(prog, "mill-xyz", model, tmp_path / "split", "--max-segment-mm", str(SEGMENT_MM), truth=model)
    n0, n1 = none["files"][0], split["files"][0]
    assert split["max_segment_mm"] == SEGMENT_MM and none["max_segment_mm"] is None
    length = np.linalg.norm([400.0, 20.0, -10.0])  # the long move's tool-point path (a mill: its axis path)
    pieces = int(np.ceil(PLUNGE_MM / SEGMENT_MM)) + int(np.ceil(length / SEGMENT_MM))  # the plunge's + the move's
    assert n0["points"] == 2 and n1["points"] == pieces
    for e in (n0, n1):
        assert e["true"]["max_um"] < MODEL_ROUNDOFF_UM               # at the vertices
        assert e["true_path_uncompensated"]["max_um"] > UNCOMPENSATED_MIN_UM
    assert n1["true_path"]["max_um"] < CHORD_FACTOR * n0["true_path"]["max_um"]
    out = capsys.readouterr().out
    assert "along the moves max" in out
    text = (tmp_path / "split" / "long.nc").read_text()
    assert text.count("\n") >= int(np.ceil(length / SEGMENT_MM))  # one line per piece


def test_max_segment_on_a_five_axis_move_measures_the_tool_point(tmp_path, capsys):
    """A rotary move sweeps the tool point around the rotary axes: the pieces follow its path (150 mm tool,
    the C turn of 45° alone sweeps an arc), not the linear axes' travel."""
    from compensation.chain_gcode import length_pieces, parse_chain_program
    from compensation.solvers.chain_exact import nominal_and_jacobian
    mt, model = chain_files(tmp_path, "five-axis-ac", 7)
    prog = tmp_path / "five.nc"
    prog.write_text(FIVE_AXIS_PROGRAM)
    moves = [m for m in parse_chain_program(prog, mt).moves if m.compensate and m.kind == "linear"]
    pieces = length_pieces(moves, lambda q: nominal_and_jacobian(mt, q)[0], 1.0)
    linear = np.array([np.linalg.norm((m.end - m.start)[:3]) for m in moves])
    # the C turn with X (X 50 → 60, C 45 → 90) sweeps more than twice its 10 mm of X; a linear-only move
    # (Y 20 → 30, A and C as before) is its axis chord
    assert pieces[1] > 2 * linear[1] and pieces[2] == np.ceil(linear[2])
    # the polyline of LENGTH_SAMPLES (16) intervals is the length to within its own chord error (an independent
    # fine polyline of 4096 intervals)
    t = np.linspace(0, 1, 4097)
    from compensation.gcode import move_points
    fine = np.linalg.norm(np.diff(nominal_and_jacobian(mt, move_points(moves[1], t))[0], axis=0), axis=1).sum()
    assert abs(pieces[1] - np.ceil(fine)) <= 1
    summary = compensate(prog, "five-axis-ac", model, tmp_path / "o", "--max-segment-mm", "5")
    assert summary["files"][0]["points"] > len(moves) + 2
