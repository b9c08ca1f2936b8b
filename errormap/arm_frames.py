"""The frames of a calibrated arm kept apart: the instrument (tracker, world) → robot base transform, the link
parameters, and the tool point in the last link's frame.

Only the base block (``base.*``, :data:`BASE_SLOTS`) carries the tracker's arbitrary placement; where a link
slot and a frame slot move the tool point the same way the frame slot is identified and the link slot held at
nominal (:data:`FRAME_SLOT_PREFIXES`, :func:`errormap.arm_calibration.identifiable_slots`;
``docs/reference/arm-calibration.md``). The robot's base frame is the frame after the base block: joint
programs and their targets are in it; :func:`to_base_frame` / :func:`from_base_frame` turn points between it
and a calibration's instrument frame. Lengths mm, angles rad; points (n, 3); transforms (4, 4)."""
from __future__ import annotations

import numpy as np

from .io import InputError

BASE_SLOTS = ("base.x_mm", "base.y_mm", "base.z_mm", "base.rz_rad", "base.ry_rad", "base.rx_rad")
"""The base frame's slots, in the order of its elementary transforms (tx ty tz rz ry rx, :func:`errormap.chain.base_ets`)."""
TOOL_SLOTS = ("tool.x_mm", "tool.y_mm", "tool.z_mm")
FRAME_SLOT_PREFIXES = ("base.", "tool.")
"""Slots identified before any link slot: a link slot they already account for is held at nominal."""


def rot(axis: int, a: float) -> np.ndarray:
    """Rotation (3, 3) by ``a`` rad about axis 0/1/2 (x/y/z)."""
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def base_slot_ets(chain):
    """The base frame's elementary transforms (in :data:`BASE_SLOTS` order) and its slots' indices (6,); InputError
    if the chain has no base slots in that order."""
    ets = [e for e in chain.ets if e.slot in BASE_SLOTS]
    if [e.slot for e in ets] != list(BASE_SLOTS):
        raise InputError(f"machine {chain.name!r}: no base frame slots {BASE_SLOTS} in this order: its base frame "
                         "cannot be told apart from its links")
    return ets, np.array([list(chain.param_names).index(s) for s in BASE_SLOTS])


def has_base_slots(chain) -> bool:
    try:
        base_slot_ets(chain)
    except InputError:
        return False
    return True


def _transform(total) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = total[:3]
    T[:3, :3] = rot(2, total[3]) @ rot(1, total[4]) @ rot(0, total[5])
    return T


def base_transform(chain, params=None) -> np.ndarray:
    """Instrument → robot base transform (4, 4) at the slot values ``params`` (n_params,) (None: the nominal base)."""
    ets, idx = base_slot_ets(chain)
    p = np.zeros(chain.n_params) if params is None else np.asarray(params, float)
    return _transform(np.array([e.value + e.coef * p[k] for e, k in zip(ets, idx)]))


def base_rotation(chain, params) -> np.ndarray:
    """The base frame's rotation (3, 3) at the slot values ``params``."""
    return base_transform(chain, params)[:3, :3]


def to_base_frame(chain, params, p_mm) -> np.ndarray:
    """Points (n, 3) in the instrument's frame of the slot values ``params`` → the robot's base frame."""
    T = base_transform(chain, params)
    return (np.asarray(p_mm, float) - T[:3, 3]) @ T[:3, :3]


def from_base_frame(chain, params, p_mm) -> np.ndarray:
    """Points (n, 3) in the robot's base frame → the instrument's frame of the slot values ``params``."""
    T = base_transform(chain, params)
    return np.asarray(p_mm, float) @ T[:3, :3].T + T[:3, 3]


def initial_base(chain, params, q, target_mm) -> np.ndarray:
    """``params`` with the base slots from a rigid fit (Kabsch) of the model's tool points at ``q`` (n, nq) to
    ``target_mm`` (n, 3): the start of a fit whose instrument may stand anywhere."""
    from .identification import rigid_fit
    ets, idx = base_slot_ets(chain)
    T_old = base_transform(chain, params)
    R, t = rigid_fit(chain.tool_point(q, params)[None], np.asarray(target_mm, float)[None])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R[0], t[0]
    T_new = T @ T_old
    Rn = T_new[:3, :3]
    new = np.concatenate([T_new[:3, 3], [np.arctan2(Rn[1, 0], Rn[0, 0]), -np.arcsin(np.clip(Rn[2, 0], -1, 1)),
                                         np.arctan2(Rn[2, 1], Rn[2, 2])]])
    out = np.array(params, float).copy()
    out[idx] = (new - np.array([e.value for e in ets])) / np.array([e.coef for e in ets])
    return out


def placed_start(chain, q, target_mm) -> np.ndarray:
    """The start (n_params,) of a calibration: the nominal chain placed on the measured points by a rigid fit of its
    base (every other slot 0); zeros for a chain without base slots."""
    x0 = np.zeros(chain.n_params)
    return initial_base(chain, x0, q, target_mm) if has_base_slots(chain) else x0
