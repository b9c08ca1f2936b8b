"""The grinder's spatial error from its 23 elements by homogeneous transforms.

Where each element enters (every error transform is ``Trans(δ)·Rot(ε)`` with
``Rot(ε) = RotX(εx)·RotY(εy)·RotZ(εz)``, applied right after the nominal motion of its body,
at the body's reference point)::

    T_tool = RotZ(θ1)·Trans(l2,0,l1)·Trans(RotZ(-θ1)·z·(sin s_xz, 0, cos s_xz))
             ·E_z(z)·Trans(l3,0,l4)·Trans(0,0,-R)
             E_z = Trans(dx_z, dy_z, dz_z)·Rot(ex_z, ey_z, ez_z)        (Z carriage, frame {1-2})
    T_work = Trans(l5,0,l6)·Trans(x,0,0)·E_x(x)·Trans(l7,0,l8)·E_oa·RotX(a)·E_a(a)
             E_x  = Trans(dx_x, dy_x, dz_x)·Rot(ex_x, ey_x, ez_x)       (X carriage)
             E_oa = Trans(0, dy_oa, dz_oa)·Rot(0, ey_oa, ez_oa)          (A-axis line, before the rotation)
             E_a  = Trans(dx_a, dy_a, dz_a)·Rot(ex_a, ey_a, ez_a)       (A body, in the rotating frame)

Squareness ``s_xz`` tilts the Z direction about the machine Y axis (towards +X).
The spatial error is the actual tool point minus the nominal tool point, both in the
workpiece frame (WCS), in μm. Translations enter in μm, angles in μrad.

The first-order (small-error) form is linear in the elements: ``e ≈ J(axes) · v`` where
``J`` (shape (n, 3, 23), μm per μm or μm per μrad) is the error-transfer Jacobian.
"""
from __future__ import annotations

import numpy as np

from .elements import ELEMENT_NAMES, ElementSet
from .machine import Grinder
from .transforms import apply, apply_T, check_points, rot_x, rot_xyz, rot_z, skew

UM = 1e-3   # mm per μm
URAD = 1e-6  # rad per μrad
IDX = {k: i for i, k in enumerate(ELEMENT_NAMES)}


def _split(values):
    v = np.asarray(values, dtype=float)
    def g(*names):
        return np.stack([v[:, IDX[k]] for k in names], axis=1)
    zeros = np.zeros(v.shape[0])
    return {
        "d_x": g("dx_x", "dy_x", "dz_x") * UM, "e_x": g("ex_x", "ey_x", "ez_x") * URAD,
        "d_z": g("dx_z", "dy_z", "dz_z") * UM, "e_z": g("ex_z", "ey_z", "ez_z") * URAD,
        "d_a": g("dx_a", "dy_a", "dz_a") * UM, "e_a": g("ex_a", "ey_a", "ez_a") * URAD,
        "d_oa": np.stack([zeros, v[:, IDX["dy_oa"]], v[:, IDX["dz_oa"]]], axis=1) * UM,
        "e_oa": np.stack([zeros, v[:, IDX["ey_oa"]], v[:, IDX["ez_oa"]]], axis=1) * URAD,
        "s": v[:, IDX["s_xz"]] * URAD,
    }


def tool_point_actual(machine: Grinder, axes, values) -> np.ndarray:
    """Actual tool point in the WCS (mm) with exact transforms.

    ``axes`` shape (n, 3) (x_mm, z_mm, a_deg); ``values`` shape (n, 23) element values
    at those axes (μm / μrad, ELEMENT_NAMES order). Returns shape (n, 3).
    """
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    e = _split(values)
    x, z, a = axes[:, 0], axes[:, 1], np.deg2rad(axes[:, 2])
    th = rot_z(np.deg2rad(machine.theta1_deg))[0]
    # tool chain, in the frame after RotZ(θ1)
    sq_in_mcs = np.stack([z * np.sin(e["s"]), np.zeros_like(z), z * np.cos(e["s"])], axis=1)
    sq_local = apply_T(th, sq_in_mcs)
    b = np.array([machine.l3, 0.0, machine.l4 - machine.R])
    local = np.array([machine.l2, 0.0, machine.l1]) + sq_local + e["d_z"] + apply(rot_xyz(e["e_z"]), np.broadcast_to(b, z.shape + (3,)))
    t = apply(th, local)
    # work chain inverse
    q = t - np.stack([machine.l5 + x, np.zeros_like(x), np.full_like(x, machine.l6)], axis=1)
    q = apply_T(rot_xyz(e["e_x"]), q - e["d_x"])
    q = q - np.array([machine.l7, 0.0, machine.l8])
    q = apply_T(rot_xyz(e["e_oa"]), q - e["d_oa"])
    q = apply_T(rot_x(a), q)
    return apply_T(rot_xyz(e["e_a"]), q - e["d_a"])


