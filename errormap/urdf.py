"""An arm's nominal chain from a URDF: the joint axes between two links, as a standard DH table.

The path from a base link to a tip link (parsed by ``urdf_parser_py``; line numbers from ``lxml``) becomes
the same chain and error slots a DH machine file gives (:func:`errormap.chain.dh_ets`): the joint axes at the
zero configuration in the base link's frame, DH frame k on axis k by the common normal (:func:`dh_from_axes`;
nearly parallel axes within :data:`NEARLY_PARALLEL_RAD` get a Hayati β); the frame conventions:
``docs/reference/arm-calibration.md``. URDF metres and radians become mm and deg; a ``continuous`` joint gets
[-360, 360] deg. Refused, naming the element and its line: a floating, planar or mimic joint on the path, a
value that is not a finite number (nan, inf), an axis of zero or non-unit length, joint origins adding up to
over 100 m (a URDF in mm), a revolute/prismatic joint without limits, a base link that is not an ancestor of the
tip, an unknown link, a file that is no ``<robot>`` XML."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from .chain import Chain, Joint, base_ets, dh_ets, et, tool_ets
from .machine_checks import MachineFileError

M_TO_MM = 1000.0
NEARLY_PARALLEL_RAD = 1e-2
"""Consecutive axes closer than this to parallel take Hayati's form (d = 0, a nominal β and its slot): their common
normal would lie at least 100 × their offset away (a calibrated URDF's 1e-3 rad tilt: 1,000 ×), a DH table there is
ill-conditioned to calibrate and loses digits (measured 3.6e-9 mm of forward kinematics at a 1e-4 rad tilt)."""
ON_AXIS_TOL_MM = 1e-9      # a point nearer an axis than this lies on it (θ = 0, a = 0)
AXIS_NORM_TOL = 1e-6       # |‖axis‖ − 1| above this: a non-unit axis (URDF axes are unit vectors)
TINY_RAD = 1e-14           # a fixed tip rotation smaller than this (round-off of rpy sums) is dropped
CONTINUOUS_LIMITS_DEG = (-360.0, 360.0)
MM_AS_M_REACH_MM = 1e5     # joint origins adding up to over 100 m: a URDF written in mm (URDF lengths are metres)
MOVING = ("revolute", "continuous", "prismatic")


def is_urdf(raw: bytes) -> bool:
    """Whether ``raw`` is XML (its first non-blank byte ``<``): a URDF candidate, never TOML."""
    return raw.removeprefix(b"\xef\xbb\xbf").lstrip()[:1] == b"<"


def _rot(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _origin(joint) -> np.ndarray:
    """The joint's origin transform, (4, 4), translation in mm."""
    T = np.eye(4)
    if joint.origin is not None:
        T[:3, :3] = _rot(joint.origin.rpy or (0.0, 0.0, 0.0))
        T[:3, 3] = np.asarray(joint.origin.xyz or (0.0, 0.0, 0.0), float) * M_TO_MM
    return T


def _zyx(R) -> tuple[float, float, float]:
    """(rx, ry, rz) with R = Rz(rz) Ry(ry) Rx(rx)."""
    from scipy.spatial.transform import Rotation
    rz, ry, rx = Rotation.from_matrix(R).as_euler("ZYX")
    return float(rx), float(ry), float(rz)


class URDFChainError(MachineFileError):
    """A URDF the chain cannot represent exactly (names the file, element and line)."""


def read_urdf(raw: bytes, path):
    """(robot model, ``{("joint"|"link", name): line}``) of a URDF's bytes; refuses what is no ``<robot>`` XML."""
    from lxml import etree
    try:
        root = etree.fromstring(raw.removeprefix(b"\xef\xbb\xbf"))
    except etree.XMLSyntaxError as exc:
        raise URDFChainError(f"{path}: not well-formed XML: {exc}") from None
    if root.tag != "robot":
        raise URDFChainError(f"{path}: line {root.sourceline}: root element <{root.tag}>; a URDF's root is <robot>")
    lines = {(el.tag, el.get("name")): el.sourceline for el in root if el.tag in ("joint", "link")}
    import contextlib
    import io
    from urdf_parser_py.urdf import URDF
    try:
        with contextlib.redirect_stderr(io.StringIO()):   # the parser prints unknown tags (gazebo, transmission)
            robot = URDF.from_xml_string(etree.tostring(root))
    except Exception as exc:   # the parser raises plain exceptions (AssertionError, ParseError, KeyError)
        raise URDFChainError(f"{path}: not a readable URDF: {type(exc).__name__}: {exc}") from None
    return robot, lines


def _leaves(robot) -> list[str]:
    parents = {j.parent for j in robot.joints}
    return [lk.name for lk in robot.links if lk.name not in parents]


def chain_path(robot, lines, path, base_link=None, tip_link=None) -> list:
    """The joints from ``base_link`` (default the root) to ``tip_link`` (default the only leaf), in order."""
    names = [lk.name for lk in robot.links]
    for key, link in (("base_link", base_link), ("tip_link", tip_link)):
        if link is not None and link not in names:
            raise URDFChainError(f"{path}: {key} {link!r} is no link of robot {robot.name!r}; links: {names}")
    undefined = [j for j in robot.joints if j.parent not in names or j.child not in names]
    if undefined:
        j = undefined[0]
        link = j.parent if j.parent not in names else j.child
        raise URDFChainError(f"{path}: line {lines.get(('joint', j.name))}: joint {j.name!r} names link {link!r}, which "
                             f"the file does not define (<link name=...>); links: {names}")
    roots = [n for n in names if n not in {j.child for j in robot.joints}]
    if not roots:
        raise URDFChainError(f"{path}: no root link: every link is a joint's child (the joints form a loop); a URDF "
                             "is one tree")
    if len(roots) != 1:
        raise URDFChainError(f"{path}: line {lines.get(('link', roots[-1]))}: {len(roots)} root links {roots}; a URDF "
                             "is one tree")
    base = base_link or roots[0]
    if tip_link is None:
        leaves = _leaves(robot)
        if len(leaves) != 1:
            raise URDFChainError(f"{path}: robot {robot.name!r} has {len(leaves)} leaf links {leaves}: name the tip "
                                 "(tip_link in a serial machine file's [urdf] table)")
        tip_link = leaves[0]
    by_child = {j.child: j for j in robot.joints}
    out, link = [], tip_link
    while link != base:
        if link not in by_child:
            raise URDFChainError(f"{path}: line {lines.get(('link', base))}: link {base!r} is not an ancestor of the "
                                 f"tip link {tip_link!r}: a chain runs from a base link down to its tip")
        j = by_child[link]
        out.append(j)
        link = j.parent
    return out[::-1]


def _check_joint(j, where) -> None:
    if j.type not in MOVING + ("fixed",):
        raise URDFChainError(f"{where}: joint {j.name!r} of type {j.type!r}: a serial chain takes revolute, "
                             "continuous, prismatic and fixed joints only")
    if j.mimic is not None and j.type != "fixed":
        raise URDFChainError(f"{where}: joint {j.name!r} mimics joint {j.mimic.joint!r}: a chain's joints are "
                             "independent (model the coupled joint as one joint)")
    for what, v in (("<origin xyz>", getattr(j.origin, "xyz", None)), ("<origin rpy>", getattr(j.origin, "rpy", None)),
                    ("<axis xyz>", j.axis), ("<limit lower>", getattr(j.limit, "lower", None)),
                    ("<limit upper>", getattr(j.limit, "upper", None))):
        if v is not None and not np.all(np.isfinite(np.asarray(v, float))):
            raise URDFChainError(f"{where}: joint {j.name!r}: {what} {np.asarray(v, float).tolist()} is not a finite "
                                 "number")
    if j.type == "fixed":
        return
    ax = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), float)
    if abs(np.linalg.norm(ax) - 1.0) > AXIS_NORM_TOL:
        raise URDFChainError(f"{where}: joint {j.name!r}: <axis xyz> {ax.tolist()} has length "
                             f"{np.linalg.norm(ax):.6g}; a URDF axis is a unit vector")
    if j.type != "continuous" and (j.limit is None or j.limit.lower is None or j.limit.upper is None
                                   or not j.limit.upper > j.limit.lower):
        raise URDFChainError(f"{where}: joint {j.name!r} ({j.type}): needs <limit lower upper> with upper > lower")


