"""One G-code reader for every machine (issue 26 point 5): the axis words, their kinds and the arc
planes come from the machine file (:class:`compensation.gcode.AxisWords`); the grinder is the
machine whose words are X Z A, a lathe's X Z C (G18 arcs), a five-axis machine's X Y Z A C (rotary
words kept as programmed). Refusals name file, line, column and word, and the machine."""
import math
import re
from pathlib import Path

import numpy as np
import pytest

import compensation.gcode as gcode
from compensation.gcode import (AxisWords, default_axis_words, move_points, parse_program, render_program,
                               render_table)
from compensation.chain_gcode import parse_chain_program, plan_chain_gcode, render_chain_axes
from errormap.io import InputError
from errormap.machine import load_machine

CORPUS = sorted(p for p in (Path(__file__).parent / "data" / "gcode_corpus").iterdir() if p.name.startswith("c")
                and "G93" not in p.read_text(encoding="latin-1"))
"""The corpus's compensated programs the plain reader reads (G93 is read by the chain's pre-pass, compensation.tcp)."""
TOL_ON_CIRCLE_MM = 1e-9
"""A point of an arc from :func:`move_points` lies on its circle to round-off of cos/sin on ~100 mm
numbers (ulp 1.4e-14 mm; a few operations), so 1e-9 mm has a margin of >1000."""
TOL_REREAD_MM = 0.5e-6
"""A written linear number re-read: half a unit of the 6th decimal written in mm."""
TOL_REREAD_DEG = 0.5e-6
"""A written rotary number re-read: half a unit of the 6th decimal written in degrees."""
SHIFT_MM = 0.0123
"""Stand-in correction added to every linear vertex before writing (a compensation of 12.3 μm)."""


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_bytes(text.encode("latin-1"))
    return p


def _shifted(job, mt):
    """The planned vertices with every linear column moved by SHIFT_MM (rotary columns as planned)."""
    lin = np.array([a.kind == "linear" for a in mt.axes])
    return [v + SHIFT_MM * lin for v in job.vertices]


# ------------------------------------------------------------------------------------------ words

def test_axis_words_come_from_the_machine_file():
    g = AxisWords.of(load_machine())
    assert g.words == ("X", "Z", "A") and g.rotary == ("A",) and g.kept == () and g.planes == ("G18",)
    assert default_axis_words() == g
    lathe = AxisWords.of(load_machine("lathe-xzc"), keep_rotary=True)
    assert lathe.words == ("X", "Z", "C") and lathe.kept == ("C",) and lathe.planes == ("G18",)
    five = AxisWords.of(load_machine("five-axis-ac"), keep_rotary=True)
    assert five.words == ("X", "Y", "Z", "A", "C") and five.rotary == ("A", "C")
    assert five.planes == ("G17", "G18", "G19")
    with pytest.raises(ValueError, match="no G-code axis words"):
        AxisWords.of(load_machine("ur5"))
    with pytest.raises(ValueError, match="distinct axis words"):
        AxisWords("m", ("X", "X"))


def test_default_words_are_read_from_the_default_machine_when_called(monkeypatch):
    """No machine's words live in the reader: the default is the built-in default machine's file,
    loaded when a caller names none (here another machine stands in for it), never at import."""
    assert not [k for k, v in vars(gcode).items() if isinstance(v, AxisWords)]
    import errormap.machine as em
    mill = load_machine("mill-xyz")
    monkeypatch.setattr(em, "load_machine", lambda *a, **k: mill)
    assert default_axis_words().words == ("X", "Y", "Z")


MILL_LINES = 120  # plain X Y Z lines of the generated mill program (seed 0): several bulk runs


