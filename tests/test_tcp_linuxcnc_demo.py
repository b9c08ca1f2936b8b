"""A program in the style of LinuxCNC's 5-axis demos (the FeatureCAM "Hermle" post of ``boat-xyzac.ngc`` and the
impeller program, run on the ``xyzac-trt`` sim config with its switchable kinematics): ``M428`` switches TCP on,
the tool is called with ``T1 M6`` and no ``G43`` (LinuxCNC's kinematics then read a zero tool offset: the
controlled point is the point the axes are referenced to, the machine file's own tool point), 3-axis roughing
at ``A0 C0`` with an arc, then a 5-axis finish pass under ``G93``. Written here from LinuxCNC's manual (G-code
overview, G93, M-code remapping) and the sim config's notes; the public demos themselves are not in the
repository (their figures: ``python -m benchmarks.run tcp``; their tests: tests/test_tcp_demos.py)."""
import json
import tomllib

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from tests.test_tcp import TIME_REL_TOL, TRUE_EXACT_UM, tcp_lines, true_tips_mm

ORIENT_TRUE_URAD = 0.1
"""With the truth as the model a solved point keeps only the written rotary digits' error (1e-6 deg =
0.017 μrad per axis): 0.1 μrad (the issue's bound is 5 μrad)."""
OFFSET = (0.0, 0.0, 13.25)
"""G54: the demo's touch-off puts the table at program Z -13.25; here the C table top."""

DEMO = """%
M428 ;TCP:xyzac
(DEMO-XYZAC)
( OPERATION=  ROUGH  Z LEVEL )
( TOOL: T1 = 10.0 dia. ENDMILL )
G00 G17 G40 G90 G94
Z5
T1 M6
G54 X-30. Y-20. A0. C0. S630 M03
G00 Z5.0 M08
Z3.0
G01 Z-6.5 F300.0
X30. F600.0
Y-10.
X-30.
G02 X-20. Y0. I10. J0.
G01 X25. Y5.
G00 Z5.0

( FINISH  FLOWLINE )
G54 X-20. Y-5. A-15. C20. S600
Z3.0
G93
G01 X-18. Y-6. Z-1.5 F60.0
X-10. Y-8. Z-2.0 A-18. C10. F120.5
X0. Y-9. Z-2.5 A-22. C0. F98.25
X10. Y-8. Z-2.0 A-26. C-15. F101.0
X18. Y-6. Z-1.5 A-30. C-30. F140.0
G94
G00 Z5.0
M429 ;identity kins
M5 M9
M2
%
"""


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("tcpdemo")
    mt = load_machine("five-axis-ac")
    truth = ChainElementSet.random(mt, 7, 10.0, 11).save(d / "truth.json")
    (d / "wo.csv").write_text("system,x_mm,y_mm,z_mm\nG54,%g,%g,%g\n" % OFFSET)
    (d / "tt.csv").write_text("tool,length_mm,radius_mm\n1,0,5\n")  # the sim's T1: Z0 (no G43 applies it anyway)
    (d / "demo.ngc").write_text(DEMO)
    return mt, truth, d


def _run(setup, out, machine="five-axis-ac", extra=()):
    mt, truth, d = setup
    rc = main(["compensate", str(d / "demo.ngc"), "--machine", machine, "--model", str(truth), "--method", "exact",
               "--out", str(d / out), "--truth", str(truth), "--work-offsets", str(d / "wo.csv"), "--tool-table",
               str(d / "tt.csv"), "--dialect", "linuxcnc", "--force", *extra])
    summary = d / out / "compensate_summary.json"
    return rc, (json.loads(summary.read_text())["files"][0] if summary.is_file() else None), d / out / "demo.ngc"


def _g93_minutes(text):
    t, g93 = [], False
    for ln in text.splitlines():
        body = ln.split("(")[0].split(";")[0].upper()
        g93 = (g93 or "G93" in body) and "G94" not in body
        if g93 and any(c in body for c in "XYZAC") and "F" in body:
            t.append(1.0 / float(body.split("F")[1].split()[0]))
    return t


def _programmed_path(src):
    """The programmed tip path (m, 3) mm as a dense polyline: the TCP lines' positions in order (rapids too),
    the one G02 arc (centre I10 J0 from X-30 Y-10, clockwise to X-20 Y0, radius 10) sampled every 0.01°."""
    rows = [p for i, _, p in tcp_lines(src) if i >= 8]  # from the G54 line on: every axis known
    out = []
    for k, p in enumerate(rows):
        if k and rows[k - 1][:2] == [-30.0, -10.0] and p[:2] == [-20.0, 0.0]:
            ang = np.radians(np.linspace(180.0, 90.0, 9001))
            out += [[-20.0 + 10.0 * np.cos(a), -10.0 + 10.0 * np.sin(a), p[2]] for a in ang]
        out.append(p[:3])
    return np.array(out)


