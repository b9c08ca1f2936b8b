"""Arm calibration through the CLI (volcomp calibrate / compensate --machine ur5): measured-pose
files, the geometric stage's bands on a simulated arm, the learned stage and joint compensation
judged against the simulated truth, and the real tracker files."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from errormap.arm_calibration import ArmCalibrator
from errormap.arm_poses import ArmPoses, convert_tracker_grid, read_arm_poses, write_arm_poses
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.io import read_table
from errormap.machine import load_machine

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "serial-arms"
# a UR5-like workspace box (deg) inside which the simulated poses are drawn (the real grid's ranges)
UR5_LO = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0])
UR5_HI = np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
NOISE_MM = 0.02          # tracker noise per component (a GTS3800 at 1 m: 15 μm + 6 μm/m)
NOISE_FLOOR_MM = np.sqrt(3) * NOISE_MM   # RMS 3-D error of a perfect model against noisy measurements
FLOOR_FACTOR = 1.25      # the bound: held-out error / compensation within 1.25× the noise
BAND_COVERAGE_MIN = 0.90  # share of identifiable slots × seeds inside their 95 % band (issue: ≥ 90 %)
N_SEEDS = 20
Z95 = 1.959963984540054


def cli(*args):
    return subprocess.run([sys.executable, "-m", "compensation.app.cli", *map(str, args)], capture_output=True,
                          text=True)


def _sim(chain, n, seed, sag=True):
    t = draw_truth(chain, seed, compliance_rad_per_mm=None if sag else np.zeros(chain.n_joints))
    q = random_joints(UR5_LO, UR5_HI, n, [seed, 0])
    return t, measure(chain, t, q, NOISE_MM, [seed, 1])


@pytest.fixture(scope="module")
def ur5():
    return load_machine("ur5")


@pytest.mark.parametrize("edit,col,words", [
    (lambda p: setattr(p, "xyz_mm", p.xyz_mm / 1000), "_mm'", "metres"),
    (lambda p: setattr(p, "q", np.radians(p.q)), "_deg'", "radians"),
    (lambda p: p.q.__setitem__((5, 2), 400.0), "q3_deg", "limits"),
])
def test_pose_file_refusals_name_file_row_column(tmp_path, ur5, edit, col, words):
    _, p = _sim(ur5, 40, 0)
    edit(p)
    f = tmp_path / "poses.csv"
    write_arm_poses(f, ur5, p)
    r = cli("calibrate", f, "--machine", "ur5", "--out", tmp_path / "o")
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and str(f) in line and "row " in line and words in line and col in line


def test_poses_too_alike_refused(tmp_path, ur5):
    _, p = _sim(ur5, 60, 0)
    p.q[:, 4] = 90.0  # joint 5 never moves: its link parameters cannot be told apart
    f = tmp_path / "poses.csv"
    write_arm_poses(f, ur5, p)
    r = cli("calibrate", f, "--machine", "ur5", "--out", tmp_path / "o", "--no-learned")
    assert r.returncode == 2 and "too alike" in r.stderr and "q5_deg" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_tracker_grid_layout_is_measured_equals_target_plus_dif(tmp_path, ur5):
    src = SHARED / "ur5_grid.csv"
    if not src.is_file():
        pytest.skip(f"{src} not present (the shared serial-arm data)")
    p = convert_tracker_grid(src, tmp_path / "ur5.csv", ur5)
    back = read_arm_poses(tmp_path / "ur5.csv", ur5)
    d = np.genfromtxt(src, delimiter=",", names=True)
    want = np.stack([d["x_t"] + d["x_dif"], d["y_t"] + d["y_dif"], d["z_t"] + d["z_dif"]], 1)
    assert back.layout == "schema" and p.layout == "tracker-grid"
    assert np.allclose(back.xyz_mm, want, rtol=0, atol=1e-8) and np.allclose(back.q[:, 0], d["joint_1"], atol=1e-8)


@pytest.mark.slow
def test_geometric_stage_recovers_link_errors_within_bands(ur5):
    """20 seeds of a simulated UR5 (link + base + tool errors, tracker noise): the identified slots lie
    within their 95 % bands of the truth's identifiable equivalent (the same estimator on the truth's
    noiseless tool points: the judge's side, never given to the estimator)."""
    inside = []
    for seed in range(N_SEEDS):
        t, p = _sim(ur5, 200, seed, sag=False)
        r = ArmCalibrator(ur5).fit(p).result_
        clean = ArmPoses(p.q, ur5.tool_point(p.q, t.errors), None, None, None, p.rows, "truth", "schema")
        eq = ArmCalibrator(ur5).fit(clean).result_
        assert (eq.free == r.free).all()
        inside.extend(np.abs(r.params - eq.params)[r.free] <= Z95 * r.std[r.free])
    assert np.mean(inside) >= BAND_COVERAGE_MIN


