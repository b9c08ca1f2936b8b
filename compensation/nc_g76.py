"""LinuxCNC's ``G76`` threading cycle on a lathe: read exactly, written with ``--expand-cycles`` as the passes its
interpreter makes (``G0`` moves and ``G33`` pieces, compensated as every G33 is: :mod:`compensation.nc_thread`).

Rules read (LinuxCNC G-code reference, "G76 Threading Cycle", and its interpreter, ``convert_threading_cycle`` /
``threading_pass`` in src/emc/rs274ngc/interp_convert.cc, ``check_other_codes`` in interp_check.cc):
``G76 P- Z- I- J- K- [R-] [Q-] [H-] [E-] [L-]`` from the tool's position S = (x0, z0), whose X is the drive line:

- P the pitch (distance per revolution), Z the thread's end (the tool ends the cycle at (x0, Z)); I the crest's offset
  from the drive line (negative: an outside thread), J the first pass's depth beyond the crest (> 0), K the full depth
  beyond the crest (> J); under ``G7`` I, J, K are diameters (halved), P, Z, E not;
- pass depths d(n) = |I| + J·n^(1/R) for n = 1, 2, … while d(n) < |I| + K, then H + 1 passes at |I| + K (H the spring
  passes, default 0); R the depth degression (default 1);
- Q the compound slide angle a (degrees, default 0; its sign flipped where Z > z0): each pass starts and ends shifted
  along Z by −(d − |I|)·tan a, and the thread's last point by + K·tan a, so the final pass ends at Z;
- a pass, s = −1 outside (I < 0), +1 inside: rapid to X = x0 + s·(d − |I| − K), Z = its start; rapid in to
  X = x0 + s·d (or, with an entry taper, L1 or L3: synchronised at P·√(E² + K²)/E in to x0 + s·(d − K), then along
  the taper to the cut depth over E); synchronised at P along Z to its end (with an exit taper, L2 or L3: to E before
  it, then along the taper out to x0 + s·(d − K)); rapid out to the first X;
- refused by LinuxCNC (and so here): X or Y on the line, a plane other than G18, cutter compensation on, P, J, K, H
  negative, R < 1, E more than half the thread's length.

Refused here besides (not read exactly): other words on the line (write them on their own line), ``$`` (another
spindle), ``G91`` (the passes are written absolute), ``Q-1`` (the interpreter takes it for no Q), |Q| ≥ 90°, L other
than 0-3, a start the program does not fix. The kept form (no ``--expand-cycles``) is refused naming the option
(:func:`compensation.nc_thread.refuse_kept`): the passes start from one point whose compensation cannot be each pass's,
and one P cannot give the true lead where the error is not linear along the thread."""
from __future__ import annotations

import math

import numpy as np

from .gcode_state import MM_PER_INCH, _Refuse
from .nc_contour import _word_text
from .nc_notes import note

LETTERS = frozenset("NGPZIJKRQHEL")
"""Words a G76 line may hold here (module docstring)."""
REQUIRED = "PZIJK"
MAX_PASSES = 10_000
"""A G76 of more passes than this is refused (its expansion would write hundreds of thousands of lines; LinuxCNC's
reference warns that a high degression R makes "a large number of passes"): the count (K/J)^R + H + 1 is checked
before the passes are made."""


