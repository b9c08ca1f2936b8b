"""The block-wise G-code reader and writer (issue 20) against the exact per-line reader: the
same classes, moves and refusals (file, line, column, word), the same vertices, and the same
output bytes, on the corpus (tests/data/gcode_corpus) and on generated programs that use every
allowed construct (bulk move lines mixed with everything the per-line classifier handles).

On the corpus the bulk step is forced on every run of plain lines (``BULK_MIN_RUN = 1``), so
the small files go through it too."""
from pathlib import Path

import numpy as np
import pytest

import compensation.gcode as g
from compensation.chain_gcode import plan_chain_gcode, render_chain_axes
from compensation.solvers.chain_exact import nominal_and_jacobian
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.chain_truth import make_chain_truth

CORPUS = sorted((Path(__file__).parent / "data" / "gcode_corpus").glob("*.nc"))
OPTIONS = [{}, {"rapids": "compensate"}, {"block_delete": "on"}, {"block_delete": "off"}]
N_PROGRAMS = 12       # generated programs (seeds 0..11), each read with every option set
LINES_PER_PROGRAM = 600


@pytest.fixture(scope="module")
def field(grinder):
    return ChainField(grinder, make_chain_truth(grinder, 3).elements)


@pytest.fixture(autouse=True)
def bulk_everywhere(monkeypatch):
    monkeypatch.setattr(g, "BULK_MIN_RUN", 1)


def _move_record(m):
    words = {k: (w.letter, w.value, w.text, w.start, w.num_start, w.num_end) for k, w in m.words.items()}
    mw = None if m.motion_word is None else (m.motion_word.value, m.motion_word.text, m.motion_word.start,
                                             m.motion_word.num_start, m.motion_word.num_end)
    return (m.index, m.kind, m.start.tobytes(), m.end.tobytes(), m.units, m.incremental, m.compensate,
            m.known.tolist(), words, mw, m.arc)


def _read(path, fast, **kw):
    try:
        prog = g.parse_program(path, fast=fast, **kw)
    except InputError as exc:
        return ("refused", str(exc)), None
    return ("read", prog.classes, [_move_record(m) for m in prog.moves]), prog


def _job_outputs(prog, machine, field, max_segment):
    job = plan_chain_gcode(prog, 0.5, field if max_segment == "auto" else None, max_segment_mm=max_segment,
                           nominal=lambda a: nominal_and_jacobian(machine, a)[0])
    # stand-in compensated vertices: every number changes, some by less than the last decimal
    axes = job.axes + 1e-3 * np.sin(np.arange(job.axes.size, dtype=float)).reshape(-1, 3)
    header = ["compensated by volcomp (test)"]
    text = render_chain_axes(prog, axes, job.counts, header=header)
    groups = g.render_program(prog, np.split(axes, np.cumsum(job.counts)[:-1]), header=header)[1]
    return (job.axes.tobytes(), job.lines.tolist(), job.kept_axes.tobytes(), job.kept_lines.tolist(),
            job.counts.tolist(), text.encode("latin-1"), [list(x) for x in groups])


def _same(path, machine, field, options=OPTIONS, segments=(None, 0.5, "auto")):
    refused = 0
    for kw in options:
        fast, prog_f = _read(path, True, **kw)
        exact, prog_e = _read(path, False, **kw)
        assert fast == exact, f"{path.name} {kw}: block-wise and per-line readers differ"
        if prog_f is None:
            refused += 1
            continue
        assert prog_f.table is not None and prog_e.table is None
        assert list(prog_f.lines) == prog_e.lines and len(prog_f.lines) == len(prog_e.lines)
        for seg in segments:
            assert _job_outputs(prog_f, machine, field, seg) == _job_outputs(prog_e, machine, field, seg), \
                f"{path.name} {kw} max_segment={seg}: outputs differ"
    return refused


def test_corpus_reads_and_writes_the_same(grinder, field):
    assert len(CORPUS) >= 30
    refused = sum(_same(p, grinder, field, segments=(None, "auto")) for p in CORPUS)
    assert refused >= 35  # the corpus' refused programs are refused by both, with the same message


# ------------------------------------------------------------------ generated programs

def _num(v, dec, rng):
    s = f"{v:.{dec}f}"
    if rng.random() < 0.2:
        s = s.rstrip("0")  # '12.' and '12.5' forms
    return s


