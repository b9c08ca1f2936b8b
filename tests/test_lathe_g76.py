"""LinuxCNC's ``G76`` threading cycle on a lathe (compensation/nc_g76.py): read exactly, written with
``--expand-cycles`` as its interpreter's passes (G0 moves and G33 pieces each with its own K), refused kept. Programs
written here from the LinuxCNC G-code reference ("G76 Threading Cycle": ``G76 P- Z- I- J- R- K- Q- H- E- L-``), not
copied.

The passes' geometry is computed here from the reference's rules, independently of the reader: depth beyond the
crest J·n^(1/R) for n = 1, 2, … while under K, then K (H + 1 times); each pass shifted along Z by −(depth)·tan Q (the
compound slide) and the thread's end by + K·tan Q; the crest at the drive line + I; a pass rapids to the retract X
(its cut X + |I| + K, outside), in to its cut X (or along the entry taper from the crest over E), cuts along Z at P per
revolution (along the exit taper over E back to the crest), and rapids out. The compensated program is checked on
``lathe-xzc`` with a seeded truth that is also the model, by the G32/G33 tests' checkers: every programmed point
reached by a written move whose TRUE tip (mean over one turn) is within :data:`TOL_POINT_UM`; every written G33
piece's TRUE lead equals the programmed P within :data:`compensation.nc_thread.LEAD_TOL_REL`; every pass starts at
its programmed Z on the TRUE machine (its phase)."""
import math

import numpy as np
import pytest

from benchmarks.suite.lathe import true_leads
from compensation.app.cli import main
from compensation.nc_thread import LEAD_TOL_REL
from compensation.turning import parse_lathe_program
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from test_lathe_g33 import LATHE, PART_Z_MM, TOL_POINT_UM, _compensate, checked

TOL_WRITTEN_MM = 1e-6
"""An expanded move's end equals the reference's within this: the written words' rounding (7 decimals: 0.5e-7 mm)
with margin."""
TOL_WRITTEN_INCH_MM = 2e-6
"""The same in an inch program: 7 decimals of an inch word round by 0.5e-7 in = 1.27e-6 mm; with margin."""
X0, Z0, Z1 = 11.0, 5.0, -30.0
"""The drive line (radius, G8), the thread's start and end Z (mm)."""
P, I, J, K, R, Q, H, E = 2.5, -1.0, 0.3, 1.534, 1.0, 29.5, 1, 2.0
"""An M20x2.5 outside thread: crest 1 mm inside the drive line, full depth 1.534 mm, first depth 0.3 mm, constant
depth, 29.5° compound slide, one spring pass; E the taper length when L tapers an end."""
M20 = ("(M20x2.5 thread, LinuxCNC G76)\n{units} G18 G90 {mode}\nG54\nS400 M3\nG0 X{x0!r} Z{z0!r}\n"
       "G76 P{p!r} Z{z1!r} I{i!r} J{j!r} K{k!r} R{r} Q{q} H{h}{taper}\nG0 X20 Z10\nG1 X19 F100\nM5\nM2\n")


def _program(taper="", x0=X0, i=I, z0=Z0, z1=Z1, inch=False, diameter=False):
    """The thread's program (mm radius values given; written in inch and/or diameter mode as asked)."""
    u, d = (25.4 if inch else 1.0), (2.0 if diameter else 1.0)
    return M20.format(units="G20" if inch else "G21", mode="G7" if diameter else "G8", x0=x0 * d / u, z0=z0 / u,
                      z1=z1 / u, p=P / u, i=i * d / u, j=J * d / u, k=K * d / u, r=R, q=Q, h=H,
                      taper=f" E{E / u!r} L{taper}" if taper else "")


def _reference(ends=0, x0=X0, i=I, z0=Z0, z1=Z1):
    """The passes' moves ``[(rapid?, x, z, lead or None)]`` (mm, radius) from the reference's rules (module
    docstring): s the side (outside −1, inside +1), the compound slide and the tapers turned where Z runs toward +Z."""
    n = np.arange(1, 1000)
    depth = J * n ** (1.0 / R)
    depth = np.concatenate([depth[depth < K], [K] * (H + 1)])
    s, toward = (1.0 if i > 0 else -1.0), (-1.0 if z1 > z0 else 1.0)
    t, e = math.tan(math.radians(Q)) * toward, E * toward
    crest, taper_lead = x0 + i, P * math.hypot(E, K) / E
    out = []
    for d in depth:
        za, zb, cut = z0 - d * t, z1 + K * t - d * t, crest + s * d
        back, top = cut - s * (abs(i) + K), cut - s * K
        out.append((True, back, za, None))
        out += [(False, top, za, taper_lead), (False, cut, za - e, taper_lead)] if ends & 1 else [(True, cut, za, None)]
        out += [(False, cut, zb + e, P), (False, top, zb, taper_lead)] if ends & 2 else [(False, cut, zb, P)]
        out.append((True, back, zb, None))
    return out, len(depth)


