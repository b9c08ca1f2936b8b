"""A simulated arm for closed-loop checks: a truth chain with known link errors and a joint-stiffness
sag under gravity, measured by a tracker with noise. The truth stays here; estimators get only the
measured poses (:class:`errormap.arm_poses.ArmPoses`).

Sag: joint ``j`` turns by ``compliance_rad_per_mm[j] * M_j(q)``, ``M_j`` the gravity moment about its
axis of unit masses at the downstream joint origins and the tool point (mm, gravity along −z of the
base) — a non-geometric, configuration-dependent effect no link-parameter set reproduces.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arm_poses import ArmPoses
from .seeds import spawn_rngs

MOMENT_FD_STEP_DEG = 1e-3   # central difference of the gravity moments (a smooth trigonometric function of q):
# truncation ~ step² × the moment's third derivative ≈ 1e-10 of the moment, far below anything a fit or a GP input resolves


@dataclass
class ArmTruth:
    """``errors`` (n_params,) the true error-slot values; ``compliance_rad_per_mm`` (nq,);
    ``backlash_rad`` (nq,) or None: each joint's lost motion; gravity holds the gear on one flank,
    so the joint sits at ``±backlash/2`` by the sign of its gravity moment."""

    errors: np.ndarray
    compliance_rad_per_mm: np.ndarray
    backlash_rad: np.ndarray | None = None

    def joint_sag_deg(self, chain, q) -> np.ndarray:
        """Joint deflection under gravity (sag + backlash), deg (revolute) / mm, shape (n, nq)."""
        m = gravity_moment_mm(chain, q, self.errors)
        d = self.compliance_rad_per_mm * m
        if self.backlash_rad is not None:
            d = d + 0.5 * np.asarray(self.backlash_rad) * np.sign(m)
        return np.degrees(d)

    def tool_point(self, chain, q) -> np.ndarray:
        """True tool point at commanded joints ``q``, mm, (n, 3)."""
        return chain.tool_point(q + self.joint_sag_deg(chain, q), self.errors)

    def base_frame_point(self, chain, q) -> np.ndarray:
        """True tool point at ``q`` (n, 3) in the robot's TRUE base frame as calibration defines it: the frame after
        the base block once it has absorbed link 1's offsets about and along its axis (``link1.dtheta_rad``,
        ``link1.dd_mm``: the slots :func:`errormap.arm_calibration.identifiable_slots` holds at nominal, their effect
        being the base's). Standard-DH chains whose first joint is revolute (``Rz(θ + q) Tz(d) …`` after the base)."""
        from .arm_frames import base_transform, rot
        names = list(chain.param_names)
        k = [names.index(n) if n in names else None for n in ("link1.dtheta_rad", "link1.dd_mm")]
        if chain.convention != "dh" or chain.joints[0].type != "revolute" or None in k:
            raise ValueError(f"machine {chain.name!r}: the true base frame is defined here for standard-DH chains with "
                             "a revolute first joint only")
        G = np.eye(4)
        G[:3, :3] = rot(2, self.errors[k[0]])
        G[2, 3] = self.errors[k[1]]
        T = base_transform(chain, self.errors) @ G
        return (self.tool_point(chain, q) - T[:3, 3]) @ T[:3, :3]


def gravity_moment_mm(chain, q, errors=None) -> np.ndarray:
    """Per joint, the gravity moment of unit masses at the downstream joint origins and the tool point, (n, nq)."""
    F = chain.frames(q, errors)
    jets = [int(np.flatnonzero(chain.joint == j)[0]) for j in range(chain.n_joints)]
    org = np.stack([F[:, k, :3, 3] for k in jets] + [F[:, -1, :3, 3]], 1)
    axes = np.stack([F[:, k, :3, chain.axis[k]] for k in jets], 1)
    g = np.array([0.0, 0.0, -1.0])
    out = np.zeros((len(F), chain.n_joints))
    for j in range(chain.n_joints):
        out[:, j] = np.einsum("ni,nmi->n", axes[:, j], np.cross(org[:, j + 1:] - org[:, j:j + 1], g))
    return out


def gravity_moment_jacobian_mm(chain, q, errors=None) -> np.ndarray:
    """∂(gravity moments)/∂q of :func:`gravity_moment_mm` by central differences (step
    :data:`MOMENT_FD_STEP_DEG` in the joints' units), mm per joint unit, shape (n, nq, nq) ``[pose, moment, joint]``."""
    q = np.atleast_2d(np.asarray(q, float))
    n, nq = q.shape
    qs = np.repeat(q[None], 2 * nq, 0)
    for j in range(nq):
        qs[2 * j, :, j] += MOMENT_FD_STEP_DEG
        qs[2 * j + 1, :, j] -= MOMENT_FD_STEP_DEG
    m = gravity_moment_mm(chain, qs.reshape(-1, nq), errors).reshape(nq, 2, n, nq)
    return np.moveaxis((m[:, 0] - m[:, 1]) / (2 * MOMENT_FD_STEP_DEG), 0, 2)


def draw_truth(chain, seed, trans_sd_mm=0.2, rot_sd_rad=3e-4, base_sd_mm=2.0, base_sd_rad=2e-3,
               compliance_rad_per_mm=None, backlash_rad=None) -> ArmTruth:
    """Random link/base/tool errors (normal, the given SDs) and a joint compliance (default: 3e-8 rad
    per mm of gravity moment on every joint, about 0.1 mm of sag at a UR5's reach); ``backlash_rad``
    (nq,) lost motion per joint or None."""
    rng = spawn_rngs(seed, 1)[0]
    e = np.zeros(chain.n_params)
    for k, n in enumerate(chain.param_names):
        base = n.startswith("base.")
        e[k] = rng.normal(0, (base_sd_mm if base else trans_sd_mm) if n.endswith("_mm")
                          else (base_sd_rad if base else rot_sd_rad))
    c = np.full(chain.n_joints, 3e-8) if compliance_rad_per_mm is None else np.asarray(compliance_rad_per_mm, float)
    return ArmTruth(e, c, None if backlash_rad is None else np.asarray(backlash_rad, float))


def measure(chain, truth: ArmTruth, q, noise_mm, seed, source="simulated") -> ArmPoses:
    """Tracker measurements of the truth at commanded joints ``q`` with N(0, noise_mm²) per component."""
    rng = spawn_rngs(seed, 1)[0]
    xyz = truth.tool_point(chain, q) + rng.normal(0, noise_mm, (len(q), 3))
    return ArmPoses(np.asarray(q, float), xyz, None, None, None, np.arange(2, len(q) + 2), source, "schema")


def random_joints(lo_deg, hi_deg, n, seed) -> np.ndarray:
    """``n`` joint vectors uniform in the box [lo, hi] (per joint), shape (n, nq)."""
    rng = spawn_rngs(seed, 1)[0]
    return rng.uniform(lo_deg, hi_deg, (n, len(lo_deg)))
