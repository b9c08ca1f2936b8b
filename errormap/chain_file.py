"""Machine files of ``kind = "serial"``: a serial chain as a DH / modified-DH table, an ET list or a URDF.

``convention`` ``"dh"`` | ``"mdh"`` (``[[link]]`` rows: ``dh = [a_mm, alpha_deg, d_mm, theta_deg]``, joint
``limits`` deg or mm), ``"et"`` (``[[et]]``: ``tx ty tz`` mm, ``rx ry rz`` deg, fixed or a joint) or ``"urdf"``
(``[urdf]``: the chain between two links, :mod:`errormap.urdf`); optional ``[base]``, ``[tool]`` (mm) and
``[errors]`` (``beta``, ``base``, ``tool`` slots). Schema, version 1, with a full example:
``docs/reference/file-formats.md`` (serial arms). Every error names the file, the table and the key and
raises :class:`MachineFileError`.
"""
from __future__ import annotations

import numpy as np

from .chain import ET_TYPES, Chain, Joint, base_ets, dh_ets, et, mdh_ets, tool_ets
from .machine_checks import (MachineFileError, check_array, check_known_keys, check_number, check_range, check_table,
                             optional_table, short_repr)

SERIAL_SCHEMA_VERSION = 1
JOINT_TYPES = ("revolute", "prismatic")
ORTHONORMAL_TOL = 1e-6   # |R Rᵀ − I| of a base rotation typed with 7+ significant digits
RADIAN_LIKE = (np.pi / 2, np.pi, np.pi / 4)  # an α of 1.5708 is π/2 in radians, not 1.57°
RADIAN_LIKE_TOL = 1e-3
# Units by content (a length column holding degrees, a file or a tool point in metres):
ANGLE_MAX_DEG = 360.0          # a DH angle beyond ±360° is no angle anyone writes: a length in its column
RIGHT_ANGLES_DEG = (90.0, 180.0, 270.0, 360.0)  # what an angle column holds; a length column of only these is angles
ANGLE_COLUMN_MIN = 2           # nonzero entries a length column needs before its pattern says "degrees": one
                               # 90 or 180 mm link is a plausible length (real arms have them), two and none else not
METRES_REACH_MM = 10.0         # every length of the chain (links + tool) adds up to under 10 mm: metres typed as mm
TOOL_METRES_RATIO = 1e-3       # a nonzero tool point under 1/1000 of the links' summed lengths: metres (a 31 mm
                               # reflector on a 1.2 m UR5 is 0.026 of it; the same point in metres 2.6e-5)


def _joint_limits(d: dict, where: str, jtype: str, path) -> tuple[float, float]:
    if "limits" not in d:
        raise MachineFileError(f"{path}: missing key '{where}.limits'")
    return check_range(d["limits"], f"{where}.limits", path, jtype == "revolute", "revolute limits")


def _joint(d: dict, where: str, path, names: set) -> tuple[Joint, float]:
    name = d.get("joint")
    if not isinstance(name, str) or not name.isidentifier():
        raise MachineFileError(f"{path}: key '{where}.joint': expected a joint name (identifier), got {short_repr(name)}")
    if name in names:
        raise MachineFileError(f"{path}: key '{where}.joint': duplicate joint name {name!r}")
    names.add(name)
    jtype = d.get("type", "revolute")
    if jtype not in JOINT_TYPES:
        raise MachineFileError(f"{path}: key '{where}.type': expected one of {list(JOINT_TYPES)}, got {short_repr(jtype)}")
    lo, hi = _joint_limits(d, where, jtype, path)
    sign = check_number(d, "direction", where, path) if "direction" in d else 1.0
    if sign not in (1.0, -1.0):
        raise MachineFileError(f"{path}: key '{where}.direction': expected 1 or -1, got {short_repr(d['direction'])}")
    return Joint(name, jtype, lo, hi), sign


def _tables(items, array: str, convention: str, path):
    """``(where, table)`` of each entry of the table array ``[[array]]``: a non-empty list of tables."""
    if not isinstance(items, list) or not items:
        raise MachineFileError(f"{path}: missing or empty table array '[[{array}]]' (convention {convention!r})")
    for i, d in enumerate(items):
        where = f"{array}[{i}]"
        if not isinstance(d, dict):
            raise MachineFileError(f"{path}: '{where}': expected a table, got {short_repr(d)}")
        yield where, d