def _read(path, cycles="keep"):
    return parse_lathe_program(path, load_machine(LATHE), "keep", None, "linuxcnc", cycles=cycles)[0]


@pytest.mark.parametrize("ends, side, inch, diameter", [
    (0, "outside", False, False), (1, "outside", False, False), (2, "outside", False, False),
    (3, "outside", False, False), (3, "inside", False, False), (3, "outside, toward +Z", True, True),
    (0, "inside, toward +Z", False, True)])
def test_g76_expanded_passes_are_the_reference_geometry(tmp_path, ends, side, inch, diameter):
    geo = {"x0": 8.0, "i": 1.0} if side.startswith("inside") else {}  # a bore: the crest 1 mm outside the drive line
    if "+Z" in side:
        geo.update(z0=Z1, z1=Z0)
    src = tmp_path / "p.ngc"
    src.write_text(_program(ends, inch=inch, diameter=diameter, **geo))
    prog = _read(src, "expand")
    ref, n = _reference(ends, **geo)
    moves = prog.moves[1:-2]  # the G0 to the drive line before, the G0 and G1 after
    assert n == 7 and len(moves) == len(ref)  # ceil(1.534 / 0.3) - 1 = 5 passes under K, then K twice (H1)
    tol = TOL_WRITTEN_INCH_MM if inch else TOL_WRITTEN_MM
    got = np.array([m.end for m in moves])
    assert np.abs(got - np.array([r[1:3] for r in ref])).max() <= tol
    assert [m.kind == "rapid" for m in moves] == [r[0] for r in ref]
    leads = [(m.lead[0] * (25.4 if inch else 1.0), r[3]) for m, r in zip(moves, ref) if r[3] is not None]
    assert all(m.synced == "G33" for m, r in zip(moves, ref) if r[3] is not None)
    assert max(abs(a - b) for a, b in leads) <= tol
    end = (geo.get("x0", X0), geo.get("z1", Z1))
    assert np.allclose(prog.moves[-3].end, end, rtol=0, atol=tol)  # the tool ends at (X0, Z)


def test_g76_compensated_every_point_lead_and_phase_true(tmp_path):
    rc, src, written, truth = _compensate(tmp_path, _program(), ("--expand-cycles",))
    assert rc == 0
    p_src, p_out = _read(src, "expand"), _read(written)
    m_src, lead_err, starts = checked(truth, p_src, p_out, P)  # every point within 1 um, every piece's lead P
    assert sum(m.lead is not None for m in m_src) == 7 and sum(m.kind == "rapid" for m in m_src) == 7  # pass starts
    assert len(lead_err) > 7  # split in pieces, each its own K
    programmed = np.array([m.start[1] for m in m_src if m.lead is not None])
    assert len(starts) == 7 and np.abs(starts - programmed).max() * 1e3 <= TOL_POINT_UM  # each pass in phase
    lathe = load_machine(LATHE)
    unc_err, _ = true_leads(ChainField(lathe, ChainElementSet.load(truth, lathe)), lathe, p_src.moves, (0.0, PART_Z_MM),
                            P)
    assert np.abs(unc_err).max() > 10 * LEAD_TOL_REL  # the truth bends the lead: the check can fail
    non_moves = [ln for ln, c in zip(p_out.lines, p_out.classes) if c != "move" and not ln.startswith("(volcomp:")]
    assert non_moves == [ln for ln, c in zip(p_src.lines, p_src.classes) if c != "move"]


@pytest.mark.parametrize("old,new,where", [
    ("G76", "G76", "line 6, column 1: 'G76' (multiple threading cycle) kept as a cycle"),
    (" H1", " H1 X10", "line 6, column 49: 'X10' on a G76 line"),
    (" R1.0", " R0.5", "line 6, column 35: 'R0.5' on a G76 line: the depth degression must be at least 1"),
    ("G18 G90", "G17 G90", "line 6, column 1: 'G76' (threading cycle) the plane is not G18"),
    (" Q29.5", " Q-1", "line 6, column 40: 'Q-1' on a G76 line"),
    (" K1.534", " K0.2", "line 6, column 28: 'K0.2' on a G76 line: K must be greater than J"),
    (" H1", " H1 E20 L1", "line 6, column 49: 'E20' on a G76 line: the taper length"),
    (" H1", " H1 F100", "line 6, column 49: 'F100' on a G76 line"),
    ("G0 X20 Z10", "Z10", "line 7, column 1: axis word 'Z10' but no motion mode"),
    (" R1.0", " R100", "line 6, column 35: a G76 of more than 10000 passes"),
])
def test_g76_refusals_name_line_column_word(tmp_path, old, new, where):
    src = tmp_path / "p.ngc"
    src.write_text(_program().replace(old, new, 1))
    with pytest.raises(InputError) as exc:
        _read(src, "keep" if old == "G76" else "expand")
    assert where in str(exc.value), str(exc.value)
    if old == "G76":
        assert "use --expand-cycles" in str(exc.value)
