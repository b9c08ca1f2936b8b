"""Independent checks of compensated programs: the written program run as the shop would, judged without the reader's
frames (the corpus count's ``--check``, benchmarks/suite/gcode_corpus.py, and the tests that compensate a program).

:func:`independent_check` judges a ``mill-xyz`` program (frames per line read by pattern, tests/program_checks.py
``_frame``), :func:`cycle_check` one with kept canned cycles (every hole's programmed bottom), :func:`lathe_check` a
``lathe-xzc`` program in turning mode (:func:`lathe_points_reached`: the TRUE tip averaged over one turn of the
spindle against the programmed surface of revolution; on the spindle axis, against the least radius any X reaches).
Each returns ``"ok: ..."``, ``"WRONG: ..."`` (silently wrong) or ``"not checkable: ..."``. Their default tables are
the count's (:data:`PART_ZERO_MM`, :data:`TOOL_LENGTH_MM`); the product is imported when a check runs (the count
checks the checkout it put first on ``sys.path``).
"""
from __future__ import annotations

import re
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parents[2] / "tests"
"""The checkout's tests folder, whose ``program_checks`` (frames by pattern, the point tolerance) the checks use."""
TOOL_LENGTH_MM = 100.0
"""Every tool's length in the count's tool table (tools 1-99)."""
PART_ZERO_MM = {"mill-xyz": (300.0, 200.0, -300.0), "lathe-xzc": (0.0, 0.0, 200.0), "five-axis-ac": (0.0, 0.0, 40.0),
                "mill-xyza": (300.0, 200.0, -425.0), "hmc-xyzb": (0.0, 150.0, -650.0),
                "five-axis-bc": (0.0, 0.0, -460.0)}
"""Where the tables put every work system: a part zero inside the machine's strokes (mill: the middle of X
and Y, 100 mm above the bottom of Z's stroke; lathe: the spindle axis, the part's face 200 mm along the bed, so
that turning towards the chuck (Z < 0) stays inside Z's stroke; five-axis: on the C axis, 40 mm above the C
table top). The rotary machines' zero is where 4/5-axis posts put it: mill-xyza on the A axis line (Y and Z
zero on it, as a 4th-axis program's radii and wrapped Y need), mid-X; hmc-xyzb on the B axis (X), 150 mm above
the pallet top (Y) and 200 mm from the B axis toward the spindle (Z: a face of a part on the pallet), so that
both the program's Z 0…+650 retracts and a G43 tool of :data:`TOOL_LENGTH_MM` stay in Z's stroke; five-axis-bc
on the C axis, 50 mm above the C table top (a part's top), the tip there at B = C = 0. These are joint-mode zeros
(machine axes = program + offset); under TCP the offset is the part zero in the workpiece frame, as five-axis-ac's
is (its corpus programs are TCP demos): a TCP program on the rotary machines would need (0, 0, 50) and the like."""


def _lines(path: Path) -> list:
    """The file's lines as a controller cuts them: its bytes as Latin-1, each line with its own ending kept (``\\n``
    ends a line: a CRLF file stays CRLF, so a check compares the bytes a controller reads; in a file with no
    ``\\n`` at all, old Mac style, ``\\r`` does)."""
    text = path.read_bytes().decode("latin-1")
    end = "\n" if "\n" in text or "\r" not in text else "\r"
    return re.findall(rf"[^{end}]*{end}|[^{end}]+$", text)


class _Verdict(Exception):
    """A verdict reached before the end of :func:`independent_check` (``not checkable: ...`` or ``WRONG: ...``)."""