def _program(seed: int, n: int, incremental: bool) -> str:
    """A program with every allowed construct; valid (the per-line reader accepts it)."""
    rng = np.random.default_rng(seed)
    pos = np.array([100.0, 20.0, 0.0])
    out = ["%", f"O{1000 + seed} (GENERATED {seed})", "(block-wise test program)", "G21 G90 G18 G94 G40 G49 G54 G64 P0.01",
           f"G0 X{pos[0]:.3f} Z{pos[1] + 5:.3f} A0.", "M3 S12000", "G1 F250."]
    inch = False
    inc = False
    ln = 10
    while len(out) < n:
        r = rng.random()
        ln += 10
        nw = f"N{ln} " if rng.random() < 0.5 else ""
        if r < 0.70:  # plain move lines (the bulk case), some with words missing
            step = rng.normal(0.0, [0.05, 0.02, 2.0])
            pos = np.clip(pos + step, [10.0, 1.0, -720.0], [190.0, 55.0, 720.0])
            scale = 25.4 if inch else 1.0
            have = rng.random(3) < 0.85
            if not have.any():
                have[rng.integers(3)] = True
            parts = []
            for j, a in enumerate("XZA"):
                if have[j]:
                    dec = 4 if (inch and j < 2) else 3
                    parts.append(a + _num(pos[j] / (1.0 if j == 2 else scale), dec, rng))
            gw = rng.choice(["", "", "G1 ", "G01 ", "G0 ", "G00 "])
            sep = rng.choice([" ", "", "  ", "\t"])
            line = nw + gw + sep.join(parts)
            if rng.random() < 0.1:
                line += f" F{rng.integers(50, 400)}."
            if rng.random() < 0.05:
                line += " (cut)"
            if rng.random() < 0.03:
                line += " ; note"
            if gw.startswith("G0"):
                out.append(line)
                out.append(nw + "G1 F250.")  # back to feed moves
            else:
                out.append(line)
        elif r < 0.74:
            out.append(rng.choice(["(comment only)", "", "   ", "; semicolon comment", "(a (nested comment)"]))
        elif r < 0.77:
            out.append(nw + rng.choice(["M8", "M9", "F300.", "S8000 M3", "T2 M6", "G4 P0.5", "G61", "G64"]))
        elif r < 0.80:  # an arc in G18, R form, short chord, then back to G1
            d = rng.normal(0.0, 0.2, 2)
            end = pos.copy()
            end[0] = np.clip(pos[0] + d[0], 10.0, 190.0)
            end[1] = np.clip(pos[1] + d[1], 1.0, 55.0)
            scale = 25.4 if inch else 1.0
            code = rng.choice(["G2", "G3"])
            out.append(f"{nw}{code} X{end[0] / scale:.5f} Z{end[1] / scale:.5f} R{2.0 / scale:.5f}")
            out.append("G1")
            pos = end
        elif r < 0.82:  # inch and back (numbers follow the unit)
            inch = not inch
            out.append(nw + ("G20" if inch else "G21"))
        elif r < 0.84:
            out.append(f"/{nw}M9" if rng.random() < 0.5 else f"/{nw}(skippable)")
        elif r < 0.85:
            out.append(f"{nw}x{pos[0] / (25.4 if inch else 1.0):.3f} z{pos[1] / (25.4 if inch else 1.0):.3f}")
        elif r < 0.86 and incremental and not inc:
            inc = True
            out.append(nw + "G91")
            for _ in range(int(rng.integers(2, 6))):
                step = rng.normal(0.0, [0.03, 0.01, 1.0])
                pos = np.clip(pos + step, [10.0, 1.0, -720.0], [190.0, 55.0, 720.0])
                scale = 25.4 if inch else 1.0
                out.append(f"X{step[0] / scale:.5f} Z{step[1] / scale:.5f} A{step[2]:.4f}")
            out.append("G90")
            inc = False
            out.append(f"X{pos[0] / (25.4 if inch else 1.0):.5f} Z{pos[1] / (25.4 if inch else 1.0):.5f} A{pos[2]:.4f}")
    if inch:
        out.append("G21")
    out += ["G0 Z58.", "M5", "M30", "%"]
    ending = "\r\n" if seed % 3 == 1 else "\n"
    text = ending.join(out)
    return text if seed % 4 == 3 else text + ending  # some without a final line ending


