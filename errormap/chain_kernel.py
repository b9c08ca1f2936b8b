"""The compiled (numba) field kernel of any machine-tool chain, generic over the compiled op arrays.

One pass per point: the component errors from one cubic B-spline per axis (scipy's operations on packed
arrays, :func:`_spline_at`), then the chain's ops on a running rotation and origin, for the actual and the
nominal chain. Packed once per field (:meth:`CompiledChain._program`): ETs that depend on a point stay single
ops, every run of constant ETs is folded into one block. The axis and the error-transfer Jacobians are
geometric and exact (:func:`_jacobian_columns`, :func:`error_jacobian`); checked against the numpy reference
:mod:`errormap.chain_field` in ``tests/test_chain_kernel.py``. Shapes: ``axes`` (n, k); ``out`` (n, 3) μm;
``jac`` (n, 3, k) μm per mm / per deg; error Jacobian (n, 3, P) μm per μm / per μrad."""
from __future__ import annotations

import numpy as np
from numba import njit

from .machine_tool import UM_MM, MachineTool, et_matrix
from .chain_elements import ChainElementSet

NCOMP = 6  # columns of a spline block (dx dy dz ex ey ez; absent components padded with zeros)


SMALL_ANGLE_RAD = 0.0009765625
"""Below this angle (2⁻¹⁰ rad) the kernels take cosine and sine from their Taylor series to x⁶ and
x⁷ (:func:`_cos_sin`): the next terms are below 1e-28 relative, so each is the exactly rounded value
up to the last rounding (equal to the library's bit for bit on the component errors' μrad angles,
tested), without a library call for each of the nine error rotations a point."""


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cos_sin(x):  # pragma: no cover - compiled
    """``(cos x, sin x)``; by their series for ``|x| <`` :data:`SMALL_ANGLE_RAD`."""
    if abs(x) < SMALL_ANGLE_RAD:
        x2 = x * x
        return (1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 - x2 * (1.0 / 720.0))),
                x + x * x2 * (-1.0 / 6.0 + x2 * (1.0 / 120.0 - x2 * (1.0 / 5040.0))))
    return np.cos(x), np.sin(x)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _chain_point(q, ev, kind, eaxis, value, joint, jscale, slot, coef, block, BR, Bt, R, t, W, O, record):  # pragma: no cover - compiled
    """A program (:meth:`CompiledChain._program`) at one point: ``R`` (3, 3), ``t`` (3,) set to the
    last frame; ``ev`` (P,) slot values. With ``record`` the axis ``W[o]`` and origin ``O[o]`` of
    every single-ET op are stored (the Jacobian's columns)."""
    for i in range(3):
        t[i] = 0.0
        for j in range(3):
            R[i, j] = 1.0 if i == j else 0.0
    for o in range(kind.shape[0]):
        k = kind[o]
        if k == 2:  # a constant block: t += R·Bt, R = R·BR
            bi = block[o]
            for i in range(3):
                r0, r1, r2 = R[i, 0], R[i, 1], R[i, 2]
                t[i] += r0 * Bt[bi, 0] + r1 * Bt[bi, 1] + r2 * Bt[bi, 2]
                for j in range(3):
                    R[i, j] = r0 * BR[bi, 0, j] + r1 * BR[bi, 1, j] + r2 * BR[bi, 2, j]
            continue
        a = eaxis[o]
        if record:
            for i in range(3):
                W[o, i] = R[i, a]
                O[o, i] = t[i]
        x = value[o]
        if joint[o] >= 0:
            x += jscale[o] * q[joint[o]]
        if slot[o] >= 0:
            x += coef[o] * ev[slot[o]]
        if k == 1:
            b = (a + 1) % 3
            c = (a + 2) % 3
            cs, sn = _cos_sin(x)
            for i in range(3):
                rb, rc = R[i, b], R[i, c]
                R[i, b] = rb * cs + rc * sn
                R[i, c] = rc * cs - rb * sn
        else:
            for i in range(3):
                t[i] += R[i, a] * x


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _column(kind_o, W, O, o, t):  # pragma: no cover - compiled
    """The tool point ``t``'s motion per unit value of op ``o``: its axis ``W[o]`` (translation) or
    ``W[o] × (t − O[o])`` (rotation about ``W[o]`` through ``O[o]``)."""
    if kind_o == 1:
        r0, r1, r2 = t[0] - O[o, 0], t[1] - O[o, 1], t[2] - O[o, 2]
        return W[o, 1] * r2 - W[o, 2] * r1, W[o, 2] * r0 - W[o, 0] * r2, W[o, 0] * r1 - W[o, 1] * r0
    return W[o, 0], W[o, 1], W[o, 2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _jacobian_columns(dev, kind, joint, jscale, slot, coef, own, t, W, O, jac_row, sgn):  # pragma: no cover - compiled
    """Adds ``sgn`` × d(tool point)/d(axes) to ``jac_row`` (3, k) after :func:`_chain_point` with
    ``record``. The Jacobian is geometric: an ET's value moves the tool point along its axis ``w``
    (translation) or by ``w × (p − o)`` (rotation about ``w`` through the ET's origin ``o``), so
    each ET that depends on an axis (its joint, or a component error of that axis with its spline
    slope ``dev``) adds slope × that column: no derivatives are carried through the chain.
    ``own`` (P,) the axis column of each slot (-1: constant)."""
    for o in range(kind.shape[0]):
        if kind[o] == 2:
            continue
        dj = joint[o]
        ds = -1
        if slot[o] >= 0:
            ds = own[slot[o]]
        if dj < 0 and ds < 0:
            continue
        c0, c1, c2 = _column(kind[o], W, O, o, t)
        if dj >= 0:
            g = sgn * jscale[o]
            jac_row[0, dj] += g * c0
            jac_row[1, dj] += g * c1
            jac_row[2, dj] += g * c2
        if ds >= 0:
            g = sgn * coef[o] * dev[slot[o]]
            jac_row[0, ds] += g * c0
            jac_row[1, ds] += g * c1
            jac_row[2, ds] += g * c2


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _spline_at(knots, k0, nk, coefs, c0, x, h, hh, vbuf, dbuf, deriv, inv_h):  # pragma: no cover - compiled
    """One cubic vector B-spline stored at offsets (knots ``knots[k0:k0 + nk]``, coefficient rows
    from ``c0``) at ``x``: values into ``vbuf`` (6,), with ``deriv`` slopes into ``dbuf``; ``inv_h``
    the number of its intervals over their span (where the interval search starts). The same
    operations as scipy's ``BSpline`` and its derivative (interval as scipy finds it,
    clipped to the end intervals; Cox–de Boor; the slope from the degree-2 basis) without array
    views per point."""
    k = 3
    nc = nk - k - 1
    # the interval np.searchsorted(t, x, side="right") - 1 clipped to [k, nc - 1]: the last knot
    # ≤ x; guessed from the mean interval ``1 / inv_h`` (exact for evenly spaced stations), then
    # moved until t[i] ≤ x < t[i + 1] (a guess only saves the search, it never decides)
    i = k
    g = (x - knots[k0 + k]) * inv_h
    if g > 0.0:  # (NaN: the first interval, as before)
        i = k + int(min(g, float(nc - 1 - k)))
    while i < nc - 1 and knots[k0 + i + 1] <= x:
        i += 1
    while i > k and knots[k0 + i] > x:
        i -= 1
    h[0] = 1.0
    for j in range(1, k + 1):
        if deriv and j == k:  # h[0:3] = the degree-2 basis of interval i: the slope
            for col in range(6):
                acc = 0.0
                for m in range(k):
                    jj = i - 2 + m
                    den = knots[k0 + jj + k] - knots[k0 + jj]
                    if den != 0.0:
                        acc += h[m] * k * (coefs[c0 + jj, col] - coefs[c0 + jj - 1, col]) / den
                dbuf[col] = acc
        for m in range(j):
            hh[m] = h[m]
        h[0] = 0.0
        for n in range(1, j + 1):
            xb = knots[k0 + i + n]
            xa = knots[k0 + i + n - j]
            if xb == xa:
                h[n] = 0.0
                continue
            w = hh[n - 1] / (xb - xa)
            h[n - 1] += w * (xb - x)
            h[n] = w * (x - xa)
    for col in range(6):
        acc = 0.0
        for m in range(k + 1):
            acc += h[m] * coefs[c0 + i - k + m, col]
        vbuf[col] = acc


@njit(cache=True, nogil=True, error_model="numpy")
def _slot_values(q, spl_axis, spl_s0, knots, koff, coefs, coff, spl_slot, spl_inv_h, consts, ev, dev, vbuf, dbuf, h, hh,
                 deriv):  # pragma: no cover - compiled
    """The component-error values into ``ev`` (P,) (and slopes into ``dev`` when ``deriv``) at one
    point from the per-axis splines (``spl_s0`` the first station of a full-turn axis, NaN
    otherwise); the constant slots of ``ev`` and ``dev`` are set once per call (:func:`_init_slots`)."""
    for s in range(spl_axis.shape[0]):
        x = q[spl_axis[s]]
        s0 = spl_s0[s]
        if not np.isnan(s0):
            x = s0 + np.mod(x - s0, 360.0)
        _spline_at(knots, koff[s], koff[s + 1] - koff[s], coefs, coff[s], x, h, hh, vbuf, dbuf, deriv, spl_inv_h[s])
        for col in range(6):
            p = spl_slot[s, col]
            if p >= 0:
                ev[p] = vbuf[col]
                if deriv:
                    dev[p] = dbuf[col]


@njit(cache=True, nogil=True)
def _init_slots(consts, ev, dev):  # pragma: no cover - compiled
    """``ev`` = the constants (component slots overwritten per point), ``dev`` = 0."""
    for p in range(ev.shape[0]):
        ev[p] = consts[p]
        dev[p] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def field_kernel(axes, prog, prog_nom, spl, consts, own, out, jac, deriv):  # pragma: no cover - compiled
    """Spatial error (μm) ``out`` (n, 3) and, when ``deriv``, dE/d(axes) ``jac`` (n, 3, k)."""
    spl_axis, spl_s0, knots, koff, coefs, coff, spl_slot, spl_inv_h = spl
    P = consts.shape[0]
    k = axes.shape[1]
    ev = np.empty(P)
    dev = np.empty(P)
    vbuf = np.empty(6)
    dbuf = np.empty(6)
    h = np.empty(4)
    hh = np.empty(4)
    R = np.empty((3, 3))
    t = np.empty(3)
    R0 = np.empty((3, 3))
    t0 = np.empty(3)
    k1, a1, v1, j1, s1, sl1, c1, b1, BR1, Bt1 = prog
    k0, a0, v0, j0, s0, sl0, c0, b0, BR0, Bt0 = prog_nom
    m = max(k1.shape[0], k0.shape[0]) if deriv else 0
    W = np.empty((m, 3))
    O = np.empty((m, 3))
    J = np.zeros((3, k))
    _init_slots(consts, ev, dev)
    for n in range(axes.shape[0]):
        q = axes[n]
        _slot_values(q, spl_axis, spl_s0, knots, koff, coefs, coff, spl_slot, spl_inv_h, consts, ev, dev, vbuf, dbuf, h, hh, deriv)
        _chain_point(q, ev, k1, a1, v1, j1, s1, sl1, c1, b1, BR1, Bt1, R, t, W, O, deriv)
        if deriv:
            J[:, :] = 0.0
            _jacobian_columns(dev, k1, j1, s1, sl1, c1, own, t, W, O, J, 1.0)
        _chain_point(q, ev, k0, a0, v0, j0, s0, sl0, c0, b0, BR0, Bt0, R0, t0, W, O, deriv)
        if deriv:
            _jacobian_columns(dev, k0, j0, s0, sl0, c0, own, t0, W, O, J, -1.0)
        for i in range(3):
            out[n, i] = (t[i] - t0[i]) * 1e3
            for j in range(k if deriv else 0):
                jac[n, i, j] = J[i, j] * 1e3


@njit(cache=True, nogil=True, error_model="numpy")
def error_jac_kernel(axes, prog, jac):  # pragma: no cover - compiled
    """∂(spatial error μm)/∂(slot values) at the nominal chain: ``jac`` (n, 3, P) zeroed by the
    caller. Each ET carrying a slot adds coefficient × its column (translation: its axis;
    rotation: axis × (tool point − origin)), × 1e3 for μm."""
    kind, eaxis, value, joint, jscale, slot, coef, block, BR, Bt = prog
    m = kind.shape[0]
    R = np.empty((3, 3))
    t = np.empty(3)
    W = np.empty((m, 3))
    O = np.empty((m, 3))
    ev = np.zeros(jac.shape[2])
    for n in range(axes.shape[0]):
        q = axes[n]
        _chain_point(q, ev, kind, eaxis, value, joint, jscale, slot, coef, block, BR, Bt, R, t, W, O, True)
        for o in range(m):
            if kind[o] == 2 or slot[o] < 0:
                continue
            c0, c1, c2 = _column(kind[o], W, O, o, t)
            g = coef[o] * 1e3
            p = slot[o]
            jac[n, 0, p] += g * c0
            jac[n, 1, p] += g * c1
            jac[n, 2, p] += g * c2


def slot_program(chain):
    """The chain as ops for :func:`error_jac_kernel`: every ET with a joint or a slot one op, runs
    of fixed ETs folded into constant blocks (layout of :meth:`CompiledChain._program`)."""
    scale = np.array([np.pi / 180 if j.type == "revolute" else 1.0 for j in chain.joints])
    jscale = np.where(chain.joint >= 0, chain.sign * scale[np.maximum(chain.joint, 0)], 0.0)
    return _pack(chain, jscale, lambda m: chain.joint[m] >= 0 or chain.slot[m] >= 0, lambda m: chain.slot[m],
                 lambda m: chain.value[m])


def error_jacobian(machine: MachineTool, axes) -> np.ndarray:
    """Compiled :meth:`MachineTool.error_jacobian` at the nominal chain: (n, k) -> (n, 3, P) μm per
    μm / per μrad (equal to the numpy form to round-off, tested)."""
    return compiled_nominal(machine).error_jacobian(axes)


def _pack(ch, jscale, single, slot_of, const_value):
    """Ops of chain ``ch``: ET ``m`` a single op where ``single(m)`` (with slot ``slot_of(m)``),
    else folded with its neighbours at value ``const_value(m)`` into a constant block."""
    ops, blocks, run = [], [], None
    for m in range(len(ch.ets)):
        if single(m):
            if run is not None:
                blocks.append(run)
                ops.append((2, 0, 0.0, -1, 0.0, -1, 0.0, len(blocks) - 1))
                run = None
            ops.append((1 if ch.kind_r[m] else 0, ch.axis[m], ch.value[m], ch.joint[m], jscale[m], slot_of(m),
                        ch.coef[m], -1))
            continue
        x = const_value(m)
        if x == 0.0:
            continue
        T = et_matrix(bool(ch.kind_r[m]), int(ch.axis[m]), x)
        run = T if run is None else run @ T
    if run is not None:
        blocks.append(run)
        ops.append((2, 0, 0.0, -1, 0.0, -1, 0.0, len(blocks) - 1))
    cols = list(zip(*ops)) if ops else [()] * 8
    B = np.array(blocks).reshape(-1, 4, 4)
    return (np.array(cols[0], dtype=np.int64), np.array(cols[1], dtype=np.int64), np.array(cols[2], dtype=float),
            np.array(cols[3], dtype=np.int64), np.array(cols[4], dtype=float), np.array(cols[5], dtype=np.int64),
            np.array(cols[6], dtype=float), np.array(cols[7], dtype=np.int64),
            np.ascontiguousarray(B[:, :3, :3]), np.ascontiguousarray(B[:, :3, 3]))


class CompiledChain:
    """The op arrays of a machine's chain and the spline arrays of an element set, packed once
    for the kernels. ``predict(axes)`` (n, 3) μm; ``predict_and_jacobian(axes)``."""

    def __init__(self, machine: MachineTool, elements: ChainElementSet):
        ch = machine.chain
        scale = np.array([np.pi / 180 if j.type == "revolute" else 1.0 for j in ch.joints])
        self.jscale = np.where(ch.joint >= 0, ch.sign * scale[np.maximum(ch.joint, 0)], 0.0)
        self.chain = ch
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
        # intervals per unit of the knot span: the interval search's first guess (_spline_at)
        inv_h = [(len(t) - 7) / (t[-4] - t[3]) if t[-4] > t[3] else 0.0 for t in knots]
        self.spl = (np.array(spl_axis, dtype=np.int64), np.array(spl_s0, dtype=float),
                    np.concatenate(knots) if knots else np.zeros(0), koff,
                    np.ascontiguousarray(np.concatenate(coefs)) if coefs else np.zeros((0, NCOMP)), coff,
                    np.array(spl_slot, dtype=np.int64).reshape(-1, NCOMP), np.array(inv_h, dtype=float))
        self.consts = np.zeros(len(machine.slots))
        for k, v in elements.constants.items():
            self.consts[idx[k]] = v
        self.k = len(machine.axes)
        self.prog = self._program(with_errors=True)
        self.prog_nom = self._program(with_errors=False)

    def _program(self, with_errors: bool):
        """The chain as ops: an ET that depends on a point (a joint, or a component error when
        ``with_errors``) stays one op; every run of ETs between them (fixed transforms, constant
        error slots at their values) is folded into one constant block (3×3 rotation, translation):
        ``(kind 0 translation | 1 rotation | 2 block, axis, value, joint, jscale, slot, coef, block,
        BR (B, 3, 3), Bt (B, 3))``."""
        ch = self.chain

        def per_point(m):
            p = ch.slot[m]
            return ch.joint[m] >= 0 or (with_errors and p >= 0 and self.own[p] >= 0)

        return _pack(ch, self.jscale, per_point, lambda m: ch.slot[m] if with_errors else -1,
                     lambda m: ch.value[m] + (ch.coef[m] * self.consts[ch.slot[m]] if with_errors and ch.slot[m] >= 0
                                              else 0.0))

    def predict(self, axes) -> np.ndarray:
        axes = np.ascontiguousarray(axes, dtype=float)
        out = np.empty((axes.shape[0], 3))
        field_kernel(axes, self.prog, self.prog_nom, self.spl, self.consts, self.own, out, np.empty((0, 3, self.k)),
                     False)
        return out

    def predict_and_jacobian(self, axes):
        axes = np.ascontiguousarray(axes, dtype=float)
        out = np.empty((axes.shape[0], 3))
        jac = np.empty((axes.shape[0], 3, self.k))
        field_kernel(axes, self.prog, self.prog_nom, self.spl, self.consts, self.own, out, jac, True)
        return out, jac


assert UM_MM == 1e-3, "the kernels write mm → μm as * 1e3"


# -- nominal tool points and per-pose slot values (every machine tool's, the grinder's too) ---------
def nominal_program(chain):
    """The chain as ops with no error slot (every joint ET one op, every run of fixed ETs one
    constant block): the nominal chain for :func:`nominal_jacobian_kernel` (layout of
    :meth:`CompiledChain._program`)."""
    scale = np.array([np.pi / 180 if j.type == "revolute" else 1.0 for j in chain.joints])
    jscale = np.where(chain.joint >= 0, chain.sign * scale[np.maximum(chain.joint, 0)], 0.0)
    return _pack(chain, jscale, lambda m: chain.joint[m] >= 0, lambda m: -1, lambda m: chain.value[m])


@njit(cache=True, nogil=True, error_model="numpy")
def values_kernel(axes, values, prog, prog_nom, out):  # pragma: no cover - compiled
    """Spatial error (μm) for slot values given per point: ``axes`` (n, k), ``values`` (n, P) μm /
    μrad, ``prog`` :func:`slot_program` (every slotted ET one op), ``prog_nom``
    :func:`nominal_program`; ``out`` (n, 3) = (actual − nominal tool point) × 1e3."""
    k1, a1, v1, j1, s1, sl1, c1, b1, BR1, Bt1 = prog
    k0, a0, v0, j0, s0, sl0, c0, b0, BR0, Bt0 = prog_nom
    R = np.empty((3, 3))
    t = np.empty(3)
    R0 = np.empty((3, 3))
    t0 = np.empty(3)
    W = np.empty((0, 3))
    for n in range(axes.shape[0]):
        q = axes[n]
        _chain_point(q, values[n], k1, a1, v1, j1, s1, sl1, c1, b1, BR1, Bt1, R, t, W, W, False)
        _chain_point(q, values[n], k0, a0, v0, j0, s0, sl0, c0, b0, BR0, Bt0, R0, t0, W, W, False)
        for i in range(3):
            out[n, i] = (t[i] - t0[i]) * 1e3


def compiled_nominal(machine: MachineTool) -> "CompiledNominal":
    """:class:`CompiledNominal` of ``machine``, packed once per machine object (kept on it)."""
    c = machine.__dict__.get("_compiled_nominal")
    if c is None:
        c = machine.__dict__["_compiled_nominal"] = CompiledNominal(machine)
    return c


def forward(machine: MachineTool, axes) -> np.ndarray:
    """Nominal tool point in the workpiece frame (mm), ``T_work⁻¹ · T_tool · origin``, at ``axes`` (n, k)
    in the machine's axis columns -> (n, 3) (compiled, :meth:`CompiledNominal.tool_points`)."""
    return compiled_nominal(machine).tool_points(_finite_axes(machine, axes))


def spatial_error(machine: MachineTool, axes, values) -> np.ndarray:
    """Spatial error (μm) with exact transforms at ``axes`` (n, k) for slot values ``values`` (n, P)
    (μm / μrad, chain slot order) -> (n, 3): point by point, float64, no small-angle step
    (:func:`values_kernel`; equal to :meth:`MachineTool.spatial_error`, the numpy chain, to round-off)."""
    return compiled_nominal(machine).spatial_error(_finite_axes(machine, axes), values)


def inverse(machine: MachineTool, points_mm, unwrap: bool = True, a_start_deg: float | None = None) -> np.ndarray:
    """Axes for workpiece-frame tool points (n, 3) -> (n, k): the chain's closed form
    (:meth:`MachineTool.closed_form_inverse`), compiled (:func:`closed_form_solver`). With ``unwrap`` the
    points are a path: the rotary axis is unwrapped along it (multi-turn paths continue past 360°) and the
    first point put in ``[lo, lo + 360)`` of its stroke, or nearest to ``a_start_deg`` when given; without
    it each point's angle lies in ``[lo, lo + 360)``. On the rotary axis itself the angle is undefined; 0."""
    from .machine_tool import rotary_on_turn
    from .transforms import check_points
    p = check_points(points_mm, "WCS points (px_mm, py_mm, pz_mm)")
    solve = closed_form_solver(machine)
    if not unwrap:  # each point's angle in [lo, lo + 360) in the same compiled pass
        return solve(p, fold=True)
    q = solve(p)
    r = solve.k.rotary
    q[:, r] = rotary_on_turn(q[:, r], solve.k.rotary_lo, unwrap=True, a_start_deg=a_start_deg)
    return q


def _finite_axes(machine: MachineTool, axes) -> np.ndarray:
    from .transforms import check_points
    return check_points(axes, f"axes ({', '.join(machine.axis_columns)})", width=len(machine.axes))


class CompiledNominal:
    """A machine's chain packed once for the point-by-point kernels that need no element set:
    ``tool_points(axes (n, k)) -> (n, 3)`` mm (nominal forward kinematics, compiled),
    ``spatial_error(axes (n, k), values (n, P)) -> (n, 3)`` μm (exact, slot values per point),
    ``error_jacobian(axes) -> (n, 3, P)`` μm per μm / per μrad (at the nominal chain)."""

    def __init__(self, machine: MachineTool):
        self.machine = machine
        self.k = len(machine.axes)
        self.P = len(machine.slots)
        self.prog_nom = nominal_program(machine.chain)
        self.prog_slots = slot_program(machine.chain)

    def _axes(self, axes) -> np.ndarray:
        axes = np.ascontiguousarray(np.atleast_2d(axes), dtype=float)
        if axes.ndim != 2 or axes.shape[1] != self.k:
            raise ValueError(f"expected axes of shape (n, {self.k}), got {axes.shape}")
        return axes

    def tool_points(self, axes) -> np.ndarray:
        axes = self._axes(axes)
        out = np.empty((axes.shape[0], 3))
        nominal_jacobian_kernel(axes, self.prog_nom, _NO_SLOTS, out, _NO_JACOBIAN, False)
        return out

    def spatial_error(self, axes, values) -> np.ndarray:
        axes = self._axes(axes)
        values = np.ascontiguousarray(values, dtype=float)
        if values.shape != (axes.shape[0], self.P):
            raise ValueError(f"expected slot values of shape ({axes.shape[0]}, {self.P}), got {values.shape}")
        out = np.empty((axes.shape[0], 3))
        values_kernel(axes, values, self.prog_slots, self.prog_nom, out)
        return out

    def error_jacobian(self, axes) -> np.ndarray:
        axes = self._axes(axes)
        jac = np.zeros((axes.shape[0], 3, self.P))
        error_jac_kernel(axes, self.prog_slots, jac)
        return jac


_NO_SLOTS = np.zeros(0, dtype=np.int64)  # a nominal program's slot columns (none)
_NO_JACOBIAN = np.empty((0, 3, 0))       # nominal_jacobian_kernel without its Jacobian

# ---------------------------------------------------------------------------- nominal chain
# (the solvers' and G-code kernels' one source of nominal kinematics)

@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def nominal_point(q, prog, R, t, W, O, ev, record):  # pragma: no cover - compiled
    """The nominal tool point of ``prog`` (a program without errors, :attr:`NominalChain.prog`) at
    axes ``q`` (k,) into ``t`` (3,) mm; with ``record`` the op columns for
    :func:`nominal_columns` into ``W``, ``O`` (ops, 3). ``R`` (3, 3), ``ev`` (≥ 1,) scratch."""
    kind, eaxis, value, joint, jscale, slot, coef, block, BR, Bt = prog
    _chain_point(q, ev, kind, eaxis, value, joint, jscale, slot, coef, block, BR, Bt, R, t, W, O, record)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def nominal_columns(prog, own, t, W, O, ev, Jp):  # pragma: no cover - compiled
    """``Jp`` (3, k) = d(tool point)/d(axes), mm per mm / per deg, after :func:`nominal_point` with
    ``record`` (geometric, exact: :func:`_jacobian_columns`)."""
    kind, eaxis, value, joint, jscale, slot, coef, block, BR, Bt = prog
    for i in range(3):
        for j in range(Jp.shape[1]):
            Jp[i, j] = 0.0
    _jacobian_columns(ev, kind, joint, jscale, slot, coef, own, t, W, O, Jp, 1.0)


@njit(cache=True, nogil=True, error_model="numpy")
def nominal_jacobian_kernel(axes, prog, own, P, J, jac):  # pragma: no cover - compiled
    """Nominal tool point ``P`` (n, 3) mm and, with ``jac``, its axis Jacobian ``J`` (n, 3, k) mm
    per mm / per deg at ``axes`` (n, k), for n points."""
    k = axes.shape[1]
    m = max(prog[0].shape[0], 1)
    W = np.empty((m, 3))
    O = np.empty((m, 3))
    R = np.empty((3, 3))
    t = np.empty(3)
    ev = np.zeros(max(own.shape[0], 1))
    Jp = np.empty((3, k))
    for n in range(axes.shape[0]):
        nominal_point(axes[n], prog, R, t, W, O, ev, jac)
        for i in range(3):
            P[n, i] = t[i]
        if jac:
            nominal_columns(prog, own, t, W, O, ev, Jp)
            for i in range(3):
                for j in range(k):
                    J[n, i, j] = Jp[i, j]


class NominalChain:
    """The nominal (error-free) chain of a machine tool packed once for compiled kernels: ``prog``
    the op arrays (the same ops as :attr:`CompiledChain.prog_nom`), ``own`` the slots' axis columns
    (unused by a program without errors, kept for the kernels' signature), ``k`` the axes, ``kinds``
    (k,) ``linear``/``rotary`` and ``full_turn`` (k,) bool per axis, ``columns`` the axis columns.

    ``machine``: a :class:`errormap.machine_tool.MachineTool`."""

    def __init__(self, machine):
        if isinstance(machine, MachineTool):
            mt, self.prog = machine, nominal_program(machine.chain)
        else:
            raise TypeError(f"Expected a machine-tool chain, got {type(machine).__name__}")
        self.machine_tool = mt
        self.own = np.zeros(0, dtype=np.int64)
        self.k = len(mt.axes)
        self.kinds = tuple(a.kind for a in mt.axes)
        self.full_turn = np.array([a.full_turn for a in mt.axes], dtype=bool)
        self.columns = mt.axis_columns

    def forward(self, axes) -> np.ndarray:
        """Nominal tool point (n, 3) mm at ``axes`` (n, k)."""
        return self.forward_and_jacobian(axes, jac=False)[0]

    def forward_and_jacobian(self, axes, jac: bool = True):
        """``(P (n, 3) mm, J (n, 3, k) mm per mm / per deg)`` at ``axes`` (n, k); ``J`` None
        without ``jac``."""
        axes = np.ascontiguousarray(axes, dtype=float)
        if axes.ndim != 2 or axes.shape[1] != self.k:
            raise ValueError(f"Expected axes of shape (n, {self.k}) ({', '.join(self.columns)}), got {axes.shape}")
        P = np.empty((axes.shape[0], 3))
        J = np.empty((axes.shape[0], 3, self.k) if jac else (0, 3, self.k))
        nominal_jacobian_kernel(axes, self.prog, self.own, P, J, bool(jac))
        return P, (J if jac else None)


# ---------------------------------------------------------------------------- closed-form inverse
# (the grinder's nominal inverse on its chain, compiled; the batched GA's generic
# fitness calls it on every offspring)

@njit(cache=True, nogil=True, error_model="numpy")
def closed_inverse_kernel(points, F0_inv_R, F0_t, w, normal, c, L_pinv, theta0, scale, mid, half, lin0, lin1, r,
                          fold, a_lo, out):  # pragma: no cover - compiled
    """:meth:`errormap.machine_tool.MachineTool.closed_form_inverse` point by point: ``points`` (n, 3)
    mm -> ``out`` (n, 3) axes, the rotary one in degrees (with ``fold`` put in ``[a_lo, a_lo +
    360)``). The same closed form as that numpy reference, with the two roots ``θ = φ ± δ`` (``cos φ
    = A/ρ``, ``sin φ = B/ρ``, ``cos δ = C/ρ``, ``sin δ ≥ 0``) turned into cosines and sines by the
    angle-addition rule, and one ``atan2`` for the root taken: no ``acos`` and no cosine or sine per
    root. Equal to the reference to round-off, the angle modulo a turn (tested)."""
    w0, w1, w2 = w[0], w[1], w[2]
    nc = normal[0] * c[0] + normal[1] * c[1] + normal[2] * c[2]
    ihalf0, ihalf1 = 1.0 / half[0], 1.0 / half[1]
    for i in range(points.shape[0]):
        d0, d1, d2 = points[i, 0] - F0_t[0], points[i, 1] - F0_t[1], points[i, 2] - F0_t[2]
        p0 = d0 * F0_inv_R[0, 0] + d1 * F0_inv_R[0, 1] + d2 * F0_inv_R[0, 2]   # F0⁻¹·p
        p1 = d0 * F0_inv_R[1, 0] + d1 * F0_inv_R[1, 1] + d2 * F0_inv_R[1, 2]
        p2 = d0 * F0_inv_R[2, 0] + d1 * F0_inv_R[2, 1] + d2 * F0_inv_R[2, 2]
        pw = p0 * w0 + p1 * w1 + p2 * w2
        a0, a1, a2 = pw * w0, pw * w1, pw * w2                        # along w
        e0, e1, e2 = p0 - a0, p1 - a1, p2 - a2                        # across w
        x0, x1, x2 = w1 * p2 - w2 * p1, w2 * p0 - w0 * p2, w0 * p1 - w1 * p0  # w × p
        A = e0 * normal[0] + e1 * normal[1] + e2 * normal[2]
        B = -(x0 * normal[0] + x1 * normal[1] + x2 * normal[2])
        C = nc - (a0 * normal[0] + a1 * normal[1] + a2 * normal[2])
        rr = np.sqrt(A * A + B * B)
        cphi, sphi, cd = 1.0, 0.0, 1.0  # on the rotary axis (A = B = 0): θ = 0
        if rr > 0.0:
            ir = 1.0 / rr
            cphi, sphi, cd = A * ir, B * ir, C * ir
        if cd < -1.0:  # a point the linear axes cannot reach: the nearest angle
            cd = -1.0
        elif cd > 1.0:
            cd = 1.0
        sd = np.sqrt((1.0 - cd) * (1.0 + cd))
        best_cost, cbest, sbest = 0.0, 1.0, 0.0
        for root in range(2):
            sg = 1.0 if root == 0 else -1.0                           # θ = φ + δ, then φ − δ
            cs = cphi * cd - sg * sphi * sd
            sn = sphi * cd + sg * cphi * sd
            q0, q1, q2 = a0 + cs * e0 - sn * x0, a1 + cs * e1 - sn * x1, a2 + cs * e2 - sn * x2  # R_w(−θ)·p
            q0, q1, q2 = q0 - c[0], q1 - c[1], q2 - c[2]
            u0 = q0 * L_pinv[0, 0] + q1 * L_pinv[0, 1] + q2 * L_pinv[0, 2]
            u1 = q0 * L_pinv[1, 0] + q1 * L_pinv[1, 1] + q2 * L_pinv[1, 2]
            g0, g1 = (u0 - mid[0]) * ihalf0, (u1 - mid[1]) * ihalf1
            cost = g0 * g0 + g1 * g1
            if root == 0 or cost < best_cost:
                best_cost, cbest, sbest = cost, cs, sn
                out[i, lin0], out[i, lin1] = u0, u1
        out[i, r] = (np.arctan2(sbest, cbest) - theta0) / scale
        if fold:
            out[i, r] = a_lo + np.mod(out[i, r] - a_lo, 360.0)


class ClosedFormInverse:
    """A chain's closed-form nominal inverse compiled (:func:`closed_inverse_kernel`) from its
    constants ``k`` (:meth:`errormap.machine_tool.MachineTool.closed_form_constants`; built once per
    machine by :func:`closed_form_solver`): ``inv(points (n, 3)
    mm, fold=False) -> axes (n, 3)``, the rotary axis in degrees (with ``fold`` in ``[lo, lo +
    360)`` of its stroke, else not yet wrapped: within a turn of ``θ0``)."""

    def __init__(self, k):
        self.k = k
        self._args = (np.ascontiguousarray(k.F0_inv_R, dtype=float), np.ascontiguousarray(k.F0_t, dtype=float),
                      np.eye(3)[k.w_axis], np.ascontiguousarray(k.normal, dtype=float),
                      np.ascontiguousarray(k.c, dtype=float), np.ascontiguousarray(k.L_pinv, dtype=float),
                      float(k.theta0), float(k.scale), np.ascontiguousarray(k.mid, dtype=float),
                      np.ascontiguousarray(k.half, dtype=float), int(k.lin[0]), int(k.lin[1]), int(k.rotary))

    def __call__(self, points_mm, fold: bool = False) -> np.ndarray:
        points = np.ascontiguousarray(points_mm, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"expected points of shape (n, 3), got {points.shape}")
        out = np.empty((points.shape[0], 3))
        closed_inverse_kernel(points, *self._args, bool(fold), float(self.k.rotary_lo), out)
        return out


def closed_form_solver(machine: MachineTool) -> ClosedFormInverse:
    """The chain's closed-form nominal inverse compiled (:class:`ClosedFormInverse` of
    :meth:`errormap.machine_tool.MachineTool.closed_form_constants`), built once per machine (kept on
    it, as its other compiled forms). ValueError where the chain has no closed form."""
    key = "_closed_form_compiled"
    if key not in machine.__dict__:
        k = machine.closed_form_constants()
        object.__setattr__(machine, key, None if k is None else ClosedFormInverse(k))
    solve = machine.__dict__[key]
    if solve is None:
        raise ValueError(f"{machine.name!r}: the chain has no closed-form inverse (use inverse, Newton)")
    return solve