def independent_check(src: Path, written: Path, dialect: str, truth_file: Path, offsets: dict | None = None,
                      tools: dict | None = None) -> str:
    """``--check``: the written program run as the shop would, judged independently of the reader's frames:
    frames (work offset, tool length) per line from the program's own G54-G59 / G54.1 P / G154 P / G43 H /
    G49 words read by patterns (tests/program_checks.py ``_frame``; the controller's power-on G54 before any),
    the same for the written program. Passes when (1) the lines that are not compensated moves are the
    source's, byte for byte and in order, with the same line ends, (2) every move the reader leaves uncompensated
    is one it may leave so (a rapid, or a move of Z alone before X and Y were given: the position the controller
    starts it from is not the program's; any other is counted wrong), and (3) every programmed end point of a
    compensated move is reached, in order, by the TRUE machine at the end of some written move within 1 um.
    ``"ok: max E um at N points"``, ``"WRONG: ..."`` (silently wrong) or ``"not checkable: ..."``. A program the
    reader expanded (subprograms, macros: a flat program is written) is judged against the reader's flat program.
    ``offsets`` {system: (3,) mm} and ``tools`` {number: length mm}: the tables the program was compensated with
    (default: the count's, every system at :data:`PART_ZERO_MM`, every tool 100 mm). A program with canned cycles is
    judged by :func:`cycle_check`."""
    text = src.read_bytes().decode("latin-1")  # not read_text: universal newlines would make CR an LF
    lf_ends = "\n" in text  # none: CR-only line ends, which the written program must keep
    if re.search(CYCLE_RE, text):
        return cycle_check(src, written, dialect, truth_file, offsets, tools)
    if NURBS_RE.search(text):  # its control-point lines are written as comments, the curve as compensated chords
        return "not checkable: NURBS blocks (G5.2/G5.3) written as chords (tests/test_gcode_nurbs.py checks them)"
    from errormap.machine import load_machine
    mill = load_machine("mill-xyz")
    if offsets is None:
        offsets, tools = _count_tables()
    try:
        (p_src, f_src, src_lines), (p_out, f_out, out_lines) = _read_pair(src, written, dialect, mill, offsets, tools)
        m_src = [m for m in p_src.moves if m.compensate]
        m_out = [m for m in p_out.moves if m.compensate]
        _kept_as_written(p_src, (m_src, m_out), (src_lines, out_lines), lf_ends, written)
    except _Verdict as verdict:
        return str(verdict)
    return _points_reached(mill, truth_file, p_src, (m_src, m_out), (f_src, f_out), _held_by_g53(src_lines))


def _read_pair(src: Path, written: Path, dialect: str, mill, offsets: dict, tools: dict) -> tuple:
    """``((parsed, frames, lines) of the source, the same of the written program)`` as :func:`independent_check` reads
    them: the source with its ``G53`` moves placed in the program's frame (:func:`_g53_placed`), or the reader's flat
    program where it expands one; the written program without the writer's header (``.bare`` beside it); ``lines``
    the lines a controller reads. Raises :class:`_Verdict` (``not checkable``) where they cannot be read so."""
    sys.path.insert(0, str(TESTS))
    from program_checks import _frame
    from compensation.gcode import AxisWords, parse_program
    aw = AxisWords.of(mill)  # dialect "auto": detected from each file, as compensate does
    try:  # a program with canned cycles is read by compensate's cycle reader, not this plain parse
        placed = _g53_placed(src, written, offsets, tools)
        expanded = parse_program(placed or src, axis_words=aw, dialect=dialect).expanded
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        raise _Verdict(f"not checkable: {type(exc).__name__}: {exc}"[:110]) from exc
    if expanded is not None and placed is not None:
        raise _Verdict("not checkable: G53 moves in a program the reader expands")
    out = [ln for ln in _lines(written) if not ln.startswith("(volcomp:")]  # the writer's header (after a '%' too)
    bare = written.with_suffix(written.suffix + ".bare")
    bare.write_bytes("".join(out).encode("latin-1"))
    placed_out = _g53_placed(bare, bare, offsets, tools) if placed is not None else None
    if expanded is not None:
        src = written.with_suffix(written.suffix + ".flat")
        src.write_text(expanded.text, encoding="latin-1")
    try:
        p_src, p_out = (parse_program(f, axis_words=aw, fast=False, dialect=dialect)
                        for f in (placed or src, placed_out or bare))
        f_src, f_out = (_frame(p.lines, offsets, tools, "G54") for p in (p_src, p_out))
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        raise _Verdict(f"not checkable: {type(exc).__name__}: {exc}"[:110]) from exc
    src_lines = _lines(src) if placed is not None else p_src.lines  # the lines a controller reads
    if len(src_lines) != len(p_src.lines):
        raise _Verdict("not checkable: the G53 lines placed in the program's frame split into other lines")
    out_lines = _lines(bare) if placed_out is not None else p_out.lines
    return (p_src, f_src, src_lines), (p_out, f_out, out_lines)