def axes_at_zero(joints, path, lines):
    """Per moving joint its axis line at the zero configuration in the base link's frame: points (m, 3) mm,
    unit directions (m, 3); the tip link's frame (4, 4); the moving joints."""
    T = np.eye(4)
    pts, dirs, moving = [], [], []
    for j in joints:
        _check_joint(j, f"{path}: line {lines.get(('joint', j.name))}")
    reach = [np.linalg.norm(_origin(j)[:3, 3]) for j in joints]
    if sum(reach) > MM_AS_M_REACH_MM:
        j = joints[int(np.argmax(reach))]
        raise URDFChainError(f"{path}: line {lines.get(('joint', j.name))}: joint {j.name!r}: <origin xyz> "
                             f"{list(j.origin.xyz)} — the chain's origins add up to {sum(reach) / M_TO_MM:.4g} m: "
                             "millimetres rather than metres? (URDF lengths are metres)")
    for j in joints:
        T = T @ _origin(j)
        if j.type != "fixed":
            ax = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), float)
            pts.append(T[:3, 3].copy())
            dirs.append(T[:3, :3] @ (ax / np.linalg.norm(ax)))
            moving.append(j)
    if not moving:
        raise URDFChainError(f"{path}: no moving joint between the base and tip links")
    return np.array(pts), np.array(dirs), T, moving


