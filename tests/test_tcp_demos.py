"""LinuxCNC's 5-axis demo programs and the program of their shape that the benchmark suite writes
(benchmarks/suite/tcp.py) on ``five-axis-ac``: the tool axis turned out to <= 5 μrad wherever the tool is tilted,
the tool axis turned out only in A's plane (C held) where the tool is vertical (A = 0: C turns the tool about itself),
the tip compensated either way, G93 times kept; every programmed tip reached by the TRUE machine (an independent
TCP inverse of the written program). The demos themselves are GPL and not stored: the tests on them run where
``$VOLCOMP_PROGRAM_CORPUS`` holds them (program_corpus/TCP_DEMOS.csv) and skip otherwise."""
import os
import re
from pathlib import Path

import numpy as np
import pytest

from benchmarks.suite import tcp as suite
from compensation.tcp_orientation import ORIENT_ROTARY_LIMIT_DEG
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.machine import load_machine
from tests.test_tcp import TIME_REL_TOL, TRUE_EXACT_UM

ORIENT_BOUND_URAD = 5.0
"""The tool axis left where the rotary axes can turn it (the issue's bound); the model's 0.5 μrad station
noise leaves about 2 μrad (observed 1.7-2.2)."""
NOISY_TIP_FRACTION = 0.1
"""A model with 0.5 μm / μrad station noise on ±10 μm / μrad elements leaves about 5 % of the tip error
(observed 5-6 %)."""
WRITTEN_DEG = 5e-7
"""Half the last written digit of a rotary word (six decimals)."""
FLOOR_GAP_URAD = 1.0
"""How far above the TRUE floor (C held, the truth solved exactly) the noisy model's solve may leave the tool axis at
the tool-vertical points: twice the model's 0.5 μrad station noise (observed 0.016 μrad)."""
FAR_TURN_DEG = 30.0
"""The C turn some tool-vertical point needs for the issue's bound: tens of degrees (observed 90° on a 10° grid, 84°
on the page's 2° grid; 36° on the boat), three grid steps at least."""
POSITION_ONLY_AXIS_URAD = 1.0
"""Position-only compensation keeps the rotary axes: the tool axis stays as it was (to the linear moves' own
effect on it, observed < 0.05 μrad)."""


def tcp_points(text):
    """Independent of the product: ``(points (n, 5) X Y Z A C, feed (n,) bool)`` of every line of a LinuxCNC program
    between M428 and M429 (modal axis words carried; ``;`` and ``( )`` comments dropped; a feed point: G1/G2/G3
    active)."""
    pos = dict.fromkeys("XYZAC", np.nan)
    on, feed, pts, flags = False, False, [], []
    for line in text.splitlines():
        body = re.sub(r"\(.*?\)", "", line.split(";")[0]).upper()
        on = (on or re.search(r"M0*428(?![\d.])", body) is not None) and re.search(r"M0*429(?![\d.])", body) is None
        g = re.findall(r"G0*([0123])(?![\d.])", body)
        if g:
            feed = g[-1] != "0"
        words = dict(re.findall(r"([XYZAC])\s*([+-]?[\d.]+)", body))
        if words and on:
            pos.update({k: float(v) for k, v in words.items()})
            pts.append([pos[a] for a in "XYZAC"])
            flags.append(feed)
    return np.array(pts), np.array(flags)


def programmed_points_reached_um(src_text, out_text, truth_path, offset_z):
    """Every programmed TCP feed point of the source: the distance (μm) to the nearest TRUE tip among the written
    feed points, each driven as a TCP controller drives it (the nominal inverse at the machine file's own tool —
    no G43 in these programs — of the written tip + work offset at the written A C, then the truth's tool point
    there). ``(max μm, points checked)``."""
    mt = load_machine(suite.MACHINE)
    off = np.array([0.0, 0.0, float(offset_z)])
    src, sf = tcp_points(src_text)
    out, of = tcp_points(out_text)
    src, out = src[sf & np.isfinite(src).all(axis=1)], out[of & np.isfinite(out).all(axis=1)]
    q, ok = mt.inverse(out[:, :3] + off, np.column_stack([np.zeros((len(out), 3)), out[:, 3:]]),
                       free=("X", "Y", "Z"), tol_mm=1e-10)
    assert ok.all()
    tips = mt.nominal(q) + 1e-3 * ChainField(mt, ChainElementSet.load(truth_path, mt)).predict(q) - off
    d = np.array([np.min(np.linalg.norm(tips - p, axis=1)) for p in src[:, :3]]) * 1e3
    return float(d.max()), len(src)