def _kept_as_written(p_src, moves: tuple, lines: tuple, lf_ends: bool, written: Path) -> None:
    """(1) and (2) of :func:`independent_check`: ``moves`` (compensated moves of the source, of the written program)
    and their ``lines``; raises :class:`_Verdict` (``WRONG``) at a feed left uncompensated, changed line ends or a
    changed line that is not a compensated move."""
    (m_src, m_out), (src_lines, out_lines) = moves, lines
    feed = next((m for m in p_src.moves  # uncompensated by design: rapids, and Z alone before X and Y were given
                 if not m.compensate and m.kind != "rapid" and set(m.words) & set("XYZ") != {"Z"}), None)
    if feed is not None:
        raise _Verdict(f"WRONG: line {feed.index + 1} ({p_src.lines[feed.index].strip()[:40]!r}), a feed, left "
                       "uncompensated")
    if lf_ends != (b"\n" in written.read_bytes()):
        raise _Verdict("WRONG: the line ends changed (CR-only and LF)")
    keep_src = [ln for i, ln in enumerate(src_lines) if i not in {m.index for m in m_src}]
    keep_out = [ln for i, ln in enumerate(out_lines) if i not in {m.index for m in m_out}]
    if keep_src != keep_out:
        bad = next((s for s, o in zip(keep_src, keep_out) if s != o), "(line count)")
        raise _Verdict(f"WRONG: a line that is not a compensated move changed: {bad.strip()[:50]!r}")


def _points_reached(mill, truth_file: Path, p_src, moves: tuple, frames: tuple, held: list) -> str:
    """(3) of :func:`independent_check`: ``moves`` (compensated moves of the source, of the written program) in their
    ``frames`` (the same order) on the TRUE machine of ``truth_file``; ``held``: per source line, the axes a ``G53``
    holds (:func:`_held_by_g53`; their error stated, not judged)."""
    sys.path.insert(0, str(TESTS))
    from program_checks import TOL_POINT_UM
    from compensation.nc_state import machine_with_tool
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    (m_src, m_out), (f_src, f_out) = moves, frames
    truth_els, fields = ChainElementSet.load(truth_file, mill), {}

    def placed(m, frames):
        off, tool = frames[m.index]
        q = m.end + off + [0.0, 0.0, tool if tool is not None else 0.0]
        if tool not in fields:
            mt = machine_with_tool(mill, tool) if tool is not None else mill
            fields[tool] = (mt, ChainField(mt, truth_els))
        return q, fields[tool]

    errs, j, held_um = [], 0, []
    for m in m_src:
        q, (mt, _) = placed(m, f_src)
        target = mt.nominal(q[None])[0]
        free = np.array([a not in held[m.index] for a in "XYZ"])  # a held axis: its error is stated, not judged
        while j < len(m_out):
            qo, (mto, truth) = placed(m_out[j], f_out)
            j += 1
            e = (mto.nominal(qo[None])[0] + truth.predict(qo[None])[0] * 1e-3 - target) * 1e3
            if np.linalg.norm(e[free]) <= TOL_POINT_UM:
                errs.append(float(np.linalg.norm(e[free])))
                held_um += [float(np.abs(e[~free]).max())] if not free.all() else []
                break
        else:
            return f"WRONG: line {m.index + 1} ({p_src.lines[m.index].strip()[:40]!r}) reached by no written move"
    if not errs:
        return "not checkable: no compensated move"
    held_note = f"; held at a G53 value: max {max(held_um):.3g} um along it at {len(held_um)} points" if held_um else ""
    return f"ok: max {max(errs):.3g} um at {len(errs)} points{held_note}"


