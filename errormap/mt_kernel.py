"""The compiled (numba) field kernel of any machine-tool chain, generic over the compiled op arrays.

One pass per point: the component errors from one vector-valued cubic B-spline per axis (the
same knots and coefficients as :meth:`errormap.mt_elements.ChainElementSet.axis_spline`, basis
by the Cox–de Boor recursion of :mod:`errormap.htm`), then the chain's ETs applied one by one to
a running rotation ``R`` (3×3) and origin ``t`` (3,), for the actual chain (with the errors) and
the nominal one (ETs that carry neither a joint nor a constant are skipped there: they are the
identity without errors). With the Jacobian every quantity carries its derivatives along the k
axes (forward mode, exact: no step, no truncation). Checked against the numpy reference
:mod:`errormap.mt_field` in ``tests/test_mt_kernel.py``.

Shapes: ``axes`` (n, k); ``out`` (n, 3) μm; ``jac`` (n, 3, k) μm per mm / per deg.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .htm import _bspline3, _bspline3_d
from .mt_chain import UM_MM, MachineTool
from .mt_elements import ChainElementSet

NCOMP = 6  # columns of a spline block (dx dy dz ex ey ez; absent components padded with zeros)


@njit(cache=True, nogil=True, error_model="numpy")
def _chain_point(q, ev, kind_r, eaxis, value, joint, jscale, slot, coef, use, R, t):  # pragma: no cover - compiled
    """The chain at one point (values only): ``R`` (3, 3), ``t`` (3,) set to the last frame.
    ``ev`` (P,) slot values (or None-like zero-size for nominal: ``slot`` ignored when ev.size == 0);
    ``use`` (m,) which ETs to apply."""
    for i in range(3):
        t[i] = 0.0
        for j in range(3):
            R[i, j] = 1.0 if i == j else 0.0
    has_e = ev.shape[0] > 0
    for m in range(kind_r.shape[0]):
        if not use[m]:
            continue
        x = value[m]
        if joint[m] >= 0:
            x += jscale[m] * q[joint[m]]
        if has_e and slot[m] >= 0:
            x += coef[m] * ev[slot[m]]
        a = eaxis[m]
        if kind_r[m]:
            b = (a + 1) % 3
            c = (a + 2) % 3
            cs, sn = np.cos(x), np.sin(x)
            for i in range(3):
                rb, rc = R[i, b], R[i, c]
                R[i, b] = rb * cs + rc * sn
                R[i, c] = rc * cs - rb * sn
        else:
            for i in range(3):
                t[i] += R[i, a] * x


@njit(cache=True, nogil=True, error_model="numpy")
def _chain_point_d(q, ev, dev, kind_r, eaxis, value, joint, jscale, slot, coef, use, own, R, t, dR, dt, dx):  # pragma: no cover - compiled
    """:func:`_chain_point` with derivatives along the k axes: ``dR`` (k, 3, 3), ``dt`` (k, 3);
    ``dev`` (P,) d(slot)/d(own axis), ``own`` (P,) the axis column of each slot (-1: constant);
    ``dx`` (k,) work array."""
    k = q.shape[0]
    for i in range(3):
        t[i] = 0.0
        for j in range(3):
            R[i, j] = 1.0 if i == j else 0.0
    for j in range(k):
        for i in range(3):
            dt[j, i] = 0.0
            for l in range(3):
                dR[j, i, l] = 0.0
    has_e = ev.shape[0] > 0
    for m in range(kind_r.shape[0]):
        if not use[m]:
            continue
        x = value[m]
        moving = False
        for j in range(k):
            dx[j] = 0.0
        if joint[m] >= 0:
            x += jscale[m] * q[joint[m]]
            dx[joint[m]] += jscale[m]
            moving = True
        if has_e and slot[m] >= 0:
            p = slot[m]
            x += coef[m] * ev[p]
            if own[p] >= 0:
                dx[own[p]] += coef[m] * dev[p]
                moving = True
        a = eaxis[m]
        if kind_r[m]:
            b = (a + 1) % 3
            c = (a + 2) % 3
            cs, sn = np.cos(x), np.sin(x)
            for i in range(3):
                rb, rc = R[i, b], R[i, c]
                nb = rb * cs + rc * sn
                nc = rc * cs - rb * sn
                for j in range(k):
                    drb, drc = dR[j, i, b], dR[j, i, c]
                    dR[j, i, b] = drb * cs + drc * sn + nc * dx[j]
                    dR[j, i, c] = drc * cs - drb * sn - nb * dx[j]
                R[i, b] = nb
                R[i, c] = nc
        else:
            for i in range(3):
                for j in range(k):
                    dt[j, i] += dR[j, i, a] * x
                    if moving:
                        dt[j, i] += R[i, a] * dx[j]
                t[i] += R[i, a] * x


@njit(cache=True, nogil=True, error_model="numpy")
def _slot_values(q, spl_axis, spl_s0, knots, koff, coefs, coff, spl_slot, consts, ev, dev, vbuf, dbuf, h, hh, deriv):  # pragma: no cover - compiled
    """The slot values ``ev`` (P,) (and slopes ``dev`` when ``deriv``) at one point from the
    per-axis splines (``spl_s0`` the first station of a full-turn axis, NaN otherwise)."""
    for p in range(ev.shape[0]):
        ev[p] = consts[p]
        dev[p] = 0.0
    for s in range(spl_axis.shape[0]):
        x = q[spl_axis[s]]
        s0 = spl_s0[s]
        if not np.isnan(s0):
            x = s0 + np.mod(x - s0, 360.0)
        tk = knots[koff[s]:koff[s + 1]]
        c = coefs[coff[s]:coff[s + 1]]
        if deriv:
            _bspline3_d(tk, c, x, h, hh, vbuf, dbuf, 0)
        else:
            _bspline3(tk, c, x, h, hh, vbuf, 0)
        for col in range(6):
            p = spl_slot[s, col]
            if p >= 0:
                ev[p] = vbuf[col]
                if deriv:
                    dev[p] = dbuf[col]


@njit(cache=True, nogil=True, error_model="numpy")
def field_kernel(axes, ops, use_nom, spl, consts, out):  # pragma: no cover - compiled
    """Spatial error (μm) at every point: ``out`` (n, 3)."""
    kind_r, eaxis, value, joint, jscale, slot, coef, use_act = ops
    spl_axis, spl_s0, knots, koff, coefs, coff, spl_slot = spl
    P = consts.shape[0]
    ev = np.empty(P)
    dev = np.empty(P)
    none = np.empty(0)
    vbuf = np.empty(6)
    dbuf = np.empty(6)
    h = np.empty(4)
    hh = np.empty(4)
    R = np.empty((3, 3))
    t = np.empty(3)
    R0 = np.empty((3, 3))
    t0 = np.empty(3)
    for n in range(axes.shape[0]):
        q = axes[n]
        _slot_values(q, spl_axis, spl_s0, knots, koff, coefs, coff, spl_slot, consts, ev, dev, vbuf, dbuf, h, hh, False)
        _chain_point(q, ev, kind_r, eaxis, value, joint, jscale, slot, coef, use_act, R, t)
        _chain_point(q, none, kind_r, eaxis, value, joint, jscale, slot, coef, use_nom, R0, t0)
        for i in range(3):
            out[n, i] = (t[i] - t0[i]) * 1e3


@njit(cache=True, nogil=True, error_model="numpy")
def field_jac_kernel(axes, ops, use_nom, spl, consts, own, out, jac):  # pragma: no cover - compiled
    """Spatial error (μm) and dE/d(axes): ``out`` (n, 3), ``jac`` (n, 3, k)."""
    kind_r, eaxis, value, joint, jscale, slot, coef, use_act = ops
    spl_axis, spl_s0, knots, koff, coefs, coff, spl_slot = spl
    P = consts.shape[0]
    k = axes.shape[1]
    ev = np.empty(P)
    dev = np.empty(P)
    none = np.empty(0)
    vbuf = np.empty(6)
    dbuf = np.empty(6)
    h = np.empty(4)
    hh = np.empty(4)
    R = np.empty((3, 3))
    t = np.empty(3)
    R0 = np.empty((3, 3))
    t0 = np.empty(3)
    dR = np.empty((k, 3, 3))
    dt = np.empty((k, 3))
    dR0 = np.empty((k, 3, 3))
    dt0 = np.empty((k, 3))
    dx = np.empty(k)
    for n in range(axes.shape[0]):
        q = axes[n]
        _slot_values(q, spl_axis, spl_s0, knots, koff, coefs, coff, spl_slot, consts, ev, dev, vbuf, dbuf, h, hh, True)
        _chain_point_d(q, ev, dev, kind_r, eaxis, value, joint, jscale, slot, coef, use_act, own, R, t, dR, dt, dx)
        _chain_point_d(q, none, dev, kind_r, eaxis, value, joint, jscale, slot, coef, use_nom, own, R0, t0, dR0, dt0, dx)
        for i in range(3):
            out[n, i] = (t[i] - t0[i]) * 1e3
            for j in range(k):
                jac[n, i, j] = (dt[j, i] - dt0[j, i]) * 1e3


class CompiledChain:
    """The op arrays of a machine's chain and the spline arrays of an element set, packed once
    for the kernels. ``predict(axes)`` (n, 3) μm; ``predict_and_jacobian(axes)``."""

    def __init__(self, machine: MachineTool, elements: ChainElementSet):
        ch = machine.chain
        scale = np.array([np.pi / 180 if j.type == "revolute" else 1.0 for j in ch.joints])
        jscale = np.where(ch.joint >= 0, ch.sign * scale[np.maximum(ch.joint, 0)], 0.0)
        use_act = np.ones(len(ch.ets), dtype=np.bool_)
        self.ops = (ch.kind_r.astype(np.bool_), ch.axis.astype(np.int64), ch.value.astype(float),
                    ch.joint.astype(np.int64), jscale, ch.slot.astype(np.int64), ch.coef.astype(float), use_act)
        self.use_nom = (ch.joint >= 0) | (ch.value != 0.0)
        col = {a.word: j for j, a in enumerate(machine.axes)}
        self.own = np.array([col[s.axis] if s.is_function else -1 for s in machine.slots], dtype=np.int64)
        idx = {n: p for p, n in enumerate(machine.slot_names)}
        spl_axis, spl_s0, knots, coefs, spl_slot = [], [], [], [], []
        for j, a in enumerate(machine.axes):
            names = machine.slots_of(a.word)
            if not names:
                continue
            sp = elements.axis_spline(a.word)
            c = np.zeros((sp.c.shape[0], NCOMP))
            c[:, :len(names)] = sp.c
            row = np.full(NCOMP, -1, dtype=np.int64)
            row[:len(names)] = [idx[k] for k in names]
            spl_axis.append(j)
            spl_s0.append(float(elements.stations[a.column][0]) if a.full_turn else np.nan)
            knots.append(np.asarray(sp.t, dtype=float))
            coefs.append(c)
            spl_slot.append(row)
        koff = np.cumsum([0] + [len(t) for t in knots]).astype(np.int64)
        coff = np.cumsum([0] + [len(c) for c in coefs]).astype(np.int64)
        self.spl = (np.array(spl_axis, dtype=np.int64), np.array(spl_s0, dtype=float),
                    np.concatenate(knots) if knots else np.zeros(0), koff,
                    np.ascontiguousarray(np.concatenate(coefs)) if coefs else np.zeros((0, NCOMP)), coff,
                    np.array(spl_slot, dtype=np.int64).reshape(-1, NCOMP))
        self.consts = np.zeros(len(machine.slots))
        for k, v in elements.constants.items():
            self.consts[idx[k]] = v
        self.k = len(machine.axes)

    def predict(self, axes) -> np.ndarray:
        axes = np.ascontiguousarray(axes, dtype=float)
        out = np.empty((axes.shape[0], 3))
        field_kernel(axes, self.ops, self.use_nom, self.spl, self.consts, out)
        return out

    def predict_and_jacobian(self, axes):
        axes = np.ascontiguousarray(axes, dtype=float)
        out = np.empty((axes.shape[0], 3))
        jac = np.empty((axes.shape[0], 3, self.k))
        field_jac_kernel(axes, self.ops, self.use_nom, self.spl, self.consts, self.own, out, jac)
        return out, jac


assert UM_MM == 1e-3, "the kernels write mm → μm as * 1e3"