@pytest.mark.parametrize("seed", range(N_PROGRAMS))
def test_generated_programs_read_and_write_the_same(tmp_path, grinder, field, seed):
    path = tmp_path / f"gen{seed}.nc"
    path.write_bytes(_program(seed, LINES_PER_PROGRAM, incremental=seed % 2 == 1).encode("latin-1"))
    assert _same(path, grinder, field, options=[{}, {"rapids": "compensate"}]) == 0
    prog = g.parse_program(path)
    assert (prog.table.obj < 0).mean() > 0.5  # most moves were read in bulk


REFUSED_LINES = ["G1 Y1.", "X1e2", "G65 P9000 A1 X2", "G1 U1.", "X#1", "G2 X1 Z1", "G17 G2 X1 Z1 R5",
                 "/G1 X100.", "G54.1", "G43 Z1", "G1 X100. X101.", "M98 P100", "G4 X1", "G28 G1 X0"]


@pytest.mark.parametrize("bad", REFUSED_LINES)
def test_refusals_are_the_same(tmp_path, grinder, field, bad):
    """A refused line in the middle of a run of plain lines: the same message (line, column, word)."""
    lines = _program(5, 200, incremental=False).split("\n")
    lines.insert(120, bad)
    path = tmp_path / "bad.nc"
    path.write_text("\n".join(lines), encoding="latin-1")
    fast, _ = _read(path, True)
    exact, _ = _read(path, False)
    assert fast == exact and fast[0] == "refused" and "line 121," in fast[1]


@pytest.mark.parametrize("start", ["", "G80\n", "G0 X1 Z1 A1\nG3 X1.5 Z1.5 R2\n"])
def test_state_before_a_bulk_run(tmp_path, grinder, field, start):
    """Plain lines with no motion mode yet, after G80, or in an arc mode: refused as the
    per-line reader refuses them (the bulk step hands such a line to it)."""
    path = tmp_path / "mode.nc"
    path.write_text("G21 G90 G18\n" + start + "".join(f"X{10 + k * 0.01:.3f} Z5. A{k:.1f}\n" for k in range(50)),
                    encoding="latin-1")
    fast, _ = _read(path, True)
    exact, _ = _read(path, False)
    assert fast == exact and fast[0] == "refused"


def test_unknown_axes_and_kept_rapids(tmp_path, grinder, field):
    """A kept rapid may leave axes unknown; the first compensated move that needs them is refused."""
    body = "G21 G90 G18\nG0 X10.\n" + "".join(f"G0 X{10 + k * 0.01:.3f}\n" for k in range(40)) + "G1 Z5.\n"
    path = tmp_path / "unknown.nc"
    path.write_text(body, encoding="latin-1")
    fast, _ = _read(path, True)
    exact, _ = _read(path, False)
    assert fast == exact and fast[0] == "refused" and "line 43," in fast[1]
    assert _read(path, True, rapids="compensate")[0] == _read(path, False, rapids="compensate")[0]


def test_reference_return_keeps_the_previous_end(tmp_path, grinder, field):
    """G28 after a move used to overwrite that move's end with NaN (a shared array): with
    --rapids compensate the compensated G0 before it then had no end. Both readers now keep it."""
    path = tmp_path / "g28.nc"
    path.write_text("%\nG21 G90 G18\nG0 X60. Z5. A0.\nG1 Z1. F300.\nG0 Z5.\nG28 G91 Z0.\nG90\nG1 X61 Z2 A1\nM30\n%\n",
                    encoding="latin-1")
    for fast in (True, False):
        prog = g.parse_program(path, rapids="compensate", fast=fast)
        assert np.array_equal(prog.moves[2].end, [60.0, 5.0, 0.0])
        assert np.isnan(prog.moves[3].start[1])  # after G28 Z is unknown
    assert _same(path, grinder, field, options=[{"rapids": "compensate"}]) == 0


# ------------------------------------------------------------------ the compiled kernels

