"""The readable numpy references the compiled chain kernel (errormap.chain_kernel, what ChainField computes
through) is tested against: the element values pushed through the chain's frames, op by op."""
from __future__ import annotations

import numpy as np

from errormap.chain_elements import ChainElementSet
from errormap.machine_tool import UM_MM, MachineTool

CHUNK = 4096  # points per numpy pass: the reference keeps (chunk, n_et + 1, 4, 4) frames


def predict_numpy(machine: MachineTool, elements: ChainElementSet, axes, chunk: int = CHUNK) -> np.ndarray:
    """Spatial error (μm), (n, k) -> (n, 3): element values pushed through the numpy chain."""
    axes = np.atleast_2d(np.asarray(axes, dtype=float))
    return machine.spatial_error(axes, elements.values(axes), chunk=chunk)


def predict_and_jacobian_numpy(machine: MachineTool, elements: ChainElementSet, axes, chunk: int = CHUNK):
    """``(E (n, 3) μm, dE/d(axes) (n, 3, k))`` by the numpy chain (the reference)."""
    axes = np.atleast_2d(np.asarray(axes, dtype=float))
    n, k = axes.shape
    E = np.empty((n, 3))
    J = np.empty((n, 3, k))
    ch = machine.chain
    col = {a.word: j for j, a in enumerate(machine.axes)}
    own = np.array([col[s.axis] if s.is_function else -1 for s in machine.slots])
    for s in range(0, n, chunk):
        q = axes[s:s + chunk]
        v = elements.values(q)
        dv = elements.slopes(q)
        F = ch.frames(q, v)
        F0 = ch.frames(q)
        E[s:s + chunk] = (F[:, -1, :3, 3] - F0[:, -1, :3, 3]) / UM_MM
        Jq = ch.joint_jacobian(q, v, frames=F) - ch.joint_jacobian(q, frames=F0)
        Je = ch.error_jacobian(q, v, frames=F)          # (m, 3, P) mm per μm/μrad
        for p in np.flatnonzero(own >= 0):
            Jq[:, :, own[p]] += Je[:, :, p] * dv[:, p, None]
        J[s:s + chunk] = Jq / UM_MM
    return E, J