def _frame(z, origin, x_hint) -> np.ndarray:
    x = x_hint - (x_hint @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    F = np.eye(4)
    F[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    F[:3, 3] = origin
    return F


def _toward(r) -> tuple[float, float]:
    """(θ, a) placing x along ±r (r in the frame's xy plane) with |θ| ≤ 90°: a signed, (0, 0) for r on the axis."""
    if np.hypot(r[0], r[1]) < ON_AXIS_TOL_MM:
        return 0.0, 0.0
    a = float(np.hypot(r[0], r[1]))
    if r[0] < 0 or (r[0] == 0 and r[1] < 0):
        a = -a
    return float(np.arctan2(r[1] / a, r[0] / a)), a


def _link(F, p, u) -> tuple[tuple, float]:
    """DH row (a, α, d, θ) and nominal β from frame F (z on the current axis) to the axis line (p, u) (base frame)."""
    R = F[:3, :3]
    p, u = R.T @ (p - F[:3, 3]), R.T @ u
    s = np.hypot(u[0], u[1])
    if s < np.sin(NEARLY_PARALLEL_RAD):       # (nearly) parallel: Hayati, d = 0, x toward the next axis
        th, a = _toward(p - (p[2] / u[2]) * u)
        c, sn = np.cos(th), np.sin(th)
        ur = np.array([c * u[0] + sn * u[1], -sn * u[0] + c * u[1], u[2]])
        return (a, float(np.arctan2(-ur[1] + 0.0, ur[2])), 0.0, th), float(np.arcsin(np.clip(ur[0], -1, 1)))
    b = u[2]                                   # skew: the common normal
    t1 = (b * (-u @ p) + p[2]) / (s * s)           # s² = 1 − b², without its cancellation near parallel
    t2 = ((-u @ p) + b * p[2]) / (s * s)
    n = np.cross([0.0, 0.0, 1.0], u) / s
    if n[0] < 0 or (n[0] == 0 and n[1] < 0):
        n = -n
    a = float((p + t2 * u - np.array([0.0, 0.0, t1])) @ n)
    al = float(np.arctan2(-u @ np.cross([0.0, 0.0, 1.0], n), u[2]))
    return (a, al, float(t1), float(np.arctan2(n[1], n[0]))), None


def _dh_T(row, beta) -> np.ndarray:
    a, al, d, th = row
    ca, sa, ct, st, cb, sb = np.cos(al), np.sin(al), np.cos(th), np.sin(th), np.cos(beta), np.sin(beta)
    Rz = np.array([[ct, -st, 0], [st, ct, 0], [0, 0, 1.0]])
    Rx = np.array([[1.0, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1.0, 0], [-sb, 0, cb]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Rx @ Ry
    T[:3, 3] = Rz @ np.array([a, 0.0, d])
    return T


def dh_from_axes(pts, dirs, tip_T):
    """Standard DH rows (m, 4) ``(a_mm, α_rad, d_mm, θ_rad)``, per link its nominal Hayati β or None (skew axes),
    base link → frame 0 (4, 4) and
    frame m → tip link rotation (3, 3) from the axis lines ``pts``/``dirs`` (m, 3) and the tip frame (4, 4)."""
    p0 = pts[0] - (pts[0] @ dirs[0]) * dirs[0]              # foot of the base origin on axis 1
    F = F0 = _frame(dirs[0], p0, np.array([1.0, 0.0, 0.0]))
    rows, betas = [], []
    for k in range(len(pts)):
        if k + 1 < len(pts):
            row, beta = _link(F, pts[k + 1], dirs[k + 1])
        else:                                                # last: origin at the tip origin's foot, α = 0
            t = F[:3, :3].T @ (tip_T[:3, 3] - F[:3, 3])
            th, a = _toward(t)
            row, beta = (a, 0.0, float(t[2]), th), None
        rows.append(row)
        betas.append(beta)
        F = F @ _dh_T(row, beta or 0.0)
    return np.array(rows), betas, F0, F[:3, :3].T @ tip_T[:3, :3]


def _limits(j) -> tuple[float, float]:
    if j.type == "continuous":
        return CONTINUOUS_LIMITS_DEG
    k = 180 / np.pi if j.type == "revolute" else M_TO_MM
    return float(j.limit.lower) * k, float(j.limit.upper) * k


def urdf_chain(raw: bytes, path, base_link=None, tip_link=None, tool_xyz_mm=(0.0, 0.0, 0.0), world_T=None,
               joint_names=None, flags=None, name=None, sha: str = "") -> Chain:
    """The nominal chain of a URDF's path ``base_link`` → ``tip_link`` (defaults: the root, the only leaf) with
    the error slots of a DH file; ``world_T`` (4, 4) a nominal frame before the base link (mm); ``joint_names``
    the joints' CSV stems (default the URDF's joint names); ``flags`` {beta, base, tool} as a machine file's
    ``[errors]``."""
    flags = {"beta": True, "base": True, "tool": True, **(flags or {})}
    robot, lines = read_urdf(raw, path)
    joints = chain_path(robot, lines, path, base_link, tip_link)
    pts, dirs, tip_T, moving = axes_at_zero(joints, path, lines)
    rows, betas, F0, R_tip = dh_from_axes(pts, dirs, tip_T)
    names = [j.name for j in moving] if joint_names is None else list(joint_names)
    if len(names) != len(moving) or len(set(names)) != len(names) or not all(str(n).isidentifier() for n in names):
        raise URDFChainError(f"{path}: joint names {names}: expected {len(moving)} distinct identifiers for the "
                             f"moving joints {[j.name for j in moving]}")
    jts = [Joint(n, "prismatic" if j.type == "prismatic" else "revolute", *_limits(j)) for n, j in zip(names, moving)]
    B = (np.eye(4) if world_T is None else world_T) @ F0
    body = dh_ets([tuple(r) for r in rows], [j.type for j in jts], beta=flags["beta"], beta_rad=betas)
    rx, ry, rz = _zyx(R_tip)
    fixed = [et(t, v) for t, v in (("rz", rz), ("ry", ry), ("rx", rx)) if abs(v) > TINY_RAD]
    ets = base_ets(B[:3, 3], _zyx(B[:3, :3]), slots=flags["base"]) + body + fixed + tool_ets(tool_xyz_mm, flags["tool"])
    digest = hashlib.sha256(sha.encode() + raw).hexdigest()
    try:
        return Chain.compile(ets, jts, name=name or robot.name, path=str(path), sha256=digest, convention="urdf")
    except ValueError as exc:
        raise URDFChainError(f"{path}: {exc}") from None


def load_urdf_machine(raw: bytes, path, sha: str = "") -> Chain:
    """``--machine robot.urdf``: the chain from the root link to the only leaf, tool point at the leaf's origin."""
    return urdf_chain(raw, path, sha=sha)


def urdf_table_chain(doc: dict, path, flags: dict, world_T, tool_mm, name, sha: str) -> Chain:
    """A serial machine file's ``[urdf]`` table (``file`` relative to the machine file, ``base_link``, ``tip_link``,
    optional ``joints``: the joints' CSV stems) → its chain."""
    from .machine_checks import check_known_keys, check_table, short_repr
    u = check_table(doc, "urdf", path)
    check_known_keys(u, ("file", "base_link", "tip_link", "joints"), "urdf", path)
    for k in ("file", "base_link", "tip_link"):
        if not isinstance(u.get(k), str) or not u.get(k):
            raise MachineFileError(f"{path}: key 'urdf.{k}': expected a string, got {short_repr(u.get(k))}")
    f = Path(path).parent / u["file"]
    if not f.is_file():
        raise MachineFileError(f"{path}: key 'urdf.file': no such file {str(f)!r} (relative to the machine file)")
    jn = u.get("joints")
    if jn is not None and not (isinstance(jn, list) and all(isinstance(x, str) for x in jn)):
        raise MachineFileError(f"{path}: key 'urdf.joints': expected a list of joint names, got {short_repr(jn)}")
    return urdf_chain(f.read_bytes(), f, u["base_link"], u["tip_link"], tool_mm, world_T, jn, flags, name, sha)
