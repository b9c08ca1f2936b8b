"""Batched rotations, cross-product matrices and point checks.

Rotations are arrays of shape (n, 3, 3), points (n, 3). Angles in rad unless
the name says otherwise.
"""
from __future__ import annotations

import numpy as np


def check_points(points, name: str = "points", width: int = 3) -> np.ndarray:
    """Convert to float64 of shape (n, width); a single point becomes (1, width).

    Raises ValueError "Expected ..., got ..." for anything else or non-finite values.
    """
    arr = np.asarray(points, dtype=float)
    if arr.ndim == 1 and arr.shape[0] == width:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise ValueError(f"Expected {name} of shape (n, {width}), got shape {np.shape(points)}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"Expected finite {name}, got {arr[bad[0], bad[1]]} at row {bad[0]}, column {bad[1]}")
    return arr


def rot_about(axis: int, angle_rad) -> np.ndarray:
    """Rotation about frame axis ``axis`` (0, 1, 2 = x, y, z) for a batch of angles, shape (n, 3, 3)."""
    a = np.atleast_1d(np.asarray(angle_rad, dtype=float))
    c, s = np.cos(a), np.sin(a)
    b, d = (axis + 1) % 3, (axis + 2) % 3
    R = np.zeros(a.shape + (3, 3))
    R[..., axis, axis] = 1.0
    R[..., b, b], R[..., b, d], R[..., d, b], R[..., d, d] = c, -s, s, c
    return R


def rot_x(angle_rad) -> np.ndarray:
    """RotX for a batch of angles, shape (n, 3, 3)."""
    return rot_about(0, angle_rad)


def rot_y(angle_rad) -> np.ndarray:
    """RotY for a batch of angles, shape (n, 3, 3)."""
    return rot_about(1, angle_rad)


def rot_z(angle_rad) -> np.ndarray:
    """RotZ for a batch of angles, shape (n, 3, 3)."""
    return rot_about(2, angle_rad)


def skew(v) -> np.ndarray:
    """Cross-product matrices: ``skew(v) @ w == cross(v, w)``; v shape (n, 3) -> (n, 3, 3)."""
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


def apply(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Batched ``R @ v``: R shape (n, 3, 3) or (3, 3), v shape (n, 3) -> (n, 3)."""
    return np.einsum("...ij,...j->...i", R, v)