def _held_by_g53(lines: list) -> list:
    """Per line, the axes (of X Y Z) a ``G53`` line set and no line gave since, read by pattern: a move there holds
    them at the machine value (the compensated axes are judged, the held one's error stated)."""
    held, out = set(), []
    for ln in lines:
        body = re.sub(r"\([^)]*\)|;.*", "", ln).upper()
        given = set(re.findall(r"(?<![A-Z#])([XYZ])\s*[-+.\d]", body))
        held = held | given if G53_RE.search(body) else held - given
        out.append(frozenset(held))
    return out


G53_RE = re.compile(r"G0*53(?![.\d])", re.IGNORECASE)
NURBS_RE = re.compile(r"^[^(;]*G0*5\.2(?!\d)", re.IGNORECASE | re.MULTILINE)


def _g53_placed(src: Path, written: Path, offsets: dict, tools: dict) -> Path | None:
    """``src`` with its ``G53`` moves placed in the program's frame (:func:`_g53_in_frame`), written beside
    ``written``; None where it has none, or one that is not a ``G0`` (the source is then read as written)."""
    if not G53_RE.search(src.read_bytes().decode("latin-1")):
        return None
    sys.path.insert(0, str(TESTS))
    from program_checks import _frame
    lines = _lines(src)
    placed = _g53_in_frame(lines, _frame(lines, offsets, tools, "G54"))
    if placed is None or placed == lines:
        return None
    out = written.with_suffix(written.suffix + ".g53")
    out.write_bytes("".join(placed).encode("latin-1"))
    return out


def _g53_in_frame(lines: list, frames: list) -> list | None:
    """The source lines with each ``G53 G0`` move written in the program's frame, independently of the reader: its
    X Y Z words (in the line's units, ``G20``/``G21`` read by pattern) minus the line's work offset and tool length
    (``frames``, tests/program_checks.py ``_frame``), the G53 dropped, so that the moves after it start where the
    controller has them (the rewritten line is a rapid, kept as written: not a point the check asks for). None: a
    G53 move that is not a G0."""
    out, selected, inch = [], False, False
    for ln, (off, tool) in zip(lines, frames):
        code = re.sub(r"\(.*?\)|;.*", "", ln.rstrip("\r\n"))
        units = re.findall(r"G0*2([01])(?![.\d])", code, re.IGNORECASE)
        inch = units[-1] == "0" if units else inch
        if not G53_RE.search(code) or not re.search(r"[XYZ]", code, re.IGNORECASE):
            selected |= bool(re.search(r"(G154|G1[12]\d|G54\.1|G59\.[123]|G5[4-9])(?![.\d])", code.upper()))
            out.append(ln)
            continue
        if not re.search(r"G0*0(?![.\d])", G53_RE.sub("", code)):
            return None
        shift_mm = np.asarray(off, dtype=float) + [0.0, 0.0, tool if tool is not None else 0.0]
        unit_mm = 25.4 if inch else 1.0

        def in_frame(m):
            mm = float(m.group(2)) * unit_mm - shift_mm["XYZ".index(m.group(1).upper())]
            return f"{m.group(1)}{mm / unit_mm:.9f}"
        body = re.sub(r"([XYZ])\s*([-+]?[\d.]+)", in_frame, G53_RE.sub("", code), flags=re.IGNORECASE)
        body += "" if selected else " G54"  # placed in the power-on system (the frames' G54): selecting it is no change
        out.append(body + ln[len(ln.rstrip("\r\n")):])
    return out


def _count_tables() -> tuple:
    """The count's tables for the checks: every system at the mill's :data:`PART_ZERO_MM`, every tool 100 mm."""
    systems = ["G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"]
    systems += [f"G54.1P{n}" for n in range(1, 49)] + [f"G154P{n}" for n in range(1, 100)]
    systems += [f"G{n}" for n in range(110, 130)]
    return {s: PART_ZERO_MM["mill-xyz"] for s in systems}, {n: TOOL_LENGTH_MM for n in range(1, 100)}


CYCLE_RE = r"(?i)G0*(?:7[346]|8[1-9])(?![\d.])"
"""A drilling canned cycle's code (G73 G74 G76 G81-G89), found by pattern."""
_MOTION_RE = r"(?i)G0*(?:[0-3]|80)(?![\d.])"
_WORDS_RE = r"(?i)([XYZR])\s*([-+]?(?:\d+\.?\d*|\.\d+))"