def _dh_links(links, path, convention: str):
    rows, types, signs, joints, names = [], [], [], [], set()
    for where, d in _tables(links, "link", convention, path):
        check_known_keys(d, ("joint", "type", "dh", "limits", "direction"), where, path)
        j, sign = _joint(d, where, path, names)
        if "dh" not in d:
            raise MachineFileError(f"{path}: missing key '{where}.dh' ([a_mm, alpha_deg, d_mm, theta_deg])")
        if not isinstance(d["dh"], list) or len(d["dh"]) != 4:
            n = len(d["dh"]) if isinstance(d["dh"], list) else "no"
            raise MachineFileError(f"{path}: key '{where}.dh': expected 4 columns [a_mm, alpha_deg, d_mm, theta_deg], "
                                   f"got {n} ({short_repr(d['dh'])})")
        a, al, dd, th = check_array(d["dh"], (4,), f"{where}.dh", path)
        for v, col in ((al, "alpha_deg"), (th, "theta_deg")):
            if abs(v) > ANGLE_MAX_DEG:
                raise MachineFileError(f"{path}: key '{where}.dh' ({col}): {v:g} is beyond ±{ANGLE_MAX_DEG:g}°: a length "
                                       "in mm where an angle in degrees is expected? (columns [a_mm, alpha_deg, d_mm, "
                                       "theta_deg])")
            if v != 0 and any(abs(abs(v) - r) < RADIAN_LIKE_TOL for r in RADIAN_LIKE):
                raise MachineFileError(f"{path}: key '{where}.dh' ({col}): {v:g} is a multiple of π in radians; "
                                       "angles are in degrees")
        rows.append((a, np.radians(al), dd, np.radians(th)))
        types.append(j.type)
        signs.append(sign)
        joints.append(j)
    return rows, types, signs, joints


def _et_list(items, path):
    ets, joints, names = [], [], set()
    for where, d in _tables(items, "et", "et", path):
        check_known_keys(d, ("type", "value", "joint", "limits", "direction", "error"), where, path)
        t = d.get("type")
        if t not in ET_TYPES:
            raise MachineFileError(f"{path}: key '{where}.type': expected one of {list(ET_TYPES)}, got {short_repr(t)}")
        rot = t[0] == "r"
        if "joint" in d:
            if "value" in d:
                raise MachineFileError(f"{path}: key '{where}.value': a joint transform takes no value")
            dj = dict(d)
            dj.setdefault("type", None)
            dj["type"] = "revolute" if rot else "prismatic"
            j, sign = _joint({k: v for k, v in dj.items() if k in ("joint", "type", "limits", "direction")},
                             where, path, names)
            slot = d.get("error")
            if slot is not None and (not isinstance(slot, str) or not slot):
                raise MachineFileError(f"{path}: key '{where}.error': expected a slot name, got {short_repr(slot)}")
            ets.append(et(t, 0.0, joint=len(joints), sign=sign,
                          slot=None if slot is None else f"{j.name}.{slot}_{'rad' if rot else 'mm'}"))
            joints.append(j)
        else:
            for k in ("limits", "direction"):
                if k in d:
                    raise MachineFileError(f"{path}: key '{where}.{k}': only a joint transform has {k}")
            if "error" in d:
                raise MachineFileError(f"{path}: key '{where}.error': an error slot on a fixed transform; link errors "
                                       "belong to a [[link]] table (convention dh/mdh) or to a joint's offset")
            v = check_number(d, "value", where, path)
            ets.append(et(t, np.radians(v) if rot else v))
    return ets, joints


def _is_right_angle(v: float) -> bool:
    return any(abs(abs(v) - r) < 1e-9 for r in RIGHT_ANGLES_DEG)


def check_length_units(lengths, tool_mm, path) -> None:
    """Refuse lengths that are degrees or metres, by content. ``lengths``: ``(key, column, value_mm)`` of
    every fixed length of the chain (a DH row's a and d, an ET translation), in file order; ``tool_mm``
    (3,). Three patterns: a length column whose nonzero entries (at least ``ANGLE_COLUMN_MIN``) are all
    right angles (degrees in the wrong column); every length together under ``METRES_REACH_MM`` (a file
    in metres); a nonzero tool point under ``TOOL_METRES_RATIO`` of the links' lengths (a tool in metres)."""
    for col in dict.fromkeys(c for _, c, _ in lengths):
        nz = [(k, v) for k, c, v in lengths if c == col and v != 0]
        if len(nz) >= ANGLE_COLUMN_MIN and all(_is_right_angle(v) for _, v in nz):
            key, v = nz[0]
            raise MachineFileError(f"{path}: key '{key}' ({col}): {v:g}; every nonzero {col} of the chain is a right "
                                   f"angle ({', '.join(f'{x:g}' for _, x in nz)}): degrees where lengths in mm are "
                                   "expected? (dh columns are [a_mm, alpha_deg, d_mm, theta_deg])")
    links_mm = float(sum(abs(v) for _, _, v in lengths))
    tool_norm = float(np.linalg.norm(tool_mm))
    if 0 < links_mm + tool_norm < METRES_REACH_MM:
        key, col, v = max(lengths, key=lambda t: abs(t[2])) if links_mm >= tool_norm else ("tool.xyz_mm", "", tool_norm)
        raise MachineFileError(f"{path}: key '{key}'{f' ({col})' if col else ''}: every length of the chain adds up "
                               f"to {links_mm + tool_norm:.4g} mm (largest {abs(v):g}): metres rather than mm? "
                               "(lengths are in mm)")
    if 0 < tool_norm < TOOL_METRES_RATIO * links_mm:
        raise MachineFileError(f"{path}: key 'tool.xyz_mm': a tool point {tool_norm:.4g} mm from the last frame on a "
                               f"chain whose links add up to {links_mm:.4g} mm: metres rather than mm? (lengths are "
                               "in mm; the flange point itself is [0, 0, 0])")


