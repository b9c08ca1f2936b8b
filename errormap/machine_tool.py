"""Machine tools as chain files (``kind = "machine-tool"``): two ET lists, compiled once.

The **work** chain (base → workpiece) and the **tool** chain (base → tool point), read by
:mod:`errormap.machine_tool_file`, compile to one :class:`errormap.chain.Chain`: the work chain inverted
(:func:`errormap.chain.inverted`) then the tool chain, shared slots whose coefficients carry the units.
Slot order: component errors (axes in canonical order, ``dx dy dz ex ey ez`` each), location errors,
squareness. Shapes: ``axes`` (n, k) in the machine's axis order (columns ``x_mm … a_deg``), slot values (n, P)
μm / μrad in :attr:`MachineTool.slot_names` order, spatial error (n, 3) μm, error-parameter Jacobian
(n, 3, P), axis Jacobian (n, 3, k). Schema: ``docs/how-to/machine-file.md``."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .chain import Chain, ET, inverted
from .machine_checks import MachineFileError, check_known_keys, check_number, check_table, optional_table, short_repr
from .machine_tool_file import (AXIS_WORDS, COMPONENTS, CHAIN_SCHEMA_VERSION, UM_MM, ChainAxis, Slot, chain_side,
                                read_controller, read_spindle, read_targets, read_tcp)

@dataclass(frozen=True)
class ClosedForm:
    """The constants of a chain's closed-form nominal inverse (:meth:`MachineTool.closed_form_inverse`):
    ``F0_inv_R`` (3, 3), ``F0_t`` (3,) mm the fixed frame before the rotary ET (``F0⁻¹·p =
    F0_inv_R·(p − F0_t)``), ``w_axis`` the rotary ET's axis (0, 1, 2 = x, y, z), ``normal`` (3,) the
    linear axes' plane normal, ``c`` (3,) mm and ``L_pinv`` (2, 3) the origin after the rotary ET
    and the pseudo-inverse of its linear directions, ``theta0`` rad and ``scale`` rad per deg the
    rotary ET's value ``θ = θ0 + scale·a``, ``mid``, ``half`` (2,) the linear strokes' middles and
    half-lengths, ``lin`` the two linear axes' columns, ``rotary`` the rotary axis' column and
    ``rotary_lo`` its stroke's start (deg)."""

    F0_inv_R: np.ndarray
    F0_t: np.ndarray
    w_axis: int
    normal: np.ndarray
    c: np.ndarray
    L_pinv: np.ndarray
    theta0: float
    scale: float
    mid: np.ndarray
    half: np.ndarray
    lin: tuple
    rotary: int
    rotary_lo: float