def passes(x0_mm, z0_mm, z_mm, p_mm, i_mm, j_mm, k_mm, r=1.0, q_deg=0.0, h=0, e_mm=0.0, ends=0) -> list:
    """The passes of a G76 from (``x0_mm`` radius, ``z0_mm``) to ``z_mm`` (module docstring; I, J, K radii, mm), each
    its moves ``[(code, X radius mm, Z mm, lead mm or None)]``: ``"G0"`` rapids and ``"G33"`` synchronised moves
    (their lead P, or a taper's). ``ends``: L (1 entry taper, 2 exit, 3 both)."""
    s = 1.0 if i_mm > 0 else -1.0
    crest, full = abs(i_mm), abs(i_mm) + k_mm
    a = math.radians(q_deg) * (-1.0 if z_mm > z0_mm else 1.0)
    taper = e_mm * (-1.0 if z_mm > z0_mm else 1.0)
    taper_lead = p_mm * math.hypot(e_mm, k_mm) / e_mm if e_mm > 0 else p_mm
    z_last = z_mm + k_mm * math.tan(a)
    depths, n = [], 1
    while crest + j_mm * n ** (1.0 / r) < full:
        depths.append(crest + j_mm * n ** (1.0 / r))
        n += 1
    out = []
    for d in depths + [full] * (h + 1):
        shift = (d - crest) * math.tan(a)
        back, cut, top = x0_mm + s * (d - full), x0_mm + s * d, x0_mm + s * (d - k_mm)
        za, zb = z0_mm - shift, z_last - shift
        out.append([("G0", back, za, None)])
        if taper and ends & 1:
            out[-1] += [("G33", top, za, taper_lead), ("G33", cut, za - taper, taper_lead)]
        else:
            out[-1].append(("G0", cut, za, None))
        if taper and ends & 2:
            out[-1] += [("G33", cut, zb + taper, p_mm), ("G33", top, zb, taper_lead)]
        else:
            out[-1].append(("G33", cut, zb, p_mm))
        out[-1].append(("G0", back, zb, None))
    return out


def g76_line(words, idx: int, st, ax) -> str | None:
    """``"state"`` for a LinuxCNC ``G76`` line on a lathe (its passes recorded as the event ``"lathe-thread"``:
    ``(passes (:func:`passes`), P mm, P text, inch, diameter)``, code ``"G76"``; the tool at (x0, Z) after it, no
    motion mode in force: a following axis word needs its G0-G3), None for any other line. Refused: module
    docstring."""
    code = next((w for w in words if w.letter == "G" and w.code == "G76"), None)
    if code is None:
        return None
    by = _words(words, code)
    col = code.start + 1
    why = ("the plane is not G18 (ZX; LinuxCNC's error)" if st.plane != "G18" else
           f"cutter compensation {st.cutter} is on (LinuxCNC's error)" if st.cutter != "G40" else
           "under G91 (the passes are written absolute here): write it under G90" if st.incremental else None)
    if why is not None:
        raise _Refuse(col, f"'G76' (threading cycle) {why}")
    ix, iz = ax.words.index("X"), ax.words.index("Z")
    x0, z0 = float(st.pos[ix]), float(st.pos[iz])
    if not (np.isfinite(x0) and np.isfinite(z0)):
        raise _Refuse(col, "'G76' from an unknown position: give X (the drive line) and Z (the thread's start) "
                           "absolutely before it")
    unit = MM_PER_INCH if st.inch else 1.0
    across = unit * (0.5 if st.diameter else 1.0)  # I J K: diameters under G7
    p, z, e = (by[a].value * unit if a in by else 0.0 for a in "PZE")
    i, j, k = (by[a].value * across for a in "IJK")
    r = by["R"].value if "R" in by else 1.0
    q = by["Q"].value if "Q" in by else 0.0
    _check_values(by, z0, p, z, e, i, j, k)
    h, ends = (int(by[a].value) if a in by else 0 for a in "HL")
    if r * math.log(k / j) > math.log(MAX_PASSES) or h + 1 > MAX_PASSES:
        raise _Refuse(by["R" if "R" in by and h + 1 <= MAX_PASSES else "H" if "H" in by else "J"].start + 1,
                      f"a G76 of more than {MAX_PASSES} passes ((K/J)^R + H + 1): not written; fewer passes (a lower "
                      "R or H, a larger J)")
    cut = passes(x0, z0, z, p, i, j, k, r, q, h, e, ends)
    st.events.append((idx, col, "lathe-thread", (cut, p, by["P"].text, st.inch, bool(st.diameter)), "G76"))
    st.pos = np.array(st.pos, dtype=float)  # a new array: the moves read hold the old one as their end
    st.pos[iz] = z
    st.mode, st.last_move = None, None  # LinuxCNC: G76 stays the motion mode (a line of axis words alone reruns it)
    return "state"