@pytest.mark.slow
def test_simulated_arm_cli_learned_stage_and_compensation(tmp_path, ur5):
    """Link errors + joint-stiffness sag + noise: calibrate through the CLI, then compensate a joint
    program and judge the commands against the TRUE arm."""
    t, fit = _sim(ur5, 400, 7)
    qc = random_joints(UR5_LO, UR5_HI, 100, [7, 5])
    check = measure(ur5, t, qc, NOISE_MM, [7, 6])
    write_arm_poses(tmp_path / "fit.csv", ur5, fit)
    write_arm_poses(tmp_path / "check.csv", ur5, check)
    r = cli("calibrate", tmp_path / "fit.csv", "--check", tmp_path / "check.csv", "--machine", "ur5", "--out",
            tmp_path / "cal")
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    st = {s["name"]: s for s in doc["stages"]}
    assert doc["kept_stage"] == "learned"
    assert st["learned"]["rms_mm"] <= FLOOR_FACTOR * NOISE_FLOOR_MM
    assert st["geometric"]["rms_mm"] > st["learned"]["rms_mm"]
    base = {s["name"]: s for s in doc["baselines"]}
    assert st["learned"]["mean_mm"] <= base["plain GP on plain LSQ residual"]["mean_mm"] * 1.05 or \
        st["learned"]["mean_mm"] <= FLOOR_FACTOR * NOISE_FLOOR_MM
    # compensation: targets = nominal tool points of a joint program; TRUE residual of the commands
    qp = random_joints(UR5_LO + 5, UR5_HI - 5, 50, [7, 9])
    prog = tmp_path / "prog.csv"
    prog.write_text(",".join(ur5.joint_columns) + "\n" + "\n".join(",".join(f"{v:.10g}" for v in row) for row in qp))
    r = cli("compensate", prog, "--machine", "ur5", "--model", tmp_path / "cal" / "calibration.json", "--out",
            tmp_path / "comp")
    assert r.returncode == 0, r.stdout + r.stderr
    out = read_table(tmp_path / "comp" / "prog.csv")
    qn = np.stack([out.float(c) for c in ur5.joint_columns], 1)
    true_err = np.linalg.norm(t.tool_point(ur5, qn) - ur5.tool_point(qp), axis=1)
    before = np.linalg.norm(t.tool_point(ur5, qp) - ur5.tool_point(qp), axis=1)
    assert np.sqrt(np.mean(true_err ** 2)) <= FLOOR_FACTOR * NOISE_FLOOR_MM < np.sqrt(np.mean(before ** 2))


# --- the real UR5 tracker grid through the CLI, judged on a BLOCKED hold-out -----------------------------
BENCH_JSON = Path(__file__).resolve().parents[1] / "benchmarks" / "arms_results.json"
N_SECTORS = 4            # joint-1 quartiles, as benchmarks/bench_arms.py (--sectors 4, folds_sector)
CHECK_SECTOR = 3         # the top quartile of joint 1 ([39, 57] deg on the grid, 250 poses) is the held-out region
# The geometric stage must beat nominal + fitted base/tool by this factor on the held-out sector. Measured:
# 0.8545 / 0.0983 mm = 8.7x on this sector (the benchmark's pooled blocked figures: 0.714 / 0.106 = 6.8x);
# 5x leaves room for a different BLAS / LM stop while still failing on a geometric stage that only fits
# base and tool (1x) or half the link errors.
BASE_TOOL_OVER_GEOMETRIC_MIN = 5.0
# The same code on the same 750 / 250 poses is deterministic: the geometric stage must reproduce the
# benchmark's figure for this fold (arms_results.json, "q1 sector 3 [39, 57] deg": 0.09833 mm; this test
# measured 0.09833 mm) to within 2 % (LM stopping and BLAS summation order only).
REPRODUCE_BENCH_REL = 0.02
# ... and lie near the benchmark's plain least-squares calibration on the blocked folds (arms_results.md,
# "plain geometric LSQ", blocked mean 0.1058 mm pooled over the 4 sectors; the per-sector figures of that
# run range 0.091 - 0.133 mm, i.e. -14 % ... +25 %). Measured here: 0.0983 mm (-7 %); plain LSQ on this
# sector 0.0993 mm. A 15 % bound: a sector within the benchmark's spread below the pooled figure.
NEAR_PLAIN_LSQ_BENCH_REL = 0.15


