"""The independent check of a compensated program (tests of work offsets, tool lengths and dialects):
every non-motion line byte-identical, every programmed point reproduced by the TRUE machine. The frames
(offset, tool length) come from the test programs' own words, read here by patterns, not by the reader
under test."""
from __future__ import annotations

import re

import numpy as np

from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import machine_with_tool
from errormap.chain_field import ChainField

TOL_POINT_UM = 1.0
"""Every programmed point reproduced by the TRUE machine within 1 μm (the issue's bound): with the truth
as the model the exact solver leaves ≤ 1e-6 μm and the written numbers round to 1 nm."""


def _frame(lines, offsets: dict, tools: dict, power_on: str | None = None):
    """Per source line, independently of the reader: (offset (3,), tool length or None) from the words the
    test programs use (G10 L2 / L1, G54.., G43 H, G49), in order. ``power_on``: the work system in force
    before the program names one (``"G54"``, every controller's power-on default; None: none, NaN), and the
    words read in any case (LinuxCNC programs are often written in lower case)."""
    off, tool, out, loaded = np.full(3, np.nan), None, [], None
    table, tooltab = {k: np.asarray(v, float) for k, v in offsets.items()}, dict(tools)
    if power_on is not None:
        off = table[power_on]
    for ln in lines:
        ln = re.sub(r"\(.*?\)", "", ln)  # comments name codes too
        ln = ln.upper() if power_on is not None else ln
        m = re.search(r"G10 L2 P(\d) X([-\d.]+) Y([-\d.]+) Z([-\d.]+)", ln)
        if m:
            table[("G54", "G55", "G56")[int(m.group(1)) - 1]] = np.array([float(m.group(k)) for k in (2, 3, 4)])
        m = re.search(r"G10 L1 P(\d) Z([-\d.]+)", ln)
        if m:
            tooltab[int(m.group(1))] = float(m.group(2))
        m = re.search(r"(G154 P\d+|G1[12]\d|G54\.1 P\d|G59\.[123]|G5[4-9])(?![.\d])", ln)
        if m and "G10" not in ln:
            off = table[m.group(1).replace(" ", "")]
        m = re.search(r"T0*(\d+) M0?6\b", ln)  # LinuxCNC: a bare G43 uses the tool loaded by M6
        if m:
            loaded = int(m.group(1))
        m = re.search(r"G43\b[^H]*H0*(\d+)", ln)
        if m:
            tool = tooltab[int(m.group(1))]
        elif re.search(r"G43(?![.\d])", ln):
            tool = tooltab[loaded]
        if "G49" in ln:
            tool = None
        out.append((off, tool))
    return out


def _groups(src, dst):
    """Output lines of each source line: a compensated line and its added lines (they start with X)."""
    j, out = 0, []
    for i, s in enumerate(src):
        k = j + 1
        while k < len(dst) and dst[k].startswith("X") and not (i + 1 < len(src) and dst[k] == src[i + 1]):
            k += 1
        out.append(list(range(j, k)))
        j = k
    assert j == len(dst)
    return out


def true_point_errors_um(prog, out_file, mill, truth_els, offsets, tools, dialect=None, power_on=None, rapids="keep"):
    """|TRUE tool point − programmed point| (μm) at every programmed end point of the program's compensated
    moves, running ``out_file`` as the shop would: machine axes = written + offset (+ tool length on Z), the
    truth machine with its tool at that length. Also checks every non-motion line byte-identical.
    ``power_on``: :func:`_frame`'s (the corpus count, benchmarks/suite/gcode_corpus.py ``--check``); ``rapids``:
    what the program was compensated with (``--rapids``)."""
    aw = AxisWords.of(mill)
    p_src = parse_program(prog, axis_words=aw, fast=False, dialect=dialect, rapids=rapids)
    p_out = parse_program(out_file, axis_words=aw, fast=False, dialect=dialect, rapids=rapids)
    src, dst = p_src.lines, p_out.lines
    moves_src = {m.index: m for m in p_src.moves if m.compensate}
    moves_out = {m.index: m for m in p_out.moves}
    frame = _frame(src, offsets, tools, power_on)
    errs = []
    for i, g in enumerate(_groups(src, dst)):
        if i not in moves_src:
            assert [dst[k] for k in g] == [src[i]]  # byte-identical
            continue
        off, L = frame[i]
        shift = off + [0.0, 0.0, L if L is not None else 0.0]
        mt = machine_with_tool(mill, L) if L is not None else mill
        truth = ChainField(mt, truth_els)
        q = moves_out[g[-1]].end + shift
        tip = mt.nominal(q[None])[0] + truth.predict(q[None])[0] * 1e-3
        target = mt.nominal((moves_src[i].end + shift)[None])[0]
        errs.append(np.linalg.norm(tip - target) * 1e3)
    return np.array(errs)