def _words(words, code) -> dict:
    """The G76 line's words by letter; refused: a word not in :data:`LETTERS`, a repeated one, a required one
    missing."""
    by = {}
    for w in words:
        if w.letter not in LETTERS or (w.letter == "G" and w is not code):
            why = ("LinuxCNC's error: the drive line is the tool's X before the cycle" if w.letter in "XY" else
                   "write it on a line of its own")
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a G76 line: only P Z I J K R Q H E L are read there "
                                       f"({why})")
        if w.letter in by:
            raise _Refuse(w.start + 1, f"repeated '{w.letter}' word")
        by[w.letter] = w
    missing = [a for a in REQUIRED if a not in by]
    if missing:
        raise _Refuse(code.start + 1, f"'G76' without {' '.join(missing)}: the threading cycle needs P (pitch), Z (the "
                                      "thread's end), I (crest offset), J (first depth) and K (full depth)")
    return by


def _check_values(by, z0, p, z, e, i, j, k) -> None:
    """The G76 words' values (module docstring), each refusal at its word."""
    def bad(a, why):
        raise _Refuse(by[a].start + 1, f"'{a}{by[a].text}' on a G76 line: {why}")
    if not p > 0:
        bad("P", "the pitch must be positive")
    if abs(z - z0) < 1e-9:
        bad("Z", "the thread's end is its start (the tool's Z): no thread")
    if i == 0:
        bad("I", "I must not be 0 (LinuxCNC's error)")
    if not j > 0:
        bad("J", "J must be greater than 0 (LinuxCNC's error)")
    if not k > j:
        bad("K", "K must be greater than J (LinuxCNC's error)")
    if "R" in by and not by["R"].value >= 1.0:
        bad("R", "the depth degression must be at least 1 (LinuxCNC's reference)")
    if "Q" in by and (by["Q"].value == -1 or not abs(by["Q"].value) < 90):
        bad("Q", "Q-1 is read by LinuxCNC's interpreter as no Q (0°), and |Q| must be under 90°: write the angle "
                 "you mean" if by["Q"].value == -1 else "the compound angle must be under 90°")
    for a, top in (("H", None), ("L", 3)):
        if a in by and (by[a].value != int(by[a].value) or by[a].value < 0 or (top is not None and by[a].value > top)):
            bad(a, "the spring passes: a whole number ≥ 0" if a == "H" else "the tapered ends: 0, 1, 2 or 3")
    if "E" in by and (e < 0 or e > abs(z - z0) / 2):
        bad("E", "the taper length must be ≥ 0 and at most half the thread's length (LinuxCNC's reference)")


def g76_lines(line, e, i: int) -> tuple:
    """``(lines, summary note)`` of the G76 of event ``e`` on ``line`` (:func:`compensation.nc_thread.
    expand_threading`): its moves (:func:`passes`) in absolute X Z of the program's units (X as the program writes
    it), each G33 with its lead K (the main cut's as P is written); ``i`` the line's 0-based index."""
    cut, p_mm, p_text, inch, diameter = e[3]
    unit = MM_PER_INCH if inch else 1.0
    ending = line[len(line.rstrip("\r\n")):] or "\n"
    out = []
    for code, x, z, lead in (m for one in cut for m in one):
        xz = f"X{_word_text(x * (2.0 if diameter else 1.0) / unit)} Z{_word_text(z / unit)}"
        if code == "G0":
            out.append(f"G00 {xz}{ending}")
        else:
            k = p_text if lead == p_mm else _word_text(lead / unit)
            out.append(f"G33 {xz} K{k}{ending}")
    return out, note("line ", i + 1, f": G76 expanded: {len(cut)} passes written as G0 moves and G33 pieces (each "
                     "compensated with its own K; the G0 to each pass's start compensated)")