def test_m428_without_g43_runs_at_the_machine_files_tool_point(setup):
    """Position only: every TCP vertex's TRUE tip, driven through an independent nominal inverse at the machine
    file's own tool length (150 mm) on the truth, lies on the programmed path; non-motion lines byte-identical;
    G93 block times kept."""
    mt, truth, d = setup
    rc, entry, out = _run(setup, "pos")
    assert rc == 0, entry
    assert entry["tcp"]["points"] > 0 and entry["tcp"]["inverse_time_lines"] > 0
    assert entry["tcp"]["tool"].startswith(f"{entry['tcp']['points']} TCP point(s) with no G43 active run at the "
                                           "machine file's own tool point")  # the summary says so
    assert entry["true"]["max_um"] <= TRUE_EXACT_UM < entry["true_uncompensated"]["max_um"]
    src, dst = DEMO, out.read_text()
    moves = {i for i, _, _ in tcp_lines(src)}
    assert all(ln in dst.splitlines() for i, ln in enumerate(src.splitlines()) if i not in moves)
    length = float(tomllib.loads(open(mt.path).read())["geometry"]["tool_length"])
    pts = np.array([p for _, on, p in tcp_lines(dst) if on])
    tips = true_tips_mm(mt, truth, pts[:, :3] + np.array(OFFSET), pts[:, 3:], length) - np.array(OFFSET)
    seg = _programmed_path(src)
    dist = np.full(len(tips), np.inf)
    for a, b in zip(seg[:-1], seg[1:]):
        t = np.clip(((tips - a) @ (b - a)) / max((b - a) @ (b - a), 1e-30), 0, 1)
        dist = np.minimum(dist, np.linalg.norm(a + t[:, None] * (b - a) - tips, axis=1))
    assert dist.max() * 1e3 <= TRUE_EXACT_UM
    src_t, dst_t = _g93_minutes(src), _g93_minutes(dst)
    assert len(dst_t) >= len(src_t) and abs(sum(dst_t) - sum(src_t)) <= TIME_REL_TOL * sum(src_t)


def test_orientation_solved_where_the_tool_is_tilted(setup):
    """With --compensate-orientation the finish pass (A from -15° to -30°) has its tool axis corrected; at the
    roughing at A0, where C turns the tool about itself, A turns out the tilt in its own plane and C is held: the
    tool axis brought nearer (counted as partly), none kept."""
    rc, entry, _ = _run(setup, "orient", extra=("--compensate-orientation",))
    assert rc == 0
    o = entry["tcp"]
    assert o["orientation_solved_points"] > 0 and o["orientation_partly_points"] > 0 == o["orientation_kept_points"]
    assert o["true_orientation_partly"]["max_urad"] < o["true_orientation_partly_uncompensated"]["max_urad"]
    assert o["true_orientation_solved"]["max_urad"] <= ORIENT_TRUE_URAD
    assert o["true_orientation_solved_uncompensated"]["max_urad"] > 100 * ORIENT_TRUE_URAD
    assert entry["true"]["max_um"] <= TRUE_EXACT_UM


def test_m428_without_g43_refused_where_the_machine_file_does_not_say(setup, tmp_path, capsys):
    """A machine file whose [tcp] does not declare tool_length_under_g49 keeps the refusal (file, line, switch)."""
    mt, _, _ = setup
    text = open(mt.path).read().replace('tool_length_under_g49 = "machine"\n', "")
    assert "tool_length_under_g49" not in text
    (tmp_path / "m.toml").write_text(text)
    rc, _, _ = _run(setup, "refused", machine=str(tmp_path / "m.toml"))
    assert rc == 2
    err = capsys.readouterr().err
    assert "demo.ngc: line 12: under 'M428' (line 2, column 1): tool-centre-point control with no tool length" in err


def test_machine_file_key_checked(setup):
    from errormap.machine_checks import MachineFileError
    from errormap.machine_tool import parse_machine_tool
    mt, _, _ = setup
    assert mt.tcp["tool_length_under_g49"] == "machine"
    doc = tomllib.loads(open(mt.path).read())
    doc["tcp"]["tool_length_under_g49"] = "zero"
    with pytest.raises(MachineFileError, match="tcp.tool_length_under_g49"):
        parse_machine_tool(doc, "m.toml")