def _rotation(b: dict, path) -> np.ndarray:
    if "rotation" not in b:
        return np.eye(3)
    R = check_array(b["rotation"], (3, 3), "base.rotation", path)
    if np.abs(R @ R.T - np.eye(3)).max() > ORTHONORMAL_TOL or np.linalg.det(R) < 0:
        raise MachineFileError(f"{path}: key 'base.rotation': not an orthonormal right-handed rotation "
                               f"(|R Rᵀ − I| = {np.abs(R @ R.T - np.eye(3)).max():.3g}, det {np.linalg.det(R):.6g})")
    return R


def parse_serial(doc: dict, path, sha: str = "") -> Chain:
    """Validate a parsed ``kind = "serial"`` machine file and compile its chain."""
    check_known_keys(doc, ("machine", "link", "et", "urdf", "base", "tool", "errors"), "", path)
    m = check_table(doc, "machine", path)
    check_known_keys(m, ("kind", "name", "schema", "convention", "description"), "machine", path)
    name = m.get("name", "serial")
    if not isinstance(name, str):
        raise MachineFileError(f"{path}: key 'machine.name': expected a string, got {short_repr(name)}")
    ver = m.get("schema", SERIAL_SCHEMA_VERSION)
    if ver != SERIAL_SCHEMA_VERSION:
        raise MachineFileError(f"{path}: key 'machine.schema': this volcomp reads serial schema "
                               f"{SERIAL_SCHEMA_VERSION}, got {short_repr(ver)}")
    conv = m.get("convention")
    if conv not in ("dh", "mdh", "et", "urdf"):
        raise MachineFileError(f"{path}: key 'machine.convention': expected one of ['dh', 'mdh', 'et', 'urdf'], got "
                               f"{short_repr(conv)}")
    body_table = {"dh": "link", "mdh": "link", "et": "et", "urdf": "urdf"}
    for other in ("link", "et", "urdf"):
        if other in doc and other != body_table[conv]:
            raise MachineFileError(f"{path}: key 'machine.convention': {conv!r} does not go with "
                                   f"{'[urdf]' if other == 'urdf' else f'[[{other}]]'}")
    e = optional_table(doc, "errors", path, {})
    check_known_keys(e, ("beta", "base", "tool"), "errors", path)
    flags = {}
    for k in ("beta", "base", "tool"):
        v = e.get(k, True)
        if not isinstance(v, bool):
            raise MachineFileError(f"{path}: key 'errors.{k}': expected true or false, got {short_repr(v)}")
        flags[k] = v
    b = optional_table(doc, "base", path, {})
    check_known_keys(b, ("xyz_mm", "rotation"), "base", path)
    base_xyz = check_array(b["xyz_mm"], (3,), "base.xyz_mm", path) if "xyz_mm" in b else np.zeros(3)
    R = _rotation(b, path)
    from scipy.spatial.transform import Rotation
    rx, ry, rz = Rotation.from_matrix(R).as_euler("ZYX")[::-1]  # R = Rz Ry Rx
    t = check_table(doc, "tool", path)
    check_known_keys(t, ("xyz_mm",), "tool", path)
    if "xyz_mm" not in t:
        raise MachineFileError(f"{path}: missing key 'tool.xyz_mm'")
    tool = check_array(t["xyz_mm"], (3,), "tool.xyz_mm", path)
    if conv == "urdf":   # lengths in metres by the URDF's own definition: no unit guessing
        from .urdf import urdf_table_chain
        world_T = np.eye(4)
        world_T[:3, :3], world_T[:3, 3] = R, base_xyz
        return urdf_table_chain(doc, path, flags, world_T, tool, name, sha)
    if conv == "et":
        body, joints = _et_list(doc.get("et"), path)
        lengths = [(f"et[{i}].value", "translation", e.value) for i, e in enumerate(body)
                   if e.kind == "t" and e.joint is None]
    else:
        rows, types, signs, joints = _dh_links(doc.get("link"), path, conv)
        body = (dh_ets if conv == "dh" else mdh_ets)(rows, types, signs, beta=flags["beta"])
        lengths = [(f"link[{i}].dh", col, v) for i, r in enumerate(rows) for col, v in (("a_mm", r[0]), ("d_mm", r[2]))]
    check_length_units(lengths, tool, path)
    ets = base_ets(base_xyz, (rx, ry, rz), slots=flags["base"]) + body + tool_ets(tool, slots=flags["tool"])
    try:
        return Chain.compile(ets, joints, name=name, path=str(path), sha256=sha, convention=conv)
    except ValueError as exc:
        raise MachineFileError(f"{path}: {exc}") from None