def _cycle_lines(lines) -> list:
    """Indices of the lines that drill (a cycle code, or an X/Y/Z word while a cycle is the mode), by pattern."""
    out, on = [], False
    for i, ln in enumerate(lines):
        body = re.sub(r"\(.*?\)|;.*", "", ln)
        if re.search(CYCLE_RE, body):
            on = True
        elif re.search(_MOTION_RE, body):
            on = False
        if on and re.search(r"(?i)[XYZ]\s*[-+.\d]", body):
            out.append(i)
    return out


def cycle_check(src: Path, written: Path, dialect: str, truth_file: Path, offsets=None, tools=None) -> str:
    """``--check`` of a program with kept canned cycles, independently of the reader: the cycle lines (found by
    pattern) blanked in both programs, the rest judged by :func:`independent_check`; then every hole: the
    programmed bottom (X Y from the last absolute X Y, Z sticky, in the frame of its line read by
    tests/program_checks.py ``_frame``) reached within 1 um by the TRUE machine at the written line's X Y Z.
    Holes under G91 are not checkable."""
    a = _lines(src)
    b = [ln for ln in _lines(written) if not ln.startswith("(volcomp:")]
    ca, cb = _cycle_lines(a), _cycle_lines(b)
    if len(ca) != len(cb):
        return "not checkable: the written program's cycle lines are not the source's (G91 repeats)"
    blank = lambda lines, c: "".join("(cycle)\n" if i in c else ln for i, ln in enumerate(lines))  # noqa: E731
    scratch = Path(tempfile.mkdtemp(prefix="volcomp-cycle-check-"))  # never beside the programs
    pa, pb = scratch / ("src" + src.suffix), scratch / ("written" + written.suffix)
    pa.write_bytes(blank(a, set(ca)).encode("latin-1"))
    pb.write_bytes(blank(b, set(cb)).encode("latin-1"))
    try:
        rest = independent_check(pa, pb, dialect, truth_file, offsets, tools)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    if rest.startswith("WRONG"):
        return rest
    if offsets is None:
        offsets, tools = _count_tables()
    try:
        errs = _hole_errors_um(a, b, dict(zip(ca, cb)), truth_file, offsets, tools)
    except _Verdict as verdict:
        return str(verdict)
    return f"ok: max {max(errs):.3g} um at {len(errs)} holes; rest {rest}" if errs else "not checkable: no hole"


def _hole_errors_um(a: list, b: list, written_of: dict, truth_file: Path, offsets: dict, tools: dict) -> list:
    """Per hole of the source lines ``a`` (``written_of``: its cycle line's index -> the written line's in ``b``), in
    order, the TRUE error (um) at the written X Y Z against the programmed bottom, as :func:`cycle_check` says; raises
    :class:`_Verdict` at a hole off by more than 1 um (``WRONG``) or a cycle under G91 (``not checkable``)."""
    sys.path.insert(0, str(TESTS))
    from program_checks import TOL_POINT_UM, _frame
    from compensation.nc_state import machine_with_tool
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    mill = load_machine("mill-xyz")
    frames = _frame(a, offsets, tools, "G54")
    els, state, inc, errs = ChainElementSet.load(truth_file, mill), {}, False, []
    for i, ln in enumerate(a):
        body = re.sub(r"\(.*?\)|;.*", "", ln).upper()
        inc = "G91" in body if re.search(r"G9[01](?![\d.])", body) else inc
        words = {k: float(v) for k, v in re.findall(_WORDS_RE, body)}
        if i not in written_of:
            if not re.search(r"G(?:28|30|53)(?![\d.])", body):
                for k in "XY":
                    if k in words:
                        state[k] = state.get(k, np.nan) + words[k] if inc else words[k]
            continue
        if inc:
            raise _Verdict("not checkable: a canned cycle under G91")
        state.update(words)
        w = {k: float(v) for k, v in re.findall(_WORDS_RE, re.sub(r"\(.*?\)|;.*", "", b[written_of[i]]).upper())}
        off, tool = frames[i]
        mt = machine_with_tool(mill, tool) if tool is not None else mill
        shift = np.asarray(off, float) + [0.0, 0.0, tool or 0.0]
        inch = any(re.search(r"G20(?![\d.])", re.sub(r"\(.*?\)|;.*", "", t).upper()) for t in a[:i + 1])
        scale = 25.4 if inch else 1.0
        run = np.array([w["X"], w["Y"], w["Z"]]) * scale + shift
        tgt = np.array([state["X"], state["Y"], state["Z"]]) * scale + shift
        tip = mt.nominal(run[None])[0] + ChainField(mt, els).predict(run[None])[0] * 1e-3
        e_um = float(np.linalg.norm(tip - mt.nominal(tgt[None])[0]) * 1e3)
        if not e_um <= TOL_POINT_UM:
            raise _Verdict(f"WRONG: hole of line {i + 1} ({a[i].strip()[:40]!r}) off by {e_um:.3g} um")
        errs.append(e_um)
    return errs


