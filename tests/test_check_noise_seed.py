"""``volcomp simulate --seed-check-noise`` (issue 28, the learned stage's error budget): redraws only the
check measurements' noise — the same machine, points, temperatures and directions — and without it the checks
are today's, bit for bit (the results tables' figures stay reproducible)."""
from __future__ import annotations

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.io import read_table
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth
from provenance import text_and_provenance

N, SIGMA = 50, 1.0
LAYOUT = ("x_mm", "z_mm", "a_deg", "time_s", "temp_c", "dir_x", "dir_z", "dir_a", "seq")


@pytest.mark.parametrize("family", ["default", "independent"])
def test_redraw_changes_only_the_noise(family):
    truth = make_chain_truth(load_machine(), 2, effects=["a_tilt"], family=family)
    a = truth.check_measurements(N, SIGMA, seed=7)
    b = truth.check_measurements(N, SIGMA, seed=7, noise_seed=11)
    for k in LAYOUT:
        np.testing.assert_array_equal(a[k], b[k])          # the layout and conditions: identical
    d = np.stack([a[k] - b[k] for k in ("dx_um", "dy_um", "dz_um")], axis=1)
    # the difference is the two noise draws' (the error itself is the same): the redraw is exactly
    # default_rng(11)'s noise, so a − b + that draw is the default draw, a N(0, σ²) sample
    noise_a = d + np.random.default_rng(11).normal(0.0, SIGMA, (N, 3))
    assert np.all(np.abs(d) > 0)
    # 150 standard normals: |mean| < 4 se and sd within 30 % of σ (loose: a check of scale, not a test of the RNG)
    assert abs(noise_a.mean()) < 4 * SIGMA / np.sqrt(3 * N) and 0.7 < noise_a.std() / SIGMA < 1.3


def test_default_noise_is_todays_stream():
    """Without ``noise_seed`` the noise is the layout stream's next draw, as before the option existed."""
    from errormap.chain_truth import make_chain_truth, random_axes
    m = load_machine()
    truth = make_chain_truth(m, 3, effects=["bump"])
    a = truth.check_measurements(N, SIGMA, seed=5)
    rng = np.random.default_rng(5)                          # the draw order of TruthGrinder.check_measurements
    axes = random_axes(m, N, rng)
    rng.normal(0, 0.02, N)
    rng.choice([-1, 1], size=(N, 3))
    noise = rng.normal(0.0, SIGMA, (N, 3))
    cond = {k: a[k] for k in ("temp_c", "dir_x", "dir_z", "dir_a")}
    e = truth.spatial_error(axes, **cond) + noise
    np.testing.assert_array_equal(np.stack([a["dx_um"], a["dy_um"], a["dz_um"]], axis=1), e)


def test_cli_option(tmp_path, capsys):
    def sim(name, *opts):
        assert main(["simulate", "--seed", "4", "--checks", str(N), *opts, "--out", str(tmp_path / name)]) == 0
        return read_table(tmp_path / name / "checks.csv")
    a, b, c = sim("a"), sim("b", "--seed-check-noise", "9"), sim("c", "--seed-check-noise", "9")
    np.testing.assert_array_equal(a.float("x_mm"), b.float("x_mm"))
    assert not np.array_equal(a.float("dx_um"), b.float("dx_um"))
    np.testing.assert_array_equal(b.float("dx_um"), c.float("dx_um"))     # the seed reproduces the draw
    assert "check_noise_seed: 9" in text_and_provenance(tmp_path / "b" / "checks.csv")
    assert "check_noise_seed" not in (tmp_path / "a" / "checks.csv").read_text()


# every family takes the option (the physics of a redrawn instrument noise is the same): the layout columns of a
# chain's checks and an arm's check poses stay bit for bit, only the measured coordinates change, the seed
# reproduces them, and the files and truth.json record it
OTHER_FAMILIES = {"mill-xyz": (("x_mm", "y_mm", "z_mm", "time_s", "temp_c", "dir_x", "dir_y", "dir_z", "seq"),
                               ("dx_um", "dy_um", "dz_um"), ["--checks", str(N)]),
                  "ur5": (("q1_deg", "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg"),
                          ("x_mm", "y_mm", "z_mm"), ["--checks", str(N), "--poses", "20"])}


@pytest.mark.parametrize("machine", sorted(OTHER_FAMILIES))
def test_cli_option_every_family(tmp_path, machine):
    import json
    layout, measured, opts = OTHER_FAMILIES[machine]

    def sim(name, *more):
        assert main(["simulate", "--machine", machine, "--seed", "4", *opts, *more, "--out", str(tmp_path / name)]) == 0
        return read_table(tmp_path / name / "checks.csv")
    a, b, c = sim("a"), sim("b", "--seed-check-noise", "9"), sim("c", "--seed-check-noise", "9")
    for k in layout:
        np.testing.assert_array_equal(a.float(k), b.float(k))
    d = np.stack([a.float(k) - b.float(k) for k in measured], axis=1)
    assert np.all(np.abs(d) > 0)                                        # every coordinate's noise redrawn
    for k in measured:
        np.testing.assert_array_equal(b.float(k), c.float(k))           # the seed reproduces the draw
    assert "check_noise_seed: 9" in text_and_provenance(tmp_path / "b" / "checks.csv")
    assert "check_noise_seed" not in (tmp_path / "a" / "checks.csv").read_text()
    assert json.loads((tmp_path / "b" / "truth.json").read_text())["check_noise_seed"] == 9
    assert "check_noise_seed" not in json.loads((tmp_path / "a" / "truth.json").read_text())


def test_chain_redraw_changes_only_the_noise():
    """A chain truth's checks: the difference of two draws is exactly the two noise streams' (the error is the same)."""
    from compensation.app.workflows.measurement import make_truth as chain_truth
    from errormap.seeds import spawn_rngs
    truth = chain_truth(load_machine("mill-xyz"), 2, effects=["reversal:X"])
    a = truth.check_measurements(N, SIGMA, seed=7)
    b = truth.check_measurements(N, SIGMA, seed=7, noise_seed=11)
    own = spawn_rngs(7, 3)[2].normal(0.0, SIGMA, (N, 3))
    new = np.random.default_rng(11).normal(0.0, SIGMA, (N, 3))
    d = np.stack([a[k] - b[k] for k in ("dx_um", "dy_um", "dz_um")], axis=1)
    # the same error evaluated twice at identical inputs: equal up to float rounding of the sums (1e-9 μm)
    np.testing.assert_allclose(d, own - new, rtol=0, atol=1e-9)
