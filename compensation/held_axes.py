"""Axes held at a machine position (``G53``): passed through unchanged, the other axes compensated.

A ``G53`` line moves its axes in machine coordinates (Fusion 360's ``G53 G0 Z0.``: Z to the top of its
stroke). Machine coordinates are not the part's: until the program gives such an axis again in work
coordinates, every move leaves it where the ``G53`` line put it, and the compensated program does too (no
word is written for it; the controller keeps it at that machine value, as programmed). The moves' other
axes are compensated with that axis held: as a lathe's spindle C is held in turning mode
(:mod:`compensation.turning`), the solved axes of :func:`compensation.solvers.chain_exact.solved_and_kept`
less the held ones move, by Gauss-Newton on the tool point

    min over the free axes of | fwd(q) + 1e-3·E(q) − p_d |     (mm; q's held axes at their machine value)

with the chain's kinematic Jacobian (the field's own slope, ~1e-5, only slows convergence). What is left is
the model's error along the held axis (the tool point's direction of that axis): it is reported
(:func:`held_summary`), never hidden.
"""
from __future__ import annotations

import numpy as np

MAX_ITER = 20
STEP_TOL_MM = 1e-9
"""A point stops when its largest step is below this (1e-6 μm; the exact solver's tolerance is 1e-4 μm)."""


def held_moves(program) -> np.ndarray:
    """Per compensated move of ``program`` (in order), its axes (bool (c, k), the reader's axis order) whose
    value a ``G53`` line set and no move gave since in work coordinates."""
    words = program.axis_words.words
    g53 = {e[0]: set(e[3]) for e in program.events if e[2] == "g53"}
    held, out = set(), []
    moves = {m.index: m for m in program.moves}
    for i in sorted(set(g53) | set(moves)):
        if i in g53:
            held |= g53[i] & set(words)
            continue
        m = moves[i]
        held -= set(m.words)
        if m.compensate:
            out.append([a in held for a in words])
    return np.array(out, dtype=bool).reshape(len(out), len(words))


def held_points(tp, k: int) -> np.ndarray | None:
    """Per point of a G-code tool path ``tp`` (bool (n, k), the machine's axis order): the axes held at a
    ``G53`` value; None where none is (or for a CSV path)."""
    if getattr(tp, "kind", None) != "gcode" or not any(e[2] == "g53" for e in tp.source.program.events):
        return None
    per_move = held_moves(tp.source.program)
    out = np.zeros((len(tp.axes), k), dtype=bool)
    out[:, list(tp.columns)] = np.repeat(per_move, np.asarray(tp.source.counts, dtype=int), axis=0)
    return out if out.any() else None


def solve_held(field, machine, result, targets, axes_d, held):
    """``result`` (a :class:`~compensation.solvers.base.SolveResult` of ``targets`` (n, 3) mm from ``axes_d``
    (n, k)) with its points that hold axes (``held`` (n, k) bool) solved again with those axes at ``axes_d``
    and the others of the solved axes free (module docstring); ``info["held"]`` says how many and what is left
    along the held axes (μm, model)."""
    from errormap.chain_kernel import NominalChain

    from .solvers.chain_exact import solved_and_kept
    chain = NominalChain(machine)
    sol, _ = solved_and_kept(machine, chain)
    axes, residual = np.array(result.axes, dtype=float), np.array(result.residual_um, dtype=float)
    success, along = np.array(result.success, dtype=bool), np.zeros(len(targets))
    for key in np.unique(held[:, sol], axis=0):
        if not key.any():
            continue
        idx = np.flatnonzero((held[:, sol] == key).all(axis=1))
        free, fixed = sol[~key], sol[key]
        q = axes[idx].copy()
        q[:, fixed] = axes_d[idx][:, fixed]
        q, F, conv, J = _gauss_newton(field, chain, q, targets[idx], free)
        d = J[:, :, fixed] / np.linalg.norm(J[:, :, fixed], axis=1, keepdims=True)  # (m, 3, h) held directions
        axes[idx], residual[idx] = q, 1e3 * F
        along[idx] = np.abs(np.einsum("mi,mih->mh", 1e3 * F, d)).max(axis=1)
        success[idx] &= conv
    commands = chain.forward_and_jacobian(axes, jac=False)[0]
    h = held[:, sol].any(axis=1)
    result.axes, result.residual_um, result.commands_mm = axes, residual, commands
    result.correction_um = 1e3 * np.linalg.norm(commands - targets, axis=1)
    result.success = success
    names = machine.axis_words
    result.info = dict(result.info or {}, held={
        "points": int(h.sum()), "axes": [names[j] for j in sol if held[:, j].any()],
        "along_held_max_um": float(along[h].max()) if h.any() else 0.0,
        "residual": "model: the tool point's error along the held axis, left as the G53 line put it (um)"})
    return result


def _gauss_newton(field, chain, q, targets, free):
    """``(q (m, k), F (m, 3) mm, converged (m,), J (m, 3, k))``: the free axes moved to least |F|,
    F = fwd + 1e-3·E − p_d; J the chain's Jacobian at the returned q."""
    conv = np.zeros(len(q), dtype=bool)
    for _ in range(MAX_ITER):
        P, J = chain.forward_and_jacobian(q)
        F = P + 1e-3 * np.asarray(field.predict(q), dtype=float) - targets
        A = J[:, :, free]
        step = np.linalg.solve(np.einsum("mif,mig->mfg", A, A), np.einsum("mif,mi->mf", A, F)[..., None])[..., 0]
        q[:, free] -= step
        conv = np.abs(step).max(axis=1) <= STEP_TOL_MM
        if conv.all():
            break
    P, J = chain.forward_and_jacobian(q)
    return q, P + 1e-3 * np.asarray(field.predict(q), dtype=float) - targets, conv, J


def merge_held(parts) -> dict:
    """One ``info["held"]`` of the per-tool parts of a file (None where a part held nothing)."""
    parts = [p for p in parts if p and p["points"]]
    if not parts:
        return {"points": 0, "axes": [], "along_held_max_um": 0.0}
    return dict(parts[0], points=sum(p["points"] for p in parts),
                axes=sorted({a for p in parts for a in p["axes"]}),
                along_held_max_um=max(p["along_held_max_um"] for p in parts))


def held_to_write(tp, axes) -> np.ndarray | None:
    """Per compensated move of the G-code path ``tp`` (bool (c, k_program)): the axes to leave unwritten, those held at
    a ``G53`` value on every point of the move and still there in the solved ``axes`` (n, k) (a later pass that moved
    them, e.g. the tool orientation's, gets them written); None where none is."""
    held = held_points(tp, axes.shape[1])
    if held is None:
        return None
    kept = held & (np.asarray(axes) == tp.axes)
    counts = np.asarray(tp.source.counts, dtype=int)
    per_move = np.repeat(counts[:, None] > 0, kept.shape[1], axis=1)
    np.logical_and.at(per_move, np.repeat(np.arange(len(counts)), counts), kept)
    out = per_move[:, list(tp.columns)]
    return out if out.any() else None
