"""The batched GA's fitness through the network as one float32 torch pipeline.

The ``offset_fitness`` capability of :class:`training.model.MLPField` (:mod:`errormap.field`): for WCS
targets ``p_d`` and offsets ``d`` (μm) the fitness is ``-|d + E(IK(p_d + 1e-3·d))|²`` (μm²), the nominal
inverse kinematics and the network run on columns, no round trip through numpy between them (float32 is
ample: the field's float32 error ~1e-4 μm against the GA's ~0.01 μm resolution; the solver recomputes
commands and residuals in float64). IK: the closed-form inverse of a chain whose nominal tool point is ``p =
(c_x - q0, Rot_x(-q2)·(t_y, c_h + q1))`` (the X-Z-A grinder's form), its constants read and its form checked
on the machine's chain (:func:`closed_form_constants`); a machine of another form is refused. The
derivation: docs/explanation/solvers.md."""
from __future__ import annotations

import math

import numpy as np
import torch

from errormap.chain_kernel import NominalChain

MM_PER_UM = 1e-3
CLOSED_FORM_TOL_MM = 1e-9
"""Largest difference between the chain's nominal tool point and the closed form at the check
points for the form to hold: round-off of the chain's ~500 mm sums is ~1e-13 mm, a real
difference of form is millimetres."""
CHECK_A_DEG = (-450.0, -90.0, 0.0, 37.0, 200.0, 719.0)
"""Rotary-axis values of the check points (several turns, both signs)."""


def closed_form_constants(machine) -> tuple[float, float, float]:
    """``(c_x, t_y, c_h)`` of the fused kernel's closed-form inverse, from the machine's chain.

    The nominal tool point at zero axes is ``(c_x, t_y, c_h)`` for a chain of the form
    ``p = (c_x - q0, Rot_x(-q2)·(t_y, c_h + q1))``; the form is checked against the chain at a
    grid of axes (the linear strokes' ends and middle × :data:`CHECK_A_DEG`) to
    :data:`CLOSED_FORM_TOL_MM`. ValueError for a machine whose chain has another form.
    """
    chain = NominalChain(machine)
    if chain.k != 3 or chain.kinds != ("linear", "linear", "rotary"):
        raise ValueError(f"the fused GA fitness inverts a chain of two linear axes and a rotary one; "
                         f"{chain.machine_tool.name!r} has {', '.join(chain.columns)}")
    cx, ty, ch = (float(v) for v in chain.forward(np.zeros((1, 3)))[0])
    mt = chain.machine_tool
    lo, hi = mt.stroke_lo, mt.stroke_hi
    g = np.array(np.meshgrid([lo[0], 0.5 * (lo[0] + hi[0]), hi[0]], [lo[1], 0.5 * (lo[1] + hi[1]), hi[1]],
                             CHECK_A_DEG, indexing="ij")).reshape(3, -1).T
    a = np.deg2rad(g[:, 2])
    h = ch + g[:, 1]
    closed = np.column_stack([cx - g[:, 0], np.cos(a) * ty + np.sin(a) * h, np.cos(a) * h - np.sin(a) * ty])
    miss = float(np.abs(chain.forward(g) - closed).max())
    if not miss <= CLOSED_FORM_TOL_MM:
        raise ValueError(f"the fused GA fitness's closed-form inverse does not fit the chain of {mt.name!r} "
                         f"(off by {miss:.3g} mm at the check points); use the generic fitness (fused=False)")
    return cx, ty, ch


class FusedOffsetFitness:
    """``fitness(points (k,) int64, offsets_um (3, k) float32) -> (k,) float32`` for fixed targets.

    ``targets_mm`` shape (n, 3) WCS mm; ``points`` index into them. ``threads``: torch's
    thread count when built (one call's own parallelism, the batched GA's default workers).
    Building it also builds the network's float32 weights, so calls from several threads at
    once share them.
    """

    BLOCK = 16_384
    """Offspring per network call (each layer's activations stay in cache)."""

    def __init__(self, field, machine, targets_mm):
        self.field = field
        self.cx, self.ty, self.ch = closed_form_constants(machine)
        targets = np.asarray(targets_mm, dtype=float)
        # per-point constants; x in float64 first (c_x - p_x), then float32
        self.x = torch.from_numpy((self.cx - targets[:, 0]).astype(np.float32))
        self.py = torch.from_numpy(targets[:, 1].astype(np.float32))
        self.pz = torch.from_numpy(targets[:, 2].astype(np.float32))
        field.predict_columns(torch.zeros((3, 1), dtype=torch.float32))  # builds the float32 net once
        self.threads = torch.get_num_threads()

    def __call__(self, pts: np.ndarray, dT: np.ndarray) -> np.ndarray:
        """Fitness of offsets ``dT`` (3, k) μm (columns) of points ``pts`` (k,); returns (k,) float32."""
        k = dT.shape[1]
        out = np.empty(k, dtype=np.float32)
        pts_t, d_t, out_t = torch.from_numpy(pts), torch.from_numpy(dT), torch.from_numpy(out)
        with torch.inference_mode():
            for s in range(0, k, self.BLOCK):
                out_t[s:s + self.BLOCK] = self._block(pts_t[s:s + self.BLOCK], d_t[:, s:s + self.BLOCK])
        return out

    def _block(self, pts, dT):
        """One block through the closed-form inverse: ``x = c_x - p_x``, ``h = sqrt(p_y² + p_z² - t_y²)``,
        ``z = h - c_h``, ``a = atan2(p_y, p_z) - atan2(t_y, h)`` (deg), then the network."""
        dm = dT * MM_PER_UM  # (3, k) mm
        xa = torch.empty_like(dT)
        torch.sub(self.x[pts], dm[0], out=xa[0])
        py = self.py[pts] + dm[1]
        pz = self.pz[pts] + dm[2]
        h = torch.sqrt(torch.clamp(py * py + pz * pz - self.ty * self.ty, min=0.0))
        torch.sub(h, self.ch, out=xa[1])
        a = torch.atan2(py, pz)
        if self.ty != 0.0:
            a -= torch.atan2(torch.full_like(h, self.ty), h)
        torch.rad2deg(a, out=xa[2])  # predict_columns folds A into the field's turn
        r = self.field.predict_columns(xa)
        r += dT
        f = (r * r).sum(dim=0).neg_()
        return torch.where(torch.isnan(f), -math.inf, f)