def _bench_blocked(arm, sector):
    doc = json.loads(BENCH_JSON.read_text(encoding="utf-8"))["real"][arm]["blocked"]
    fold = [f for f in doc["folds"] if f["fold"].startswith(f"q1 sector {sector} ")]
    assert len(fold) == 1, f"{BENCH_JSON}: no blocked fold 'q1 sector {sector}'"
    return doc["summary"]["plain geometric LSQ"]["mean_mm"], fold[0]


@pytest.mark.slow
def test_real_ur5_grid_blocked_sector_through_the_cli(tmp_path, ur5):
    """The real 1,000-pose UR5 tracker grid: fit on three joint-1 quartiles, check on the fourth (another
    region of the workspace), through ``volcomp calibrate … --check`` in-process. ``--no-learned``: the
    learned stage's CV alone takes ~30 CPU s here; the geometric stages and the plain baselines are judged.
    MEASURED residual on the held-out sector; about 20 CPU s."""
    from compensation.app.cli import main
    src = SHARED / "ur5_grid.csv"
    if not src.is_file():
        pytest.skip(f"{src} not present (the shared serial-arm data)")
    poses = read_arm_poses(src, ur5)
    q1 = poses.q[:, 0]
    edges = np.quantile(q1, np.linspace(0, 1, N_SECTORS + 1))
    sector = np.clip(np.searchsorted(edges, q1, side="right") - 1, 0, N_SECTORS - 1)
    held = sector == CHECK_SECTOR
    write_arm_poses(tmp_path / "fit.csv", ur5, poses.subset(np.flatnonzero(~held)))
    write_arm_poses(tmp_path / "check.csv", ur5, poses.subset(np.flatnonzero(held)))
    assert main(["calibrate", str(tmp_path / "fit.csv"), "--machine", "ur5", "--check", str(tmp_path / "check.csv"),
                 "--out", str(tmp_path / "cal"), "--no-learned"]) == 0
    doc = json.loads((tmp_path / "cal" / "calibration.json").read_text(encoding="utf-8"))
    assert doc["n_check_poses"] == held.sum() and doc["n_fit_poses"] == (~held).sum()
    assert q1[held].min() >= q1[~held].max()          # blocked: the held-out poses lie beyond every fit pose
    st = {s["name"]: s for s in doc["stages"]}
    base = {s["name"]: s for s in doc["baselines"]}
    geo = st["geometric"]["mean_mm"]
    assert base["nominal + base/tool"]["mean_mm"] >= BASE_TOOL_OVER_GEOMETRIC_MIN * geo
    assert geo <= base["plain geometric LSQ"]["mean_mm"]      # never returns a model losing to the plain baseline
    plain_bench, fold = _bench_blocked("ur5", CHECK_SECTOR)
    assert fold["n_check"] == held.sum()
    assert abs(geo - fold["geometric_mean_mm"]) <= REPRODUCE_BENCH_REL * fold["geometric_mean_mm"]
    assert abs(geo - plain_bench) <= NEAR_PLAIN_LSQ_BENCH_REL * plain_bench
    # the kept stage is one of the stages, and the lowest held-out one unless the rule says why not
    assert doc["kept_stage"] in st
    lowest = min(st.values(), key=lambda s: s["mean_mm"])["name"]
    assert doc["kept_stage"] == lowest or "not" in doc["kept_why"], doc["kept_why"]
    assert doc["kept_stage"] == "geometric" and "not run" in doc["kept_why"]
