"""The G-code corpus (tests/data/gcode_corpus): every program is either compensated with a
line-by-line diff that touches only what it should, or refused naming line, column and word.

Each program says what is expected in its first ``expect:`` comment:
``expect: compensate [block-delete=on|off] [rapids=compensate] [max-segment=MM]`` or
``expect: refuse line=N col=C word=W [work-offsets=none]``. Programs ``c*`` are compensated, ``r*``
refused; they are written in several dialect styles (LinuxCNC, grbl, Fanuc-like, Fusion-post-like),
in machine coordinates (the grinder's axes): each is read with ``--work-offsets machine`` unless it
says ``work-offsets=none`` (no table: a program is never read at an assumed zero).
"""
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compensation.app.cli import main
from compensation.gcode import tokenize
from compensation.nc_state import MACHINE, read_work_offsets
from compensation.solvers import solve
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.chain_kernel import forward
from errormap.chain_truth import make_chain_truth
from path_files import read_as_compensate, render_gcode

CORPUS = Path(__file__).parent / "data" / "gcode_corpus"
AXES = ("X", "Z", "A")
"""The axis words the corpus is written for: the built-in default machine's (test_gcode_axis_words
checks them against its file)."""
PROGRAMS = sorted(p for p in CORPUS.iterdir() if p.is_file())
TOL_REREAD_MM = 1.3e-6
"""Re-read vertex vs compensated vertex: half a unit of the last written decimal, 0.5e-6 mm
(mm) or 0.5e-7 in = 1.27e-6 mm (inch)."""
TOL_REREAD_DEG = 0.5e-6
TOL_LANDING_MM = 3e-6
"""Model landing point of the re-read output vs target: the exact solver's 1e-4 μm plus the
writer's rounding (≤ 1.3e-6 mm per linear axis; 0.5e-6 deg at ≤ 60 mm radius ≈ 0.5e-6 mm)."""


def expectation(path: Path) -> dict:
    line = next(ln for ln in path.read_text(encoding="latin-1").splitlines() if "expect:" in ln)
    words = line.split("expect:", 1)[1].replace(")", " ").split()
    out = {"what": words[0]}
    for w in words[1:]:
        k, v = w.split("=", 1)
        out[k] = v
    return out


def read_options(exp: dict) -> dict:
    opts = {}
    if "block-delete" in exp:
        opts["block_delete"] = exp["block-delete"]
    if "rapids" in exp:
        opts["rapids"] = exp["rapids"]
    offsets = exp.get("work-offsets", MACHINE)  # the corpus is in machine coordinates (module docstring)
    if offsets != "none":
        opts["work_offsets"] = read_work_offsets(offsets)
    return opts


@pytest.fixture(scope="module")
def field(grinder):
    return ChainField(grinder, make_chain_truth(grinder, 7).elements)


def test_corpus_is_large_and_mixed():
    kinds = [expectation(p)["what"] for p in PROGRAMS]
    assert len(PROGRAMS) >= 30
    assert kinds.count("compensate") >= 15 and kinds.count("refuse") >= 30
    assert all(p.name[0] == ("c" if k == "compensate" else "r") for p, k in zip(PROGRAMS, kinds))


@pytest.mark.parametrize("path", [p for p in PROGRAMS if p.name.startswith("r")], ids=lambda p: p.name)
def test_refused_programs_name_line_column_and_word(path, grinder):
    exp = expectation(path)
    with pytest.raises(InputError) as err:
        read_as_compensate(path, grinder, **read_options(exp))
    msg = str(err.value)
    assert msg.startswith(f"{path}: line {exp['line']}, column {exp['col']}: "), msg
    assert exp["word"].lower() in msg.lower(), msg


def _skeleton(line: str) -> tuple:
    """Words other than X Z A (letter, value) and the comment text of a line."""
    body = line.rstrip("\r\n")
    _, words, _ = tokenize(body)
    kept = [(w.letter, w.value) for w in words if w.letter not in AXES]
    comments = re.findall(r"\([^)]*\)|;.*$", body)
    return kept, comments


@pytest.mark.parametrize("path", [p for p in PROGRAMS if p.name.startswith("c")], ids=lambda p: p.name)
def test_compensated_programs_change_only_their_motion(path, grinder, field):
    exp = expectation(path)
    opts = read_options(exp)
    seg = float(exp["max-segment"]) if "max-segment" in exp else "auto"
    tp = read_as_compensate(path, grinder, field, max_segment_mm=seg, **opts)
    targets = forward(grinder, tp.axes)
    res = solve("exact", field, targets, grinder, target_axes=tp.axes)
    assert res.success.all()
    text, groups = render_gcode(tp, res.axes)
    prog = tp.source.program
    compensated = {m.index: m for m in prog.moves if m.compensate}
    for i, line in enumerate(prog.lines):
        if i not in compensated:
            assert groups[i] == [line], f"{path.name}: line {i + 1} changed"
            continue
        m = compensated[i]
        first, extra = groups[i][0], groups[i][1:]
        src_words, src_comments = _skeleton(line)
        out_words, out_comments = _skeleton(first)
        if m.kind == "arc":  # an arc becomes G1 chords: its G2/G3 and I K R P words go
            src_words = [(k, v) for k, v in src_words if k not in "IKRP" and not (k == "G" and v in (2, 3))]
            out_words = [(k, v) for k, v in out_words if not (k == "G" and v == 1)]
        assert out_words == src_words and out_comments == src_comments, f"{path.name}: line {i + 1}: {first!r}"
        ending = line[len(line.rstrip("\r\n")):]
        # a block-delete move keeps its '/' on every piece (issue 30), and only such a move
        slash = "/" if line.lstrip(" \t").startswith("/") else ""
        for e in extra:
            assert re.fullmatch(re.escape(slash) + r"X-?\d+\.\d+ Z-?\d+\.\d+ A-?\d+\.\d+(\r\n|\n)?", e), e
            assert e.endswith(ending) or i == len(prog.lines) - 1
    # what the controller reads back is the compensated vertices, and they land on the targets
    back = _reread(text, path, grinder, opts)
    assert back.axes.shape == res.axes.shape
    assert np.abs(back.axes[:, :2] - res.axes[:, :2]).max() <= TOL_REREAD_MM
    assert np.abs(back.axes[:, 2] - res.axes[:, 2]).max() <= TOL_REREAD_DEG + 1e-12
    landed = forward(grinder, back.axes) + 1e-3 * field.predict(back.axes)
    assert np.abs(landed - targets).max() < TOL_LANDING_MM


