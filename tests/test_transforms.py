"""The rigid-transform algebra of errormap/transforms.py (moved there from errormap/sweeps.py, which
imports it): composition, inversion and the error transform against 4×4 homogeneous matrices built
independently here."""
import numpy as np

from errormap import transforms as tf

SEED = 7
N = 50
FLOAT_MM = 1e-12
"""mm-sized (≤ 1e3 mm) products of orthonormal matrices: double rounding is ~1e-13 mm."""


def _homogeneous(R, t) -> np.ndarray:
    H = np.zeros(R.shape[:-2] + (4, 4))
    H[..., :3, :3], H[..., :3, 3], H[..., 3, 3] = R, t, 1.0
    return H


def _random_pose(rng, n):
    R = tf.rot_xyz(rng.uniform(-np.pi, np.pi, (n, 3)))
    return R, rng.uniform(-1000.0, 1000.0, (n, 3))


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])




def test_compose_and_invert_match_homogeneous_matrices():
    rng = np.random.default_rng(SEED)
    a, b = _random_pose(rng, N), _random_pose(rng, N)
    np.testing.assert_allclose(_homogeneous(*tf.compose(a, b)), _homogeneous(*a) @ _homogeneous(*b),
                               rtol=0, atol=FLOAT_MM)
    np.testing.assert_allclose(_homogeneous(*tf.invert(a)), np.linalg.inv(_homogeneous(*a)), rtol=0, atol=FLOAT_MM)
    R, t = tf.compose(a, tf.invert(a))
    np.testing.assert_allclose(R, np.broadcast_to(np.eye(3), R.shape), rtol=0, atol=FLOAT_MM)
    np.testing.assert_allclose(t, 0.0, rtol=0, atol=FLOAT_MM)


def test_error_transform_is_trans_then_rot_xyz_in_um_and_urad():
    rng = np.random.default_rng(SEED)
    d_um, e_urad = rng.normal(0, 50.0, (N, 3)), rng.normal(0, 200.0, (N, 3))
    R, t = tf.error_transform(d_um, e_urad)
    for i in range(N):
        ex, ey, ez = e_urad[i] * 1e-6
        np.testing.assert_allclose(R[i], _rx(ex) @ _ry(ey) @ _rz(ez), rtol=0, atol=FLOAT_MM)
    np.testing.assert_allclose(t, d_um * 1e-3, rtol=0, atol=FLOAT_MM)
