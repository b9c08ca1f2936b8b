"""Tripod error transfer (tripod-3tpt paper)."""
from dataclasses import replace

import numpy as np
import pytest

from errormap.machine import load_machine
from errormap.pkm.hexapod import forward_kinematics, inverse_kinematics, workspace_poses
from errormap.pkm.tripod import leg_error_norm, sensitivity_vs_lambda, transfer_matrices

FK_TOL_MM = 1e-7
FD_STEP_MM = 1e-4
TRANSFER_TOL = 1e-6


@pytest.fixture(scope="module")
def tripod():
    return load_machine(expect_kind="tripod")


def test_tripod_ik_fk(tripod):
    tips, _ = workspace_poses(tripod, 200, seed=1)
    fk = forward_kinematics(tripod, inverse_kinematics(tripod, tips))
    assert np.max(np.abs(fk.x - tips)) < FK_TOL_MM


def test_transfer_matrices_match_finite_differences(tripod):
    p = np.array([[30.0, -20.0, 1000.0]])
    T = transfer_matrices(tripod, p)
    legs = inverse_kinematics(tripod, p)
    for i in range(3):
        dl = np.zeros(3)
        dl[i] = FD_STEP_MM
        d = (forward_kinematics(tripod, legs + dl).x - forward_kinematics(tripod, legs - dl).x) / (2 * FD_STEP_MM)
        assert np.allclose(d[0], T["f_l"][0][:, i], atol=TRANSFER_TOL)
        b = tripod.base_joints_mm.copy()
        b[i, 0] += FD_STEP_MM
        plus = forward_kinematics(replace(tripod, base_joints_mm=b), legs).x
        b[i, 0] -= 2 * FD_STEP_MM
        minus = forward_kinematics(replace(tripod, base_joints_mm=b), legs).x
        assert np.allclose((plus - minus)[0] / (2 * FD_STEP_MM), T["f_B"][0, i][:, 0], atol=TRANSFER_TOL)
    assert np.allclose(T["f_A"], -T["f_B"])


def test_sensitivity_grows_with_lambda_and_distance(tripod):
    lam = np.linspace(4.3, 6.4, 12)
    K = sensitivity_vs_lambda(tripod, lam)
    assert np.all(np.diff(K) > 0)
    assert np.all(np.diff(sensitivity_vs_lambda(tripod, lam, offset_xy_mm=(80.0, -60.0))) > 0)
    # at the centre K = 2/3 * l / c * (1 + ...) -> at least linear in lambda
    assert K[-1] / K[0] >= lam[-1] / lam[0] * 0.99
    assert leg_error_norm(tripod, np.array([[0.0, 0.0, 1000.0]]))[0] > 1.0


def test_sensitivity_plot_written_and_shows_the_trends(tripod, tmp_path, capsys):
    """The tripod paper's findings as a plot (via the CLI) and its data: K grows with lambda and with the
    distance from the fixed platform."""
    from compensation.app.cli import main
    from compensation.app.reports.tripod_sensitivity import plot_tripod_sensitivity
    from errormap.machine import builtin_machine_path

    png = tmp_path / "sens.png"
    assert main(["interpolate", "--machine", str(builtin_machine_path("tripod")), "--sensitivity-plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote" in capsys.readouterr().out
    st = plot_tripod_sensitivity(tripod, tmp_path / "again.png")
    assert np.all(np.diff(st["K_lambda"], axis=1) > 0)            # every curve grows with lambda
    K = st["K_map"]
    inside = np.isfinite(K)
    assert inside.mean() > 0.5                                     # the section is mostly workspace
    dK_h = np.diff(K, axis=1)                                      # along the distance from the fixed platform
    assert np.all(dK_h[np.isfinite(dK_h)] > 0)
    assert main(["interpolate", "--sensitivity-plot", str(tmp_path / "x.png")]) == 2   # hexapod: refused
    assert not (tmp_path / "x.png").exists()
