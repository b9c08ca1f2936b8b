"""A serial kinematic chain as data: ordered elementary transforms, compiled once.

An elementary transform (ET) translates along or rotates about x, y or z of the current frame; it is fixed
or a joint (offset + direction · joint value) and may carry an additive *error slot*. Standard and modified
DH tables compile to ETs (:func:`dh_ets`, :func:`mdh_ets`: Δθ, Δd, Δa, Δα per link, a Hayati β on parallel
consecutive axes, a base frame of 6 slots and a tool point of 3), element names derived from the chain
(``link2.da_mm``, ``base.rz_rad``, ``tool.z_mm``). Machine tools (:mod:`errormap.machine_tool`) add two
extensions: a slot entering several ETs with coefficients that carry its unit (``shared_slots=True``), and
error values per pose, ``errors`` (n, P). Units: joints in their units (deg, mm), error parameters mm / rad.
Shapes: ``q`` (n, nq), frames (n, 4, 4), tool-point error Jacobian (n, 3, n_params), joint Jacobian
(n, 3 or 6, nq); the tool point is the last frame's origin. See ``docs/reference/machine-tool-chains.md``."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

AXES = "xyz"
ET_TYPES = ("tx", "ty", "tz", "rx", "ry", "rz")


@dataclass(frozen=True)
class ET:
    """One elementary transform. ``kind`` 't' (translation, mm) or 'r' (rotation, rad) along/about
    ``axis`` (0, 1, 2 = x, y, z); ``value`` the constant part; ``joint`` the joint index or None;
    ``sign`` the joint direction (+1/-1); ``slot`` the error-slot name or None; ``coef`` the slot's
    coefficient (the ET's value gains ``coef * error``; 1 for arms)."""

    kind: str
    axis: int
    value: float = 0.0
    joint: int | None = None
    sign: float = 1.0
    slot: str | None = None
    coef: float = 1.0

    @property
    def type(self) -> str:
        return self.kind + AXES[self.axis]


@dataclass(frozen=True)
class Joint:
    """A joint: ``name``, ``type`` ('revolute' in deg or 'prismatic' in mm), limits ``lo`` < ``hi``."""

    name: str
    type: str
    lo: float
    hi: float

    @property
    def unit(self) -> str:
        return "deg" if self.type == "revolute" else "mm"

    @property
    def column(self) -> str:
        """The CSV column of this joint's values (``q1_deg``)."""
        return f"{self.name}_{self.unit}"


def et(type_: str, value: float = 0.0, joint: int | None = None, sign: float = 1.0, slot: str | None = None,
       coef: float = 1.0) -> ET:
    """An :class:`ET` from a type word ``tx`` … ``rz`` (rotation values in rad)."""
    return ET(type_[0], AXES.index(type_[1]), float(value), joint, float(sign), slot, float(coef))


def inverted(ets) -> list[ET]:
    """The ETs of the inverse transform: the list reversed, every value, joint direction and slot
    coefficient negated (``(T1·…·Tk)⁻¹ = Tk⁻¹·…·T1⁻¹`` and ``Tx(v)⁻¹ = Tx(−v)``, ``Rx(v)⁻¹ = Rx(−v)``)."""
    return [ET(e.kind, e.axis, -e.value, e.joint, -e.sign, e.slot, -e.coef) for e in reversed(list(ets))]


def base_ets(xyz_mm=(0.0, 0.0, 0.0), rpy_rad=(0.0, 0.0, 0.0), slots: bool = True) -> list[ET]:
    """Base frame: tx ty tz rz ry rx (``rpy_rad`` = (rx, ry, rz)); 6 error slots ``base.*``."""
    s = (lambda n: f"base.{n}") if slots else (lambda n: None)
    return [et("tx", xyz_mm[0], slot=s("x_mm")), et("ty", xyz_mm[1], slot=s("y_mm")), et("tz", xyz_mm[2], slot=s("z_mm")),
            et("rz", rpy_rad[2], slot=s("rz_rad")), et("ry", rpy_rad[1], slot=s("ry_rad")),
            et("rx", rpy_rad[0], slot=s("rx_rad"))]


def tool_ets(xyz_mm, slots: bool = True) -> list[ET]:
    """Tool point: tx ty tz in the last frame; 3 error slots ``tool.*``."""
    s = (lambda n: f"tool.{n}") if slots else (lambda n: None)
    return [et("tx", xyz_mm[0], slot=s("x_mm")), et("ty", xyz_mm[1], slot=s("y_mm")), et("tz", xyz_mm[2], slot=s("z_mm"))]


def parallel_axes(alpha_rad: float, tol_rad: float = 1e-6) -> bool:
    """Whether a link twist makes its two joint axes parallel (α ≡ 0 mod π)."""
    r = np.mod(alpha_rad, np.pi)
    return min(r, np.pi - r) < tol_rad


def dh_ets(rows, joint_types, signs=None, slots: bool = True, beta: bool = True, beta_rad=None) -> list[ET]:
    """Standard DH rows ``(a_mm, alpha_rad, d_mm, theta_rad)`` → ETs Rz(θ+q) Tz(d) Tx(a) Rx(α) [Ry(β)].

    Joint i (0-based) is revolute (about z, θ offset) or prismatic (along z, d offset). Slots
    ``link{i+1}.dtheta_rad/dd_mm/da_mm/dalpha_rad`` and ``link{i+1}.beta_rad`` where α ≡ 0 (mod π)
    and ``beta``. ``beta_rad`` (n_links,) optional: per link None (the rule above) or the nominal β of a
    link in Hayati's form whatever its α (a nearly parallel next axis, e.g. read from a URDF): it gets the
    Ry(β) transform, with the slot where ``beta``.
    """
    out = []
    signs = [1.0] * len(rows) if signs is None else signs
    betas = [None] * len(rows) if beta_rad is None else list(beta_rad)
    for i, ((a, al, d, th), jt, sg, b) in enumerate(zip(rows, joint_types, signs, betas)):
        s = (lambda n, i=i: f"link{i + 1}.{n}") if slots else (lambda n: None)
        rev = jt == "revolute"
        out.append(et("rz", th, joint=i if rev else None, sign=sg, slot=s("dtheta_rad")))
        out.append(et("tz", d, joint=None if rev else i, sign=sg, slot=s("dd_mm")))
        out.append(et("tx", a, slot=s("da_mm")))
        out.append(et("rx", al, slot=s("dalpha_rad")))
        hayati = parallel_axes(al) if b is None else True
        if beta and slots and hayati:
            out.append(et("ry", b or 0.0, slot=s("beta_rad")))
        elif b:
            out.append(et("ry", b))
    return out


def mdh_ets(rows, joint_types, signs=None, slots: bool = True, beta: bool = True) -> list[ET]:
    """Modified DH rows ``(a_prev_mm, alpha_prev_rad, d_mm, theta_rad)`` → Rx(α) [Ry(β)] Tx(a) Rz(θ+q) Tz(d)."""
    out = []
    signs = [1.0] * len(rows) if signs is None else signs
    for i, ((a, al, d, th), jt, sg) in enumerate(zip(rows, joint_types, signs)):
        s = (lambda n, i=i: f"link{i + 1}.{n}") if slots else (lambda n: None)
        rev = jt == "revolute"
        out.append(et("rx", al, slot=s("dalpha_rad")))
        if beta and slots and parallel_axes(al):
            out.append(et("ry", 0.0, slot=s("beta_rad")))
        out.append(et("tx", a, slot=s("da_mm")))
        out.append(et("rz", th, joint=i if rev else None, sign=sg, slot=s("dtheta_rad")))
        out.append(et("tz", d, joint=None if rev else i, sign=sg, slot=s("dd_mm")))
    return out


@dataclass
class Chain:
    """A compiled serial chain (build with :meth:`compile`). ``param_names`` are the error slots
    in chain order; ``joints`` the joints in order."""

    name: str
    ets: tuple
    joints: tuple
    param_names: tuple
    kind_r: np.ndarray = field(repr=False)
    axis: np.ndarray = field(repr=False)
    value: np.ndarray = field(repr=False)
    joint: np.ndarray = field(repr=False)
    sign: np.ndarray = field(repr=False)
    slot: np.ndarray = field(repr=False)
    coef: np.ndarray = field(default=None, repr=False)
    path: str = ""
    sha256: str = ""
    kind: str = "serial"
    convention: str = "et"

    @classmethod
    def compile(cls, ets, joints, name: str = "chain", shared_slots: bool = False, slot_order=None, **kw) -> "Chain":
        """Check and compile ETs and joints once into index arrays. ``shared_slots``: a slot name may
        enter several ETs (one parameter); otherwise a repeated name is refused. ``slot_order``: the
        parameter order (every slot name once); default the order of first appearance."""
        ets = tuple(ets)
        joints = tuple(joints)
        names = [e.slot for e in ets if e.slot is not None]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup and not shared_slots:
            raise ValueError(f"duplicate error slot names {dup}")
        names = list(dict.fromkeys(names))
        if slot_order is not None:
            if sorted(slot_order) != sorted(names) or len(set(slot_order)) != len(names):
                raise ValueError(f"slot_order {list(slot_order)} is not a permutation of the chain's slots {names}")
            names = list(slot_order)
        used = sorted({e.joint for e in ets if e.joint is not None})
        if used != list(range(len(joints))):
            raise ValueError(f"joints {[j.name for j in joints]} must each drive at least one transform")
        for e in ets:
            if e.joint is not None and (joints[e.joint].type == "revolute") != (e.kind == "r"):
                raise ValueError(f"joint {joints[e.joint].name!r} ({joints[e.joint].type}) drives a {e.type} transform")
        index = {n: k for k, n in enumerate(names)}
        slot = np.array([-1 if e.slot is None else index[e.slot] for e in ets], dtype=np.int64)
        return cls(name=name, ets=ets, joints=joints, param_names=tuple(names),
                   kind_r=np.array([e.kind == "r" for e in ets]), axis=np.array([e.axis for e in ets]),
                   value=np.array([e.value for e in ets]),
                   joint=np.array([-1 if e.joint is None else e.joint for e in ets]),
                   sign=np.array([e.sign for e in ets]), slot=slot,
                   coef=np.array([e.coef for e in ets]), **kw)

    def __post_init__(self):
        if self.coef is None:
            self.coef = np.ones(len(self.ets))

    @property
    def plain_slots(self) -> bool:
        """Every slot in one ET with coefficient 1, in chain order (an arm): the selection path."""
        s = self.slot[self.slot >= 0]
        return bool(np.array_equal(s, np.arange(self.n_params)) and np.all(self.coef[self.slot >= 0] == 1.0))

    def slot_matrix(self) -> np.ndarray:
        """``S`` (n_et, n_params): ``S[k, p]`` the coefficient with which slot p enters ET k."""
        S = np.zeros((len(self.ets), self.n_params))
        k = np.flatnonzero(self.slot >= 0)
        np.add.at(S, (k, self.slot[k]), self.coef[k])
        return S

    # -- sizes ---------------------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    @property
    def joint_columns(self) -> list[str]:
        return [j.column for j in self.joints]

    @property
    def joint_lo(self) -> np.ndarray:
        return np.array([j.lo for j in self.joints])

    @property
    def joint_hi(self) -> np.ndarray:
        return np.array([j.hi for j in self.joints])

    def _joint_scale(self) -> np.ndarray:
        """Joint unit → internal unit (deg → rad, mm → mm), shape (nq,)."""
        return np.array([np.pi / 180 if j.type == "revolute" else 1.0 for j in self.joints])

    # -- kinematics ----------------------------------------------------------------------------
    def et_values(self, q, errors=None) -> np.ndarray:
        """Value of every ET per pose, shape (n, n_et): constant + sign*joint + coef*error.
        ``errors`` shape (n_params,) (the same for every pose) or (n, n_params) (per pose)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if q.shape[1] != self.n_joints:
            raise ValueError(f"expected q of shape (n, {self.n_joints}), got {q.shape}")
        v = np.broadcast_to(self.value, (q.shape[0], len(self.ets))).copy()
        jm = self.joint >= 0
        v[:, jm] += self.sign[jm] * (q * self._joint_scale())[:, self.joint[jm]]
        if errors is not None:
            e = np.asarray(errors, dtype=float)
            sm = self.slot >= 0
            if e.shape == (self.n_params,):
                v[:, sm] += e[self.slot[sm]] * self.coef[sm]
            elif e.shape == (q.shape[0], self.n_params):
                v[:, sm] += e[:, self.slot[sm]] * self.coef[sm]
            else:
                raise ValueError(f"expected errors of shape ({self.n_params},) or ({q.shape[0]}, {self.n_params}), "
                                 f"got {e.shape}")
        return v

    def frames(self, q, errors=None) -> np.ndarray:
        """Cumulative frames before each ET and after the last, shape (n, n_et + 1, 4, 4)."""
        from ._chain_frames import chain_frames   # numba: loaded with the first frames, not with the module
        v = self.et_values(q, errors)
        n, m = v.shape
        cs, sn = np.zeros((n, m)), np.zeros((n, m))
        for k in np.flatnonzero(self.kind_r):   # per column, as numpy gave them before the compiled pass
            cs[:, k], sn[:, k] = np.cos(v[:, k]), np.sin(v[:, k])
        F = np.empty((n, m + 1, 4, 4))
        chain_frames(v, cs, sn, self.kind_r, self.axis, F)
        return F

    def fk(self, q, errors=None) -> np.ndarray:
        """Tool frame in the base (world) frame, shape (n, 4, 4)."""
        return self.frames(q, errors)[:, -1]

    def tool_point(self, q, errors=None) -> np.ndarray:
        """Tool point, mm, shape (n, 3)."""
        return self.frames(q, errors)[:, -1, :3, 3]

    def _columns(self, F) -> tuple[np.ndarray, np.ndarray]:
        """Per ET the tool-point displacement and the rotation per unit value, each (n, 3, n_et)."""
        from ._chain_frames import chain_columns   # numba (as frames): the array expressions' bits, one pass
        n, m = F.shape[0], len(self.ets)
        lin, ang = np.empty((n, m, 3)), np.empty((n, m, 3))   # (n, m, 3), viewed as (n, 3, m) below
        chain_columns(np.ascontiguousarray(F, dtype=float), self.kind_r, self.axis, lin, ang)
        return np.moveaxis(lin, 1, 2), np.moveaxis(ang, 1, 2)

    def error_jacobian(self, q, errors=None, frames=None, orientation: bool = False) -> np.ndarray:
        """∂(tool point [, rotation vector of the tool frame, world axes])/∂(error parameters), shape
        (n, 3 or 6, n_params) (mm resp. rad per mm or per rad; with coefficients, per unit of the slot: a
        slot in several ETs sums their columns)."""
        F = self.frames(q, errors) if frames is None else frames
        lin, ang = self._columns(F)
        cols = np.concatenate([lin, ang], axis=1) if orientation else lin
        if self.plain_slots:
            return cols[:, :, self.slot >= 0]
        return cols @ self.slot_matrix()

    def joint_jacobian(self, q, errors=None, orientation: bool = False, frames=None) -> np.ndarray:
        """∂(tool point [, rotation vector])/∂(joint values in their units), shape (n, 3 or 6, nq)."""
        F = self.frames(q, errors) if frames is None else frames
        lin, ang = self._columns(F)
        cols = np.concatenate([lin, ang], axis=1) if orientation else lin
        J = np.zeros(cols.shape[:2] + (self.n_joints,))
        for k in np.flatnonzero(self.joint >= 0):
            J[:, :, self.joint[k]] += self.sign[k] * cols[:, :, k]
        return J * self._joint_scale()

    def describe(self) -> dict:
        """The chain as plain data (ETs, joints, error slots) for JSON documents."""
        return {"name": self.name, "convention": self.convention,
                "joints": [{"name": j.name, "type": j.type, "limits": [j.lo, j.hi], "unit": j.unit} for j in self.joints],
                "ets": [{"type": e.type, "value": e.value, "joint": None if e.joint is None else self.joints[e.joint].name,
                         "sign": e.sign, "slot": e.slot} for e in self.ets],
                "param_names": list(self.param_names)}