def lathe_check(src: Path, written: Path, dialect: str, truth_file: Path) -> str:
    """``--check`` of a ``lathe-xzc`` program in turning mode, independently of the reader's frames: the part zero
    of the count's tables (:data:`PART_ZERO_MM`, every system), the lines that are not compensated moves the
    source's byte for byte, and every programmed end point (radius, Z) reached, in order, by some written move:
    the TRUE tool tip averaged over one turn of the spindle on the programmed surface of revolution within 1 um
    (``compensation.turning.surface_residual_um``), at the tool offset in force (``G43 H`` / ``G49`` read by pattern,
    tests/program_checks.py ``_frame``: the count's tool table, every tool :data:`TOOL_LENGTH_MM` along Z, no X
    offset). A point on the spindle axis: :func:`lathe_points_reached`. A program with C words is not checked here."""
    sys.path.insert(0, str(TESTS))
    from program_checks import TOL_POINT_UM, _frame
    from compensation.turning import parse_lathe_program
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    lathe, zero = load_machine("lathe-xzc"), PART_ZERO_MM["lathe-xzc"]
    out = [ln for ln in _lines(written) if not ln.startswith("(volcomp:")]
    bare = written.with_suffix(written.suffix + ".bare")
    bare.write_bytes("".join(out).encode("latin-1"))
    try:
        (p_src, _), (p_out, _) = (parse_lathe_program(f, lathe, "keep", None, dialect) for f in (src, bare))
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        return f"not checkable: {type(exc).__name__}: {exc}"[:110]
    if len(p_src.axis_words.words) != 2:
        return "not checkable: C words (C-axis mode)"
    m_src = [m for m in p_src.moves if m.compensate]
    m_out = [m for m in p_out.moves if m.compensate]
    keep_src = [ln for i, ln in enumerate(p_src.lines) if i not in {m.index for m in m_src}]
    keep_out = [ln for i, ln in enumerate(p_out.lines) if i not in {m.index for m in m_out}]
    if keep_src != keep_out:
        return "WRONG: a line that is not a compensated move changed"
    systems, tools = _count_tables()
    try:
        f_src, f_out = (_frame(p.lines, {s: zero for s in systems}, tools, "G54") for p in (p_src, p_out))
    except KeyError as exc:  # a tool or work system the count's tables do not hold
        return f"not checkable: {exc} not in the count's tables"
    z_of = lambda frames, moves: [frames[m.index][1] or 0.0 for m in moves]  # noqa: E731 - the tool's Z offset
    field, on_axis = ChainField(lathe, ChainElementSet.load(truth_file, lathe)), []
    errs, missed = lathe_points_reached(field, lathe, m_src, m_out, (zero[0], zero[2]), TOL_POINT_UM, on_axis,
                                        (z_of(f_src, m_src), z_of(f_out, m_out)))
    if missed is not None:
        return f"WRONG: line {missed} reached by no written move"
    axis = (f" ({len(on_axis)} on the spindle axis: off it by the least radius any X reaches, up to "
            f"{max(f for _, f in on_axis):.3g} um)") if on_axis else ""
    return f"ok: max {max(errs):.3g} um at {len(errs)} points{axis}" if errs else "not checkable: no compensated move"