def _mill_program(seed: int) -> str:
    """A three-axis program: plain moves with missing words, G17 arcs, an inch section, comments."""
    rng = np.random.default_rng(seed)
    out = ["%", "O1234 (MILL)", "G21 G90 G17", "T1 M6", "G0 X0. Y0. Z5.", "G1 Z-1. F300."]
    for i in range(MILL_LINES):
        words = [f"{w}{v:.4f}" for w, v in zip("XYZ", rng.uniform(-50, 50, 3)) if rng.random() < 0.8] or ["X1."]
        out.append(("N%d " % i if i % 3 == 0 else "") + " ".join(words) + (" (c)" if i % 7 == 0 else ""))
        if i == 40:
            out += ["G1 X0. Y0.", "G2 X10. Y0. I5. J0.", "G1 X10. Y0. Z0."]
        if i == 80:
            out += ["G20", "X0.5 Y0.25 Z0.1", "G21"]
    return "\n".join(out + ["M30", "%"]) + "\n"


@pytest.mark.parametrize("machine", ["mill-xyz", "lathe-xzc"])
def test_blockwise_reader_of_another_three_word_machine_is_the_per_line_one(tmp_path, machine, monkeypatch):
    """The block-wise reader and writer take the machine's three words as arguments: a mill's X Y Z
    (all linear) and a lathe's X Z C (C rotary, all words written) read into the same classes and
    moves as the per-line reader, and render_table writes the same bytes as render_program."""
    monkeypatch.setattr(gcode, "BULK_MIN_RUN", 1)
    ax = AxisWords.of(load_machine(machine))
    text = _mill_program(0)
    if machine == "lathe-xzc":
        text = text.replace("Y", "C").replace("G17", "G18").replace("J0.", "K0.")
    path = _write(tmp_path, "p.nc", text)
    fast, slow = (parse_program(path, fast=f, axis_words=ax) for f in (True, False))
    assert fast.table is not None and slow.table is None
    assert fast.classes == slow.classes
    assert [(m.index, m.kind, m.start.tobytes(), m.end.tobytes(), m.units, sorted(m.words)) for m in fast.moves] == \
        [(m.index, m.kind, m.start.tobytes(), m.end.tobytes(), m.units, sorted(m.words)) for m in slow.moves]
    comp = [m for m in slow.moves if m.compensate]
    rng = np.random.default_rng(1)
    verts = [np.vstack([move_points(m, [0.5, 1.0])] if k % 5 == 0 else [m.end[None, :]]) + rng.normal(0, 1e-3, 3)
             for k, m in enumerate(comp)]
    counts = [len(v) for v in verts]
    want, _ = render_program(slow, verts, header=["test"])
    got, _ = render_table(fast, np.vstack(verts), counts, header=["test"])
    assert got == want
    assert any(len(v) > 1 for v in verts) and any(not set(ax.words) <= set(m.words) for m in comp)


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.name)
def test_grinder_chain_file_reads_the_corpus_as_the_grinder(path):
    """The grinder as a chain file (grinder-chain: words X Z A from its joints) reads every compensated
    program of the corpus into the same classes and moves as the grinder's reader."""
    opts = {}
    text = path.read_text(encoding="latin-1")
    for key, opt in (("block-delete=on", {"block_delete": "on"}), ("block-delete=off", {"block_delete": "off"}),
                     ("rapids=compensate", {"rapids": "compensate"})):
        if key in text.split("expect:", 1)[1].splitlines()[0]:
            opts.update(opt)
    grinder = parse_program(path, fast=False, **opts)
    chain = parse_chain_program(path, load_machine("grinder-chain"), **opts)
    assert chain.classes == grinder.classes
    assert len(chain.moves) == len(grinder.moves)
    for a, b in zip(chain.moves, grinder.moves):
        assert (a.index, a.kind, a.compensate, a.units, a.incremental) == (b.index, b.kind, b.compensate, b.units,
                                                                          b.incremental)
        np.testing.assert_array_equal(a.start, b.start)
        np.testing.assert_array_equal(a.end, b.end)
        assert a.arc == b.arc


# ------------------------------------------------------------------------------------------ lathe