def _reread(text, path, grinder, opts):
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / path.name
        p.write_bytes(text.encode("latin-1"))
        return read_as_compensate(p, grinder, **opts)


def test_cli_batch_over_the_corpus(tmp_path, grinder, capsys):
    el = make_chain_truth(grinder, 7).elements.save(tmp_path / "el.json")
    plain = [str(p) for p in PROGRAMS if p.name.startswith("c") and "expect: compensate)" in p.read_text("latin-1")]
    assert len(plain) >= 10
    out = tmp_path / "out"
    assert main(["compensate", *plain, "--model", str(el), "--method", "exact", "--out", str(out),
                 "--work-offsets", MACHINE]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted([Path(p).name for p in plain] + ["compensate_summary.json"])
    # one refused program in the batch: exit 2 naming it, nothing written
    out2 = tmp_path / "out2"
    bad = str(CORPUS / "r01_macro_call.nc")
    assert main(["compensate", *plain, bad, "--model", str(el), "--method", "exact", "--out", str(out2),
                 "--work-offsets", MACHINE]) == 2
    assert "r01_macro_call.nc: line 3, column 5: G65 P9000" in capsys.readouterr().err
    assert not out2.exists()


# ------------------------------------------------------------------------- random programs

PASS_LINES = ["(note X12 Z3 A4)", "M8", "M9", "F150", "S12000 M3", "; comment", "", "N100 M1", "T2 M6"]


@st.composite
def programs(draw):
    lines = ["G21 G90 G18 G1 X60 Z5 A0 F100"]
    inch = incremental = False
    for _ in range(draw(st.integers(1, 25))):
        kind = draw(st.sampled_from(["pass", "units", "distance", "g1", "g1", "g1", "g0", "arc"]))
        if kind == "pass":
            lines.append(draw(st.sampled_from(PASS_LINES)))
        elif kind == "units":
            inch = draw(st.booleans())
            lines.append("G20" if inch else "G21")
        elif kind == "distance":
            incremental = draw(st.booleans())
            lines.append("G91" if incremental else "G90")
        else:
            s = 1 / 25.4 if inch else 1.0
            axes = draw(st.lists(st.sampled_from(AXES), min_size=1, max_size=3, unique=True))
            words = []
            for a in axes:
                if a == "A":
                    v = draw(st.floats(-30, 30)) if incremental else draw(st.floats(0, 720))
                elif incremental:
                    v = draw(st.floats(-0.5, 0.5)) * s
                else:
                    v = (draw(st.floats(55, 65)) if a == "X" else draw(st.floats(4, 6))) * s
                words.append(f"{a}{v:.4f}")
            if kind == "arc":  # a half circle in XZ back and forth is always well defined with R
                if incremental:
                    words = ["X0.01", "R0.005"] if inch else ["X0.2", "R0.1"]
                else:
                    continue
            code = {"g1": "G1", "g0": "G0", "arc": draw(st.sampled_from(["G2", "G3"]))}[kind]
            lines.append(f"{code} " + " ".join(words) + draw(st.sampled_from(["", " (c)", " ; c"])))
            if kind == "arc":
                lines.append("G1")
    ending = draw(st.sampled_from(["\n", "\r\n"]))
    return ending.join(lines) + ending


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=programs(), seed=st.integers(0, 2**32 - 1), rapids=st.sampled_from(["keep", "compensate"]))
def test_random_programs_keep_every_other_line_and_read_back(tmp_path, grinder, text, seed, rapids):
    p = tmp_path / "rand.nc"
    p.write_bytes(text.encode("latin-1"))
    # units as written: a random program's A may span a few degrees (the unit check would ask if it is radians)
    tp = read_as_compensate(p, grinder, rapids=rapids, max_segment_mm=0.3, work_offsets=read_work_offsets(MACHINE),
                            units="as-written")
    rng = np.random.default_rng(seed)
    comp = tp.axes + rng.uniform(-2e-4, 2e-4, tp.axes.shape) * np.array([1.0, 1.0, 10.0])
    out, groups = render_gcode(tp, comp)
    compensated = {m.index for m in tp.source.program.moves if m.compensate}
    for i, line in enumerate(tp.source.program.lines):
        if i not in compensated:
            assert groups[i] == [line]
    q = tmp_path / "back.nc"
    q.write_bytes(out.encode("latin-1"))
    back = read_as_compensate(q, grinder, rapids=rapids, work_offsets=read_work_offsets(MACHINE), units="as-written")
    assert back.axes.shape == comp.shape
    assert np.abs(back.axes[:, :2] - comp[:, :2]).max() <= TOL_REREAD_MM
    assert np.abs(back.axes[:, 2] - comp[:, 2]).max() <= TOL_REREAD_DEG + 1e-12