AXIS_ZONE_MM = 1.0
"""A programmed radius beyond this is reachable by X (a tool's centre-height error is tens of um): only nearer the
spindle axis does :func:`lathe_points_reached` look for the least radius the tip can reach."""


def least_radial_um(field, lathe, q, target) -> float:
    """The least radial deviation (um) from the programmed radius of ``target`` (1, 3) that any X reaches, Z as at
    ``q`` (1, 3) (bounded Brent over X within :data:`AXIS_ZONE_MM`; the tip's mean radius over the turn is convex
    in X near the axis); 0 where X reaches the programmed radius."""
    from scipy.optimize import minimize_scalar
    from compensation.turning import surface_residual_um

    def radial(x_mm):
        qx = q.copy()
        qx[0, 0] = x_mm
        return float(surface_residual_um(field, lathe, qx, target)[0][0, 0])
    best = minimize_scalar(radial, bounds=(target[0, 0] - AXIS_ZONE_MM, target[0, 0] + AXIS_ZONE_MM),
                           method="bounded", options={"xatol": 1e-7})
    return max(0.0, float(best.fun))


def lathe_points_reached(field, lathe, m_src, m_out, zero_xz_mm, tol_um: float, on_axis: list | None = None,
                         tools_z_mm: tuple | None = None) -> tuple:
    """``(errors um, missed line)``: per programmed move of ``m_src``, in order, the TRUE error of the first later move
    of ``m_out`` that reaches it within ``tol_um`` — the tool tip driven to the written (radius, Z), averaged over one
    turn of the spindle, against the programmed surface of revolution (``compensation.turning.surface_residual_um``);
    the moves' ends are in the work frame, ``zero_xz_mm`` the part zero's (X, Z) in the machine. ``missed``: the
    1-based line of the first programmed point no written move reaches (its errors so far), else None.
    ``tools_z_mm``: ``(per move of m_src, per move of m_out)`` the tool offset along Z in force (mm; 0: none): the
    machine's Z is the program's plus it, the tool tip that far back (``compensation.turning.at_tool``); a written
    move reaches only a point programmed with the same offset.

    A programmed radius nearer the spindle axis than the TRUE tip passes it (a point on the axis, X0; the tool's
    centre-height error) is reached by no X and Z: there the error left whatever is written is the least radial
    deviation any X reaches at the written Z (:func:`least_radial_um`, found here by a search over X, not by the
    compensator's closest approach; the model residual there when the model is the truth). Such a point counts as
    reached when its error less that floor (its radial deviation less the floor, its axial deviation in full) is within
    ``tol_um``; that is its error, and ``(line, floor um)`` is appended to ``on_axis`` (a list, when given)."""
    from compensation.turning import at_tool, surface_residual_um
    tz_src, tz_out = tools_z_mm if tools_z_mm is not None else ([0.0] * len(m_src), [0.0] * len(m_out))
    at = {}
    place = lambda e, tz: np.array([[e[0] + zero_xz_mm[0], e[1] + zero_xz_mm[1] + tz, 0.0]])  # noqa: E731 - X, Z, C
    errs, j = [], 0
    for m, tz in zip(m_src, tz_src):
        if tz not in at:
            at[tz] = at_tool(field, lathe, 0.0, tz) if tz else (field, lathe)
        f, mt = at[tz]
        target = place(m.end, tz)
        while j < len(m_out):
            q = place(m_out[j].end, tz)
            r = surface_residual_um(f, mt, q, target)[0][0] if tz_out[j] == tz else np.full(2, np.inf)
            near = np.isfinite(r).all() and np.hypot(*r) > tol_um and abs(target[0, 0]) < AXIS_ZONE_MM
            floor = least_radial_um(f, mt, q, target) if near else 0.0
            e = float(np.hypot(r[0] - floor, r[1]))  # the axial error in full: only the radius has a floor
            j += 1
            if np.isfinite(e) and e <= tol_um:
                errs.append(e)
                if floor > 0.0 and on_axis is not None:
                    on_axis.append((m.index + 1, floor))
                break
        else:
            return errs, m.index + 1
    return errs, None