LATHE_PROGRAM = ("%\nO2001 (LATHE X Z C)\nG18 G90 G21\nT1 M6\nG0 X10. Z-20. C0.\n"
                 "G1 X10. Z-20. C0. F100.\n"
                 "G3 X20. Z-10. I10. K0. C30.\n"       # quarter turn, C turns along it (a helix)
                 "G2 X10. Z-20. R10.\n"                 # back along the same circle, clockwise
                 "G91 G1 X0.5 C15.\nG90\n"
                 "(FINISH)\nG1 X12. Z-18.\nM30\n%\n")


def test_lathe_reads_g18_arcs_over_x_z_with_c(tmp_path):
    mt = load_machine("lathe-xzc")
    path = _write(tmp_path, "lathe.nc", LATHE_PROGRAM)
    prog = parse_chain_program(path, mt)
    assert prog.axis_words.words == ("X", "Z", "C")
    arcs = [m for m in prog.moves if m.arc is not None]
    assert len(arcs) == 2
    g3, g2 = arcs
    # G18: u = Z (column 1), v = X (column 0); centre X20 Z-20 from I10 K0, radius 10
    assert (g3.arc["ju"], g3.arc["jv"]) == (1, 0)
    assert (g3.arc["uc"], g3.arc["vc"]) == (-20.0, 20.0) and g3.arc["r0"] == pytest.approx(10.0)
    # counter-clockwise seen from +Y (from Z towards X): start at angle -90°, end at 0°, +90°
    assert g3.arc["sweep"] == pytest.approx(math.pi / 2)
    assert g2.arc["sweep"] == pytest.approx(-math.pi / 2)  # R10 clockwise back: the short arc
    t = np.linspace(0.0, 1.0, 11)
    pts = move_points(g3, t)
    r = np.hypot(pts[:, 0] - 20.0, pts[:, 1] + 20.0)
    assert np.abs(r - 10.0).max() < TOL_ON_CIRCLE_MM
    np.testing.assert_allclose(pts[:, 2], 30.0 * t, atol=TOL_ON_CIRCLE_MM)  # C linear along the arc
    assert np.abs(pts[-1] - g3.end).max() < TOL_ON_CIRCLE_MM
    inc = next(m for m in prog.moves if m.incremental)
    np.testing.assert_array_equal(inc.end, [10.5, -20.0, 45.0])


def test_lathe_program_written_back_writes_c_and_keeps_every_other_line(tmp_path):
    mt = load_machine("lathe-xzc")
    path = _write(tmp_path, "lathe.nc", LATHE_PROGRAM)
    prog = parse_chain_program(path, mt)
    job = plan_chain_gcode(prog, 0.5)
    text = render_chain_axes(prog, np.concatenate(_shifted(job, mt)), job.counts, header=["test"])
    src = LATHE_PROGRAM.splitlines(keepends=True)
    moved = {m.index for m in prog.moves if m.compensate}
    out = text.splitlines(keepends=True)
    assert out[:2] == src[:2] and out[2] == "(test)\n"  # header after '%' and the O line
    for i, ln in enumerate(src):
        if i not in moved:
            assert ln in out  # every non-motion line byte for byte
    # the arcs became G1 chords (I K R gone); the lathe's C is one of the three axes the exact solver
    # moves (X, Z, C), so it is written on every compensated line, like X and Z: along the G3 arc's
    # chords and on the G2 arc (where C stays at 30) alike
    assert "G1 X10.014277 Z-19.788878 C0.379747\n" in out and "G1 X19.813478 Z-9.989677 C30.000000\n" in out
    assert not re.search(r"\b[IKR]-?\d", text) and not re.search(r"\bG[23]\b", text)
    assert "G91 G1 X0.500000 C15.000000 Z0.000000\n" in out  # incremental: differences of what was written
    assert "G1 X12.012300 Z-17.987700 C45.000000\n" in out  # C added where the source line had none
    back = plan_chain_gcode(parse_chain_program(_write(tmp_path, "out.nc", text), mt), 1e9).axes
    want = np.concatenate(_shifted(job, mt))
    assert back.shape == want.shape
    assert np.abs(back[:, :2] - want[:, :2]).max() < TOL_REREAD_MM
    assert np.abs(back[:, 2] - want[:, 2]).max() < TOL_REREAD_DEG