N_FUZZ_LINES = 20_000  # random lines from plain-looking fragments (seed 0): the kernel vs the patterns
_FRAGMENTS = ["N10", "N", "G1", "G01", "G0", "G00", "G1.", "G10", "G001", "g1", "X", "X1", "X-1.5", "X+.5", "X.",
              "X-.", "X1.", "X 1", "X1 0", "Z2.25", "Z-0", "Z", "A3", "A-720.125", "A1e2", "F200.", "F", "F.5",
              "(c)", "(", ")", "(a)(b)", ";x", "; (y)", " ", "\t", "", "M3", "Y1", "X12345678901234567890",
              "X9007199254740993", "X0.00000000000000000000001", "Z1.23456789012345678", "\r", "#1", "\xe9",
              "N" + "1" * 301, "X" + "9" * 17]


def _fuzz_lines(n, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        k = int(rng.integers(1, 7))
        parts = rng.choice(_FRAGMENTS, k)
        sep = rng.choice(["", " ", "  ", "\t"], k)
        out.append("".join(s + p for s, p in zip(sep, parts)) + rng.choice(["", "", "\r", "\r\r"]))
    return out


@pytest.mark.parametrize("words", [("X", "Z", "A"), ("Z", "A", "Y")], ids="".join)
def test_scan_kernel_reads_lines_as_the_patterns_do(words):
    """Every line's kind, spans and values from the compiled kernel are the patterns' (the
    kernel may leave a line to them, KIND_ASK; it never decides otherwise), for the default
    machine's words and for another three letters in another order (the letters are arguments)."""
    from compensation import gcode_kernels as gs
    lines = _fuzz_lines(N_FUZZ_LINES)
    data = "\n".join(lines).encode("latin-1")
    buf = np.frombuffer(data, np.uint8)
    starts, ends = gs.line_bounds(buf)
    assert starts.size == len(lines)
    kind, spans, vals = gs.scan_lines(buf, starts, ends, words)
    pattern = g._bulk_move(words)
    seen = set()
    for i, line in enumerate(lines):
        body = line.rstrip("\r\n")
        m = pattern.fullmatch(body)
        is_move = m is not None and m.lastindex is not None and m.lastindex >= 2
        want = gs.KIND_MOVE if is_move else (gs.KIND_PASS if g._BULK_PASS.fullmatch(body) else gs.KIND_OTHER)
        seen.add(int(kind[i]))
        if kind[i] == gs.KIND_ASK:
            continue
        assert kind[i] == want, repr(line)
        if is_move:
            assert spans[i].tolist() == [list(r) for r in m.regs[1:5]], repr(line)
            for j in range(3):
                if m.start(j + 2) >= 0:
                    assert vals[i, j] == float(m.group(j + 2)) and \
                        np.signbit(vals[i, j]) == np.signbit(float(m.group(j + 2))), repr(line)
                else:
                    assert np.isnan(vals[i, j])
    assert seen == {gs.KIND_MOVE, gs.KIND_PASS, gs.KIND_OTHER, gs.KIND_ASK}


N_FORMAT_VALUES = 200_000  # random values plus ties and near-ties at every decimal count used


@pytest.mark.parametrize("decimals", sorted(set(g.DECIMALS.values())))
def test_format_fixed_writes_what_fmt_writes(decimals):
    from compensation import gcode_kernels as gs
    rng = np.random.default_rng(decimals)
    v = np.concatenate([rng.uniform(-3000, 3000, N_FORMAT_VALUES // 2),
                        rng.normal(0, 1e-6, N_FORMAT_VALUES // 4),
                        (rng.integers(-10**9, 10**9, N_FORMAT_VALUES // 8) + 0.5) / 10.0 ** decimals,
                        np.nextafter((rng.integers(-10**9, 10**9, N_FORMAT_VALUES // 8) + 0.5) / 10.0 ** decimals, 0),
                        [0.0, -0.0, 1e-300, -1e-300, 5e-7, -5e-7, 9.99e8, -9.99e8, 123.4565, 0.0000005]])
    mags, negs = gs.format_fixed(v, decimals)
    got = [g._fixed_str(int(m), bool(s), decimals) for m, s in zip(mags.tolist(), negs.tolist())]
    assert got == [g.fmt(x, decimals) for x in v.tolist()]
    with pytest.raises(ValueError, match="Expected finite values below"):
        gs.format_fixed(np.array([1.0, 2.0 ** 60]), decimals)