def check_program(tmp_path, name, src: Path, offset_z):
    """The suite's row of one program (noisy model) checked, then the truth as model: every programmed tip
    reached, C held only near A = 0, and there the tool axis brought nearer."""
    mt = load_machine(suite.MACHINE)
    truth = ChainElementSet.random(mt, 0, 10.0, 11)
    tp = truth.save(tmp_path / "truth.json")
    model = suite.noisy(truth, 1).save(tmp_path / "model.json")
    (tmp_path / "wo.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{offset_z:g}\n")
    (tmp_path / "tt.csv").write_text("tool,length_mm,radius_mm\n1,0,5\n")
    tables = (tmp_path / "wo.csv", tmp_path / "tt.csv")
    r = suite.program_row(name, src, "linuxcnc", tables, model, tp, tmp_path)
    assert r["tip_pos_um"] <= NOISY_TIP_FRACTION * r["tip_before_um"]
    assert r["tip_ori_um"] <= NOISY_TIP_FRACTION * r["tip_before_um"]
    assert abs(r["axis_pos_urad"] - r["axis_before_urad"]) <= POSITION_ONLY_AXIS_URAD
    assert r["solved"] > 0 and r["axis_solved_ori_urad"] <= ORIENT_BOUND_URAD < r["axis_solved_before_urad"]
    assert r["kept"] == 0 and (not r["partly"] or r["axis_partly_ori_urad"] < r["axis_partly_before_urad"])
    minutes_in, minutes_out = r["g93_minutes_in_out"]
    assert minutes_in > 0 and abs(minutes_out - minutes_in) <= TIME_REL_TOL * minutes_in
    # the truth as model: the programmed tips reached; C held (as the position-only run writes it) only where the
    # tool is vertical
    pos = suite.compensate(src, "linuxcnc", tables, tp, tp, tmp_path / "t-pos", False)
    ori = suite.compensate(src, "linuxcnc", tables, tp, tp, tmp_path / "t-ori", True)
    for e in (pos, ori):
        reached, n = programmed_points_reached_um(src.read_text(encoding="latin-1"), e["output"], tp, offset_z)
        assert n > 100 and reached <= TRUE_EXACT_UM
    # the truth as model, the noisy model (each model splits the moves by its own field: its own point count)
    for (pos_text, ori_text), n_partly, n_points in (((pos["output"], ori["output"]),
                                                      ori["tcp"]["orientation_partly_points"], ori["points"]),
                                                     (r["outputs"], r["partly"], r["points"])):
        p, feed = tcp_points(pos_text)
        o, _ = tcp_points(ori_text)
        # C as the position-only run writes it: every partly point (and a solved one whose C correction is under
        # the written digits, 5e-7 deg); no rotary word corrected by more than the solve's limit (no swing)
        ok = np.isfinite(p).all(axis=1) & feed
        held = (o[:, 4] == p[:, 4]) & ok
        assert feed.sum() == n_points and held.sum() >= n_partly
        assert np.abs(o[ok, 3:] - p[ok, 3:]).max() <= ORIENT_ROTARY_LIMIT_DEG + WRITTEN_DEG
    return r


@pytest.mark.slow
def test_the_demo_shaped_program(tmp_path):
    """The program the suite writes in the demos' shape (roughing at A0, finishing tilted under G93)."""
    src = tmp_path / "xyzac-demo-shape.ngc"
    src.write_text(suite.demo_shape_program())
    r = check_program(tmp_path, src.name, src, suite.DEMO_OFFSET_Z_MM)
    assert r["partly"] > 0  # its roughing at A = 0
    # the floor at those points, on the TRUE machine solved exactly (C turned every 10°: 3.5 CPU s; the page: every 2°)
    mt = load_machine(suite.MACHINE)
    truth = ChainElementSet.random(mt, 0, 10.0, 11)
    floor = suite.vertical_floor(src, (tmp_path / "wo.csv", tmp_path / "tt.csv"), truth, suite.noisy(truth, 1), 10.0)
    assert floor["points"] == r["partly"]
    # with C held the bound is out of reach of any command, and the product's solve is at the floor
    assert ORIENT_BOUND_URAD < floor["held_urad"] <= r["axis_partly_ori_urad"] <= floor["held_urad"] + FLOOR_GAP_URAD
    # turning C reaches it, but only by tens of degrees
    assert floor["turned_urad"] <= ORIENT_BOUND_URAD and floor["turn_max_deg"] >= FAR_TURN_DEG


CORPUS = os.environ.get(suite.CORPUS_ENV)
DEMOS, _ = suite.fetched_demos(CORPUS)


@pytest.mark.slow
@pytest.mark.skipif(not DEMOS, reason="LinuxCNC's 5-axis demos not fetched ($VOLCOMP_PROGRAM_CORPUS, "
                                      "benchmarks/program_corpus/TCP_DEMOS.csv)")
@pytest.mark.parametrize("demo", DEMOS, ids=[d[0] for d in DEMOS])
def test_linuxcnc_demo(tmp_path, demo):
    name, path, offset_z = demo
    check_program(tmp_path, name, path, offset_z)