@pytest.mark.parametrize("line, col, what", [
    ("G1 X10. Y5. Z-20.", 9, "the machine 'lathe-xzc' has no Y axis (its axes: X Z C)"),
    ("G1 X10. B5.", 9, "has no B axis"),
    ("G1 U1.", 4, "has no U axis (its axes: X Z C; on lathe dialects U is incremental X)"),
    ("G3 X20. Z-10. J5.", 15, "arc centre Y offset, but the machine 'lathe-xzc' has no Y axis"),
    ("G17 G3 X20. Z-10. I10.", 8, "G3 arc in the G17 plane: the machine 'lathe-xzc' has no Y axis "
                                  "(its arc planes: G18 XZ)"),
    ("G19 G2 Z-10. K5.", 8, "G19 plane: the machine 'lathe-xzc' has no Y axis"),
    ("G1 X10. Z-20. A5.", 15, "has no A axis"),
])
def test_lathe_refusals_name_line_column_and_machine(tmp_path, line, col, what):
    path = _write(tmp_path, "bad.nc", f"G18 G90 G21\nG1 X10. Z-20. C0. F100.\n{line}\nM30\n")
    with pytest.raises(InputError) as err:
        parse_chain_program(path, load_machine("lathe-xzc"))
    msg = str(err.value)
    assert msg.startswith(f"{path}: line 3, column {col}: ") and what in msg and "\n" not in msg, msg


# ------------------------------------------------------------------------------------------ five-axis

FIVE_PROGRAM = ("(5-AXIS)\nG21 G90 G17\nT3 M6\nG0 X0. Y0. Z-200. A0. C0.\n"
                "G1 X50. Y20. Z-250. A-30. C45. F500.\n"
                "G1 X60. C90.\n"                        # A not on the line, unchanged: not written
                "G1 Y30. A-30.000 C90.\n"               # unchanged rotary words keep their text
                "G2 X80. Y30. I10. J0. C120.\n"         # G17 arc, C along it
                "G18 G3 X90. Z-240. I0. K10.\n"         # G18 arc (XZ)
                "G19 G2 Y40. Z-230. J0. K10.\n"         # G19 arc (YZ)
                "G91 G1 X1. A0.5\nG90\nM30\n")


def test_five_axis_keeps_a_and_c_as_programmed(tmp_path):
    mt = load_machine("five-axis-ac")
    path = _write(tmp_path, "five.nc", FIVE_PROGRAM)
    prog = parse_chain_program(path, mt)
    assert [m.arc["ju"] for m in prog.moves if m.arc] == [0, 2, 1]  # G17 X→Y, G18 Z→X, G19 Y→Z
    assert [m.arc["jv"] for m in prog.moves if m.arc] == [1, 0, 2]
    job = plan_chain_gcode(prog, 0.5)
    text = render_chain_axes(prog, np.concatenate(_shifted(job, mt)), job.counts)
    out = text.splitlines(keepends=True)
    assert "G1 X60.012300 C90. Y20.012300 Z-249.987700\n" in out  # A not appended: it does not move
    assert "G1 Y30.012300 A-30.000 C90. X60.012300 Z-249.987700\n" in out  # A, C texts as written
    for ln in FIVE_PROGRAM.splitlines(keepends=True):
        if not re.search(r"\b[XYZ]-?\d", ln):
            assert ln in out
    # every rotary number in the output is the programmed orientation, every linear one the corrected
    back = plan_chain_gcode(parse_chain_program(_write(tmp_path, "out.nc", text), mt), 1e9).axes
    want = np.concatenate(_shifted(job, mt))
    assert back.shape == want.shape
    assert np.abs(back[:, 3:] - np.concatenate(job.vertices)[:, 3:]).max() < TOL_REREAD_DEG
    assert np.abs(back[:, :3] - want[:, :3]).max() < TOL_REREAD_MM
    chord_lines = [ln for ln in out if ln not in FIVE_PROGRAM and not ln.startswith(("G", "("))]
    assert chord_lines and all(ln.startswith("X") for ln in chord_lines)
    assert any(" C" in ln for ln in chord_lines)           # C moves along the G17 arc: on its chords
    assert not any(" A" in ln for ln in chord_lines)       # A does not move on any arc: never added