@dataclass(frozen=True)
class WorkRotation:
    """The nominal rotation of the workpiece frame in the machine (base) frame, ``base <- work``, as
    data: the work chain's rotation ETs in order (translations do not turn the frame; error slots
    are left out: nominal), each ``(axis, value_rad, column, rad_per_unit)`` — a rotation about x, y
    or z (0, 1, 2) by ``value_rad + rad_per_unit * axes[:, column]`` (``column`` -1: a fixed rotation).
    ``n_axes`` the number of axis columns it takes. A residual measured in the work frame (the spatial
    error's frame) is ``R(axes)ᵀ`` times the same vector in the machine frame. Built by
    :meth:`MachineTool.work_rotation`; saved as :meth:`to_dict` (the learned residual's file)."""

    ets: tuple
    n_axes: int

    def __call__(self, axes) -> tuple:
        """``R`` (n, 3, 3), base <- work, and ``dR/d(axes)`` (n, 3, 3, k) (per deg or mm of each column)
        at ``axes`` (n, k), closed form: the product of the ETs' rotations and, per joint ET, the
        product with that ET's derivative ``Rot·K`` (``K`` the unit axis' cross-product matrix)."""
        axes = np.asarray(axes, dtype=float)
        if axes.ndim != 2 or axes.shape[1] != self.n_axes:
            raise ValueError(f"expected axes of shape (n, {self.n_axes}), got {axes.shape}")
        n = axes.shape[0]
        rots, ders = [], []
        for ax, v, col, k in self.ets:
            x = np.full(n, float(v)) if col < 0 else v + k * axes[:, col]
            b, c = (ax + 1) % 3, (ax + 2) % 3
            cs, sn = np.cos(x), np.sin(x)
            Rt = np.zeros((n, 3, 3))
            Rt[:, ax, ax] = 1.0
            Rt[:, b, b], Rt[:, b, c], Rt[:, c, b], Rt[:, c, c] = cs, -sn, sn, cs
            Kx = np.zeros((3, 3))
            Kx[c, b], Kx[b, c] = 1.0, -1.0
            rots.append(Rt)
            ders.append(Rt @ Kx)
        m = len(rots)
        pre = [np.broadcast_to(np.eye(3), (n, 3, 3))]
        for Rt in rots:
            pre.append(pre[-1] @ Rt)
        suf = [np.broadcast_to(np.eye(3), (n, 3, 3))]
        for Rt in reversed(rots):
            suf.append(Rt @ suf[-1])
        suf = suf[::-1]          # suf[i] = rots[i] ... rots[m-1]; suf[m] = I
        dR = np.zeros((n, 3, 3, self.n_axes))
        for i, (ax, v, col, k) in enumerate(self.ets):
            if col >= 0:
                dR[:, :, :, col] += k * (pre[i] @ ders[i] @ suf[i + 1])
        return np.array(pre[m]), dR

    @property
    def turns(self) -> bool:
        """Whether the work frame turns with an axis (any rotation ET is a joint)."""
        return any(col >= 0 for _, _, col, _ in self.ets)

    def to_dict(self) -> dict:
        return {"n_axes": int(self.n_axes),
                "ets": [[int(a), float(v), int(c), float(k)] for a, v, c, k in self.ets]}

    @classmethod
    def from_dict(cls, doc) -> "WorkRotation":
        """ValueError on anything but :meth:`to_dict`'s output."""
        try:
            n_axes = int(doc["n_axes"])
            ets = tuple((int(a), float(v), int(c), float(k)) for a, v, c, k in doc["ets"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"expected a work rotation {{n_axes, ets: [[axis, value_rad, column, rad_per_unit], ...]}} "
                             f"({exc})") from None
        if n_axes < 1 or any(a not in (0, 1, 2) or not -1 <= c < n_axes or not (np.isfinite(v) and np.isfinite(k))
                             for a, v, c, k in ets):
            raise ValueError("expected work rotation ETs about axis 0, 1 or 2, of finite values, on a column "
                             f"-1..{n_axes - 1}")
        return cls(ets, n_axes)


@dataclass(frozen=True)
class MachineTool:
    """A compiled machine-tool chain file. ``axes`` in canonical word order; ``slots`` in chain
    order; ``chain`` the compiled ``inv(work)·tool`` chain (joints = ``axes``, parameters =
    slots in μm/μrad); ``targets[word]`` (m, 3) target balls in that body's frame (mm);
    ``geometry`` the named constants; ``work_ets``/``tool_ets`` the two chains as written."""

    name: str
    axes: tuple
    slots: tuple
    chain: Chain
    work_ets: tuple
    tool_ets: tuple
    targets: dict
    geometry: dict
    body_index: dict = field(default_factory=dict)
    path: str = ""
    sha256: str = ""
    kind: str = "machine-tool"
    description: str = ""
    spindle: dict | None = None
    """``[spindle]`` of the file (a lathe's work spindle): ``axis`` (its rotary axis word),
    ``turning_on`` / ``turning_off`` (the M codes that start turning and end it), ``x_words`` (``"diameter"``,
    ``"radius"`` or None: what a Fanuc, Haas or Siemens ISO control's X words are); None without one."""
    tcp: dict | None = None
    """``[tcp]`` of the file: ``switch_on`` / ``switch_off`` (tuples of M code numbers) that switch the
    controller's tool-centre-point kinematics on and off (LinuxCNC's switchable kinematics, remapped M
    codes); None without one (:mod:`compensation.tcp`)."""
    controller: dict | None = None
    """``[controller]`` of the file: ``harmless_m`` (a tuple of M code numbers) this machine's controller runs
    without moving an axis or calling a program, beyond its dialect's own; None without one."""
    truth: dict = field(default_factory=dict)
    """``[truth]`` of the file: how seeded truths of this machine are drawn
    (:func:`errormap.chain_truth.recipe` reads and checks it); empty without one."""
    read_as: str = ""
    """The one line a command says when the file was not a chain file but was read into one (a
    ``kind = "grinder"`` file, :func:`errormap.grinder_file.parse_grinder_file`); empty for a chain file."""

    # -- names and sizes ----------------------------------------------------------------------
    @property
    def axis_words(self) -> tuple:
        return tuple(a.word for a in self.axes)

    @property
    def axis_columns(self) -> tuple:
        """Axis column names in order (``("x_mm", "z_mm", "a_deg")``)."""
        return tuple(a.column for a in self.axes)

    @property
    def slot_names(self) -> tuple:
        return tuple(s.name for s in self.slots)

    @property
    def iso_names(self) -> tuple:
        return tuple(s.iso for s in self.slots)

    @property
    def function_slots(self) -> tuple:
        """Names of the component errors (functions of their axis), chain order."""
        return tuple(s.name for s in self.slots if s.is_function)

    @property
    def constant_slots(self) -> tuple:
        return tuple(s.name for s in self.slots if not s.is_function)

    def slots_of(self, word: str) -> tuple:
        """The component-error names of axis ``word`` in COMPONENTS order."""
        return tuple(f"{c}_{word.lower()}" for c in COMPONENTS if f"{c}_{word.lower()}" in self.slot_names)

    @property
    def strokes(self) -> dict:
        """``{column: (lo, hi)}`` per axis."""
        return {a.column: a.stroke for a in self.axes}

    @property
    def stroke_lo(self) -> np.ndarray:
        return np.array([a.stroke[0] for a in self.axes])

    @property
    def stroke_hi(self) -> np.ndarray:
        return np.array([a.stroke[1] for a in self.axes])

    # -- kinematics (numpy reference) -----------------------------------------------------------
    def _check(self, axes, values=None):
        axes = np.atleast_2d(np.asarray(axes, dtype=float))
        if axes.ndim != 2 or axes.shape[1] != len(self.axes):
            raise ValueError(f"expected axes of shape (n, {len(self.axes)}) ({', '.join(self.axis_columns)}), "
                             f"got {np.shape(axes)}")
        if values is not None:
            values = np.asarray(values, dtype=float)
            if values.shape not in ((len(self.slots),), (axes.shape[0], len(self.slots))):
                raise ValueError(f"expected slot values of shape ({axes.shape[0]}, {len(self.slots)}) or "
                                 f"({len(self.slots)},), got {values.shape}")
        return axes, values

    def tool_point(self, axes, values=None) -> np.ndarray:
        """Tool point in the workpiece frame (mm), shape (n, 3); ``values`` (n, P) or (P,) μm/μrad
        (None: nominal)."""
        axes, values = self._check(axes, values)
        return self.chain.tool_point(axes, values)

    def nominal(self, axes) -> np.ndarray:
        """Nominal tool point in the workpiece frame (mm), shape (n, 3)."""
        return self.tool_point(axes)

    def _by_chunk(self, fn, axes, values, shape, chunk: int) -> np.ndarray:
        """``fn(axes rows, their values or None)`` over ``chunk`` rows at a time, stacked: (n, *shape)."""
        axes, values = self._check(axes, values)
        out = np.empty((axes.shape[0], *shape))
        for s in range(0, axes.shape[0], chunk):
            sl = slice(s, s + chunk)
            out[sl] = fn(axes[sl], None if values is None else (values if values.ndim == 1 else values[sl]))
        return out

    def spatial_error(self, axes, values, chunk: int = 4096) -> np.ndarray:
        """Exact spatial error (μm), actual minus nominal tool point in the workpiece frame, (n, 3)."""
        return self._by_chunk(lambda q, v: (self.chain.tool_point(q, v) - self.chain.tool_point(q)) / UM_MM,
                              axes, values, (3,), chunk)

    def error_jacobian(self, axes, values=None, chunk: int = 4096) -> np.ndarray:
        """∂(spatial error μm)/∂(slot values), shape (n, 3, P), μm per μm or per μrad; at the
        nominal chain (``values`` None: the first-order error-transfer matrix, ``e ≈ J·v``) or
        linearised at ``values``."""
        return self._by_chunk(lambda q, v: self.chain.error_jacobian(q, v) / UM_MM, axes, values,
                              (3, len(self.slots)), chunk)

    def axis_jacobian(self, axes, values=None, chunk: int = 4096) -> np.ndarray:
        """∂(tool point mm)/∂(axes in mm/deg) at fixed slot values, shape (n, 3, k)."""
        return self._by_chunk(self.chain.joint_jacobian, axes, values, (3, len(self.axes)), chunk)

    def inverse(self, points_mm, axes_start, free=None, tol_mm: float = 1e-10, max_iter: int = 50):
        """Nominal inverse kinematics by Newton: axes that put the nominal tool point at
        ``points_mm`` (n, 3) (workpiece frame, mm). ``axes_start`` (n, k) the starting axes, which
        also give the values of the axes not solved for; ``free`` the axis words solved for
        (exactly 3; default all axes of a 3-axis machine, the linear axes otherwise — a 5-axis
        machine keeps the rotary axes of ``axes_start``, i.e. the tool orientation). Returns
        ``(axes (n, k), converged (n,) bool)``: converged where the tool point is within ``tol_mm``
        after at most ``max_iter`` steps (a point the free axes cannot reach does not converge)."""
        pts = np.atleast_2d(np.asarray(points_mm, dtype=float))
        q, _ = self._check(axes_start)
        q = q.copy()
        if pts.shape != (q.shape[0], 3):
            raise ValueError(f"expected points of shape ({q.shape[0]}, 3), got {pts.shape}")
        if free is None:
            free = self.axis_words if len(self.axes) == 3 else tuple(a.word for a in self.axes if a.kind == "linear")
        cols = [self.axis_words.index(w) for w in free]
        if len(cols) != 3 or len(set(cols)) != 3:
            raise ValueError(f"expected 3 distinct axis words of {list(self.axis_words)} to solve for, got {list(free)}")
        active = np.ones(q.shape[0], dtype=bool)
        for _ in range(max_iter):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            r = pts[idx] - self.tool_point(q[idx])
            done = np.abs(r).max(axis=1) <= tol_mm
            active[idx[done]] = False
            idx, r = idx[~done], r[~done]
            if idx.size == 0:
                break
            J = self.axis_jacobian(q[idx])[:, :, cols]
            ok = np.abs(np.linalg.det(J)) > 1e-12
            step = np.zeros((idx.size, 3))
            step[ok] = np.linalg.solve(J[ok], r[ok][:, :, None])[:, :, 0]
            active[idx[~ok]] = False
            q[np.ix_(idx, cols)] += step
        err = np.abs(pts - self.tool_point(q)).max(axis=1)
        return q, err <= tol_mm

    def closed_form_inverse(self):
        """The nominal inverse in closed form where the chain's structure allows it, else None
        (``docs/reference/machine-tool-chains.md``).

        Recognised from the compiled chain: three axes, one rotary driving one ET with only fixed ETs
        before it (``F0``) and no rotary joint after it, so that ``p = F0·R_w(θ)·(c + L·u)``;
        ``n·R_w(−θ)·F0⁻¹p = n·c`` gives ``θ = atan2(B, A) ± acos(C / hypot(A, B))`` (clipped; θ = 0 on the
        rotary axis itself), each with ``u = L⁺·(R_w(−θ)·F0⁻¹p − c)``; the root whose linear axes lie
        nearest their strokes' middles is taken. Returns ``points (n, 3) mm -> axes (n, 3)``, the rotary
        axis in degrees not yet wrapped (:meth:`inverse_closed`): the readable reference of the compiled
        :func:`errormap.chain_kernel.closed_form_solver`, equal to it to round-off (tested)."""
        k = self.closed_form_constants()
        if k is None:
            return None
        lin, r, w = list(k.lin), k.rotary, np.eye(3)[k.w_axis]
        n, c, L_pinv, F0_inv_R, F0_t = k.normal, k.c, k.L_pinv, k.F0_inv_R, k.F0_t
        theta0, s, mid, half = k.theta0, k.scale, k.mid, k.half

        def solve(points_mm):
            p = (np.asarray(points_mm, dtype=float) - F0_t) @ F0_inv_R.T       # F0⁻¹·p
            par = (p @ w)[:, None] * w
            perp = p - par
            wxp = np.cross(w, p)
            A, B, C = perp @ n, -(wxp @ n), n @ c - par @ n
            rr = np.hypot(A, B)
            ratio = np.divide(C, rr, out=np.ones_like(C), where=rr > 0.0)
            phi, d = np.arctan2(B, A), np.arccos(np.clip(ratio, -1.0, 1.0))
            best, best_cost = None, None
            for th in (phi + d, phi - d):
                cs, sn = np.cos(th)[:, None], np.sin(th)[:, None]
                q = par + cs * perp - sn * wxp                                   # R_w(−θ)·p
                u = (q - c) @ L_pinv.T
                cost = (((u - mid) / half) ** 2).sum(axis=1)
                ax = np.empty((p.shape[0], 3))
                ax[:, lin[0]], ax[:, lin[1]] = u[:, 0], u[:, 1]
                ax[:, r] = (th - theta0) / s
                if best is None:
                    best, best_cost = ax, cost
                else:
                    take = cost < best_cost
                    best[take] = ax[take]
            return best

        return solve

    def closed_form_constants(self):
        """The constants of :meth:`closed_form_inverse` (:class:`ClosedForm`), or None where the
        chain's structure has no closed form."""
        ch = self.chain
        if len(self.axes) != 3:
            return None
        rot = [j for j, a in enumerate(self.axes) if a.kind == "rotary"]
        lin = [j for j, a in enumerate(self.axes) if a.kind == "linear"]
        if len(rot) != 1 or len(lin) != 2:
            return None
        r = rot[0]
        drives = np.flatnonzero(ch.joint >= 0)
        at = [m for m in drives if ch.joint[m] == r]
        if len(at) != 1 or any(ch.joint[m] >= 0 for m in range(at[0])):
            return None
        m0 = at[0]
        if any(ch.kind_r[m] and ch.joint[m] >= 0 for m in range(m0 + 1, len(ch.ets))):
            return None
        F0 = np.eye(4)
        for m in range(m0):
            F0 = F0 @ et_matrix(bool(ch.kind_r[m]), int(ch.axis[m]), float(ch.value[m]))
        scale = np.where(ch.joint >= 0, ch.sign, 0.0)

        def rest(u):  # origin after the rotary ET, (2,) linear axis values -> (3,) mm
            T = np.eye(4)
            for m in range(m0 + 1, len(ch.ets)):
                x = ch.value[m]
                if ch.joint[m] >= 0:
                    x = x + scale[m] * u[lin.index(int(ch.joint[m]))]
                T = T @ et_matrix(bool(ch.kind_r[m]), int(ch.axis[m]), float(x))
            return T[:3, 3]

        c = rest(np.zeros(2))
        L = np.stack([rest(np.eye(2)[j]) - c for j in range(2)], axis=1)
        n = np.cross(L[:, 0], L[:, 1])
        if np.linalg.norm(n) < 1e-9 * max(1.0, np.linalg.norm(L) ** 2):
            return None
        n = n / np.linalg.norm(n)
        w = np.eye(3)[int(ch.axis[m0])]
        if np.linalg.norm(n - (n @ w) * w) < 1e-9:
            return None
        lo = np.array([self.axes[j].stroke[0] for j in lin])
        hi = np.array([self.axes[j].stroke[1] for j in lin])
        return ClosedForm(F0_inv_R=np.ascontiguousarray(F0[:3, :3].T), F0_t=F0[:3, 3].copy(),
                          w_axis=int(ch.axis[m0]), normal=n, c=c, L_pinv=np.linalg.pinv(L),
                          theta0=float(ch.value[m0]), scale=float(ch.sign[m0]) * np.pi / 180.0,
                          mid=(lo + hi) / 2.0, half=np.maximum((hi - lo) / 2.0, 1e-12), lin=tuple(lin), rotary=r,
                          rotary_lo=float(self.axes[r].stroke[0]))

    def inverse_closed(self, points_mm, unwrap: bool = True, a_start_deg: float | None = None) -> np.ndarray:
        """Nominal axes for workpiece-frame tool points by :meth:`closed_form_inverse` (refused with
        ValueError where the chain has none), shape (n, 3) -> (n, 3). The rotary axis: with
        ``unwrap`` the points are a path, unwrapped along it (multi-turn paths continue past 360°)
        and the first point put in ``[lo, lo + 360)`` of its stroke, or nearest to ``a_start_deg``
        when given; without ``unwrap`` each point's angle lies in ``[lo, lo + 360)``."""
        solve = self._closed_form()
        if solve is None:
            raise ValueError(f"{self.name!r}: the chain has no closed-form inverse (use inverse, Newton)")
        q = solve(np.atleast_2d(np.asarray(points_mm, dtype=float)))
        r = next(j for j, a in enumerate(self.axes) if a.kind == "rotary")
        q[:, r] = rotary_on_turn(q[:, r], self.axes[r].stroke[0], unwrap, a_start_deg)
        return q

    def _closed_form(self):
        """:meth:`closed_form_inverse`, built once per machine."""
        key = "_closed_form_solver"
        if key not in self.__dict__:
            object.__setattr__(self, key, self.closed_form_inverse())
        return self.__dict__[key]

    def work_rotation(self) -> WorkRotation:
        """The nominal rotation of the work frame in the machine frame as data (:class:`WorkRotation`):
        the work chain's rotation ETs, joints in this machine's axis columns (deg → rad)."""
        scale = [np.pi / 180 if a.kind == "rotary" else 1.0 for a in self.axes]
        ets = tuple((int(e.axis), float(e.value), -1 if e.joint is None else int(e.joint),
                     0.0 if e.joint is None else float(e.sign) * scale[e.joint])
                    for e in self.work_ets if e.kind == "r" and (e.joint is not None or e.value != 0.0))
        return WorkRotation(ets, len(self.axes))

    def body_frames(self, word: str, axes, values=None):
        """Actual frame of the moving body of axis ``word`` in the machine (base) frame, after its
        motion and its component errors (where its ``[targets]`` are mounted): ``(R (n, 3, 3),
        t (n, 3) mm)``, base <- body. ``axes`` (n, k); ``values`` (n, P) or (P,) μm/μrad, None nominal."""
        if word not in self.body_index:
            raise ValueError(f"expected an axis word of {self.name!r} {list(self.axis_words)}, got {word!r}")
        side, upto = self.body_index[word]
        return self.side_frames(side, axes, values, upto=upto)

    def side_frames(self, side: str, axes, values=None, upto: int | None = None, start: int = 0):
        """The frame after the first ``upto`` ETs (all when None) of the ``work`` or ``tool`` chain
        as written (from the machine base; from the frame after ET ``start`` when given, i.e. the
        transform of ETs ``start .. upto - 1`` alone), with every ET at its value, joint and slot value:
        ``(R (n, 3, 3), t (n, 3) mm)``, base <- that frame. ``axes`` (n, k); ``values`` (n, P) or
        (P,) μm/μrad, None nominal. ``side_frames("tool", q)[1]`` is the tool point in the machine
        frame; :meth:`body_frames` is this at a body's ETs."""
        if side not in ("work", "tool"):
            raise ValueError(f"expected side 'work' or 'tool', got {side!r}")
        axes, values = self._check(axes, values)
        ets = (self.work_ets if side == "work" else self.tool_ets)[start:upto]
        n = axes.shape[0]
        scale = np.array([np.pi / 180 if a.kind == "rotary" else 1.0 for a in self.axes])
        index = {s: p for p, s in enumerate(self.slot_names)}
        R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        t = np.zeros((n, 3))
        for e in ets:
            x = np.full(n, e.value)
            if e.joint is not None:
                x = x + e.sign * axes[:, e.joint] * scale[e.joint]
            if e.slot is not None and values is not None:
                v = values[index[e.slot]] if values.ndim == 1 else values[:, index[e.slot]]
                x = x + e.coef * v
            if e.kind == "t":
                t = t + R[:, :, e.axis] * x[:, None]
            else:
                b, c = (e.axis + 1) % 3, (e.axis + 2) % 3
                cs, sn = np.cos(x)[:, None], np.sin(x)[:, None]
                rb, rc = R[:, :, b].copy(), R[:, :, c].copy()
                R[:, :, b] = rb * cs + rc * sn
                R[:, :, c] = rc * cs - rb * sn
        return R, t

    def target_points(self, word: str, axes, values=None) -> np.ndarray:
        """The target balls of axis ``word``'s body in the machine frame, (n, m, 3) mm."""
        R, t = self.body_frames(word, axes, values)
        return np.einsum("nij,kj->nki", R, self.targets[word]) + t[:, None, :]

    def describe(self) -> dict:
        """The machine as plain data for JSON documents and ``volcomp machines``."""
        return {"name": self.name, "kind": self.kind,
                "axes": [{"word": a.word, "column": a.column, "kind": a.kind, "side": a.side,
                          "stroke": list(a.stroke)} for a in self.axes],
                "slots": [{"name": s.name, "iso": s.iso, "kind": s.kind, "axis": s.axis, "unit": s.unit}
                          for s in self.slots]}


def parse_machine_tool(doc: dict, path, sha: str = "") -> MachineTool:
    """Validate a parsed ``kind = "machine-tool"`` file and compile its chain (``docs/how-to/machine-file.md``)."""
    check_known_keys(doc, ("machine", "geometry", "work", "tool", "targets", "spindle", "tcp", "controller",
                          "truth"), "",
                     path)
    m = check_table(doc, "machine", path)
    check_known_keys(m, ("kind", "name", "schema", "description"), "machine", path)
    name = m.get("name", "machine-tool")
    if not isinstance(name, str):
        raise MachineFileError(f"{path}: key 'machine.name': expected a string, got {short_repr(name)}")
    ver = m.get("schema", None)
    if isinstance(ver, bool) or ver != CHAIN_SCHEMA_VERSION:
        raise MachineFileError(f"{path}: key 'machine.schema': this volcomp reads machine-tool schema "
                               f"{CHAIN_SCHEMA_VERSION}, got {short_repr(ver)}")
    g = optional_table(doc, "geometry", path, {})
    geometry = {}
    for k in g:
        if not isinstance(k, str) or not k.isidentifier():
            raise MachineFileError(f"{path}: key 'geometry.{k}': expected a constant name (identifier)")
        geometry[k] = check_number(g, k, "geometry", path)
    words, axes, slots, placed = {}, [], [], set()
    work, work_body = chain_side(doc.get("work"), "work", path, geometry, words, axes, slots, placed)
    tool, tool_body = chain_side(doc.get("tool"), "tool", path, geometry, words, axes, slots, placed)
    if not axes:
        raise MachineFileError(f"{path}: no joint in [[work]] or [[tool]]: a machine tool has moving axes")
    order = sorted(range(len(axes)), key=lambda i: AXIS_WORDS.index(axes[i][0].word))
    index = {axes[i][0].word: k for k, i in enumerate(order)}

    def renumber(ets):
        return [ET(e.kind, e.axis, e.value, None if e.joint is None else index[e.joint], e.sign, e.slot, e.coef)
                for e in ets]

    work_n, tool_n = renumber(work), renumber(tool)
    dup = sorted({s.name for s in slots if [t.name for t in slots].count(s.name) > 1})
    if dup:
        raise MachineFileError(f"{path}: duplicate error slot name {dup[0]!r} (squareness names must differ from "
                               "the derived names)")
    axis_names = tuple(axes[i][0] for i in order)
    joints = tuple(axes[i][1] for i in order)
    kind_rank = {"component": 0, "location": 1, "squareness": 2}
    ordered = sorted(slots, key=lambda s: (kind_rank[s.kind], AXIS_WORDS.index(s.axis)))  # stable: file order within
    try:
        chain = Chain.compile(inverted(work_n) + tool_n, joints, name=name, shared_slots=True,
                              slot_order=[s.name for s in ordered], path=str(path),
                              sha256=sha, kind="machine-tool", convention="machine-tool")
    except ValueError as exc:
        raise MachineFileError(f"{path}: {exc}") from None
    by_name = {s.name: s for s in slots}
    slot_list = tuple(by_name[n] for n in chain.param_names)
    targets = read_targets(optional_table(doc, "targets", path, {}), path, axis_names)
    body_index = {**{w: ("work", k) for w, k in work_body.items()}, **{w: ("tool", k) for w, k in tool_body.items()}}
    return MachineTool(name=name, axes=axis_names, slots=slot_list, chain=chain, work_ets=tuple(work_n),
                       tool_ets=tuple(tool_n), targets=targets, geometry=geometry, body_index=body_index,
                       path=str(path), sha256=sha, description=str(m.get("description", "")),
                       spindle=read_spindle(optional_table(doc, "spindle", path), path, axis_names),
                       tcp=read_tcp(optional_table(doc, "tcp", path), path, axis_names),
                       controller=read_controller(optional_table(doc, "controller", path), path),
                       truth=optional_table(doc, "truth", path, {}))


def rotary_on_turn(a_deg, a_lo: float, unwrap: bool = True, a_start_deg: float | None = None) -> np.ndarray:
    """A rotary axis' values (n,) deg put on a turn (:meth:`MachineTool.inverse_closed`): with
    ``unwrap`` a path, unwrapped along it (multi-turn paths continue past 360°) and the first point
    put in ``[a_lo, a_lo + 360)``, or nearest to ``a_start_deg`` when given; without ``unwrap`` each
    value in ``[a_lo, a_lo + 360)``."""
    a = np.asarray(a_deg, dtype=float)
    if not unwrap:
        return a_lo + np.mod(a - a_lo, 360.0)
    a = np.rad2deg(np.unwrap(np.deg2rad(a)))
    if a.size:
        if a_start_deg is None:
            a = a - 360.0 * np.floor((a[0] - a_lo) / 360.0)
        else:
            a = a - 360.0 * np.round((a[0] - a_start_deg) / 360.0)
    return a


def et_matrix(kind_r: bool, axis: int, x: float) -> np.ndarray:
    """One ET with value ``x`` (mm or rad) as a 4×4 matrix."""
    T = np.eye(4)
    if kind_r:
        b, c = (axis + 1) % 3, (axis + 2) % 3
        cs, sn = np.cos(x), np.sin(x)
        T[b, b], T[b, c], T[c, b], T[c, c] = cs, -sn, sn, cs
    else:
        T[axis, 3] = x
    return T