def nominal_frames(machine: Grinder, axes):
    """Intermediate nominal quantities shared by the first-order form and the Jacobian."""
    from .kinematics import forward, tool_in_machine_nominal
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    x, z, a = axes[:, 0], axes[:, 1], np.deg2rad(axes[:, 2])
    t = tool_in_machine_nominal(machine, z)
    q0 = t - np.stack([machine.l5 + x, np.zeros_like(x), np.full_like(x, machine.l6)], axis=1)
    q2 = q0 - np.array([machine.l7, 0.0, machine.l8])
    Ra = np.transpose(rot_x(a), (0, 2, 1))  # RotX(-a)
    return {"z": z, "q0": q0, "q2": q2, "Ra": Ra, "p": forward(machine, axes),
            "th": rot_z(np.deg2rad(machine.theta1_deg))[0],
            "b": np.array([machine.l3, 0.0, machine.l4 - machine.R])}


def error_jacobian(machine: Grinder, axes) -> np.ndarray:
    """Error-transfer Jacobian ∂(spatial error μm)/∂(element value), shape (n, 3, 23).

    Columns in ELEMENT_NAMES order; translation columns are μm/μm, angle columns μm/μrad.
    Derived from ``E⁻¹·q ≈ q - δ - ε×q``::

        dp = RotX(-a)·[RotZ(θ1)(δ_z + ε_z×b) + (s·z, 0, 0) - δ_x - ε_x×q0 - δ_oa - ε_oa×q2] - δ_a - ε_a×p
    """
    f = nominal_frames(machine, axes)
    n = f["z"].shape[0]
    Ra, th = f["Ra"], f["th"]
    J = np.zeros((n, 3, len(ELEMENT_NAMES)))
    RaTh = Ra @ th
    J[:, :, [IDX[k] for k in ("dx_z", "dy_z", "dz_z")]] = RaTh
    J[:, :, [IDX[k] for k in ("ex_z", "ey_z", "ez_z")]] = -(RaTh @ skew(f["b"])) * (URAD / UM)
    J[:, :, IDX["s_xz"]] = Ra[:, :, 0] * f["z"][:, None] * (URAD / UM)
    J[:, :, [IDX[k] for k in ("dx_x", "dy_x", "dz_x")]] = -Ra
    J[:, :, [IDX[k] for k in ("ex_x", "ey_x", "ez_x")]] = (Ra @ skew(f["q0"])) * (URAD / UM)
    J[:, :, IDX["dy_oa"]] = -Ra[:, :, 1]
    J[:, :, IDX["dz_oa"]] = -Ra[:, :, 2]
    RaQ2 = (Ra @ skew(f["q2"])) * (URAD / UM)
    J[:, :, IDX["ey_oa"]] = RaQ2[:, :, 1]
    J[:, :, IDX["ez_oa"]] = RaQ2[:, :, 2]
    J[:, :, [IDX[k] for k in ("dx_a", "dy_a", "dz_a")]] = -np.eye(3)
    J[:, :, [IDX[k] for k in ("ex_a", "ey_a", "ez_a")]] = skew(f["p"]) * (URAD / UM)
    return J


def spatial_error_exact(machine: Grinder, axes, values, chunk: int = 50_000) -> np.ndarray:
    """Spatial error (μm) with exact transforms; ``values`` shape (n, 23) -> (n, 3).

    Works in chunks of ``chunk`` points to bound peak memory.
    """
    from .kinematics import forward
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    values = np.asarray(values, dtype=float)
    out = np.empty((axes.shape[0], 3))
    for s in range(0, axes.shape[0], chunk):
        sl = slice(s, s + chunk)
        out[sl] = (tool_point_actual(machine, axes[sl], values[sl]) - forward(machine, axes[sl])) / UM
    return out


def spatial_error_first_order(machine: Grinder, axes, values) -> np.ndarray:
    """Spatial error (μm) in the first-order form ``J · v``; shapes as the exact form."""
    return np.einsum("nij,nj->ni", error_jacobian(machine, axes), np.asarray(values, dtype=float))


class HTMField:
    """The 23-element homogeneous-transform model as an error field.

    ``predict(axes)`` maps axes (x_mm, z_mm, a_deg), shape (n, 3), to the spatial
    error (dx_um, dy_um, dz_um), shape (n, 3). ``exact=False`` uses the first-order form.
    """

    kind = "htm"

    def __init__(self, machine: Grinder, elements: ElementSet, exact: bool = True, chunk: int = 50_000):
        self.machine = machine
        self.elements = elements
        self.exact = exact
        self.chunk = chunk

    def element_values(self, axes) -> np.ndarray:
        """The 23 element values at ``axes``, shape (n, 23)."""
        return self.elements.values(check_points(axes, "axes (x_mm, z_mm, a_deg)"))

    def predict(self, axes) -> np.ndarray:
        axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
        out = np.empty((axes.shape[0], 3))
        for s in range(0, axes.shape[0], self.chunk):
            sl = slice(s, s + self.chunk)
            v = self.elements.values(axes[sl])
            if self.exact:
                out[sl] = spatial_error_exact(self.machine, axes[sl], v, chunk=self.chunk)
            else:
                out[sl] = spatial_error_first_order(self.machine, axes[sl], v)
        return out

    __call__ = predict