def test_five_axis_refuses_a_word_it_lacks(tmp_path):
    path = _write(tmp_path, "five.nc", "G21 G90 G17\nG0 X0. Y0. Z-200. A0. C0.\nG1 X10. B5.\nM30\n")
    with pytest.raises(InputError, match=r"line 3, column 9: 'B5\.': the machine 'five-axis-ac' has no B axis "
                                         r"\(its axes: X Y Z A C\)"):
        parse_chain_program(path, load_machine("five-axis-ac"))


# ------------------------------------------------------------------------------------------ grinder

@pytest.mark.parametrize("line, col, what", [
    ("G1 X2 Y1", 7, "the machine 'micro-drill flute grinder' has no Y axis (its axes: X Z A)"),
    ("G1 X2 C1", 7, "has no C axis"),
    ("G18 G2 X2 Z3 J1", 14, "arc centre Y offset, but the machine 'micro-drill flute grinder' has no Y axis"),
    ("G17 G2 X2 Z3 I1", 8, "G17 plane: the machine 'micro-drill flute grinder' has no Y axis "
                           "(its arc planes: G18 XZ)"),
])
def test_grinder_refusals_name_the_machine(tmp_path, line, col, what):
    from path_files import read_as_compensate
    path = _write(tmp_path, "g.nc", f"G21 G90 G1 X1 Z2 A3 F100\n{line}\nM30\n")
    with pytest.raises(InputError) as err:
        read_as_compensate(path, load_machine())
    msg = str(err.value)
    assert msg.startswith(f"{path}: line 2, column {col}: ") and what in msg, msg


def test_render_program_writes_every_grinder_word(tmp_path):
    """On the grinder every word is compensated: a line without A gets one appended, even unchanged."""
    path = _write(tmp_path, "g.nc", "G21 G90\nG1 X1 Z2 A3 F100\nX2\nM30\n")
    prog = parse_program(path, fast=False)
    text, _ = render_program(prog, [np.array([[1.0, 2.0, 3.0]]), np.array([[2.0, 2.0, 3.0]])])
    assert text == "G21 G90\nG1 X1.000000 Z2.000000 A3.000000 F100\nX2.000000 Z2.000000 A3.000000\nM30\n"


@pytest.mark.parametrize("machine,block_wise", [("mill-xyz", True), ("five-axis-ac", False)])
def test_chain_reader_is_block_wise_where_it_can(tmp_path, machine, block_wise):
    """A chain's program goes through the block-wise reader when its machine has three axis words, none kept
    (the mill), else line by line (a five-axis machine keeps A and C); the moves are the per-line reader's."""
    import dataclasses
    mt = load_machine(machine)
    path = (Path(__file__).parent / "data" / "mill_pocket.nc" if block_wise
            else _write(tmp_path, "five.nc", FIVE_PROGRAM))
    prog = parse_chain_program(path, mt)
    assert (prog.table is not None) == block_wise
    ref = parse_program(path, fast=False, axis_words=prog.axis_words)
    assert prog.classes == ref.classes
    rec = [(m.index, m.kind, m.start.tobytes(), m.end.tobytes(), m.units, sorted(m.words)) for m in prog.moves]
    assert rec == [(m.index, m.kind, m.start.tobytes(), m.end.tobytes(), m.units, sorted(m.words)) for m in ref.moves]
    assert dataclasses.asdict(prog.axis_words) == dataclasses.asdict(ref.axis_words)
