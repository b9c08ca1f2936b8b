"""The tables of a machine-tool chain file (``kind = "machine-tool"``) read into ETs, axes and slots.

``[[work]]`` (base → workpiece) and ``[[tool]]`` (base → tool point) are ordered lists of fixed transforms and
joints (axis words ``X Y Z U V W A B C``); the slot names are derived from the chain: six component errors per
moving axis (``dx_w … ez_w``, μm / μrad, ``Trans(δ)·RotX·RotY·RotZ`` after the motion or at an ``errors_of``
marker), four location errors per rotary axis (e.g. ``dy_oa dz_oa ey_oa ez_oa``, before its rotation) and the
named squareness constants (``R(+s)·T(q)·R(−s)``). :func:`errormap.machine_tool.parse_machine_tool` compiles
the result. Schema: ``docs/how-to/machine-file.md`` and ``docs/reference/file-formats.md``."""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .chain import AXES, Joint, et
from .machine_checks import MachineFileError, check_array, check_known_keys, check_number, check_range, short_repr

CHAIN_SCHEMA_VERSION = 1
AXIS_WORDS = ("X", "Y", "Z", "U", "V", "W", "A", "B", "C")
"""Axis words in canonical order (the order of the machine's axes columns)."""
LINEAR_WORDS = ("X", "Y", "Z", "U", "V", "W")
DEFAULT_ALONG = {"X": "x", "Y": "y", "Z": "z", "U": "x", "V": "y", "W": "z", "A": "x", "B": "y", "C": "z"}
JOINT_KINDS = ("linear", "rotary")
COMPONENTS = ("dx", "dy", "dz", "ex", "ey", "ez")
"""The six component errors of an axis, in the order of the error transform Trans(δ)·RotX·RotY·RotZ."""
ISO_DIR = {"dx": "X", "dy": "Y", "dz": "Z", "ex": "A", "ey": "B", "ez": "C"}
UM_MM = 1e-3    # mm per μm
URAD_RAD = 1e-6  # rad per μrad
ORTHONORMAL_TOL = 1e-6   # |R Rᵀ − I| of a rotation typed with 7+ significant digits
FULL_TURN_DEG = 360.0
FULL_TURN_TOL_DEG = 1e-9  # a rotary stroke spanning 360° to this is a full turn (periodic errors)
MAX_ROTARY_ANGLE_DEG = 1e5  # a fixed rotation value beyond this is no angle (a length typed in a rotation)


@dataclass(frozen=True)
class ChainAxis:
    """One moving axis: ``word`` (X … C), ``kind`` linear|rotary, ``along`` (0, 1, 2 = x, y, z of
    the frame it moves in), ``direction`` ±1, ``stroke`` (lo, hi) in mm or deg, ``side`` work|tool."""

    word: str
    kind: str
    along: int
    direction: float
    stroke: tuple
    side: str

    @property
    def unit(self) -> str:
        return "deg" if self.kind == "rotary" else "mm"

    @property
    def column(self) -> str:
        """The axis' CSV column and stations key (``x_mm``, ``a_deg``)."""
        return f"{self.word.lower()}_{self.unit}"

    @property
    def full_turn(self) -> bool:
        """A rotary axis whose stroke spans one turn: its errors are periodic."""
        return self.kind == "rotary" and abs(self.stroke[1] - self.stroke[0] - FULL_TURN_DEG) <= FULL_TURN_TOL_DEG


@dataclass(frozen=True)
class Slot:
    """One error slot: ``name`` (volcomp), ``iso`` (ISO 230 name), ``kind`` component|location|
    squareness, ``axis`` the axis word it belongs to, ``unit`` um|urad; a component error is a
    function of its axis, the others constants."""

    name: str
    iso: str
    kind: str
    axis: str
    unit: str

    @property
    def is_function(self) -> bool:
        return self.kind == "component"


def _value(d, key, where, path, geometry):
    """A number, or a geometry constant by name (``"l5"``, ``"-theta1_deg"``)."""
    v = d.get(key)
    if isinstance(v, str):
        neg = v.startswith("-")
        name = v[1:] if neg else v
        if name not in geometry:
            raise MachineFileError(f"{path}: key '{where}.{key}': {v!r} is neither a number nor a [geometry] "
                                   f"constant (known: {sorted(geometry)})")
        return -geometry[name] if neg else geometry[name]
    return check_number(d, key, where, path)


def _rotation_ets(d, where, path):
    R = check_array(d["rotation"], (3, 3), f"{where}.rotation", path)
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > ORTHONORMAL_TOL or np.linalg.det(R) < 0:
        raise MachineFileError(f"{path}: key '{where}.rotation': not an orthonormal right-handed rotation "
                               f"(|R Rᵀ − I| = {err:.3g}, det {np.linalg.det(R):.6g})")
    from scipy.spatial.transform import Rotation
    rz, ry, rx = Rotation.from_matrix(R).as_euler("ZYX")  # R = Rz Ry Rx
    return [et("rz", rz), et("ry", ry), et("rx", rx)]


def _component_ets(word, which):
    """The error transform Trans(δ)·RotX·RotY·RotZ of axis ``word`` (slots in μm / μrad)."""
    out, slots = [], []
    for c in which:
        name = f"{c}_{word.lower()}"
        t = ("t" if c[0] == "d" else "r") + c[1]
        out.append(et(t, 0.0, slot=name, coef=UM_MM if c[0] == "d" else URAD_RAD))
        slots.append(Slot(name, f"E{ISO_DIR[c]}{word}", "component", word, "um" if c[0] == "d" else "urad"))
    return out, slots


def _component_list(d, key, where, path):
    v = d.get(key, True)
    if v is True:
        return COMPONENTS
    if v is False:
        return ()
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise MachineFileError(f"{path}: key '{where}.{key}': expected true, false or a list of {list(COMPONENTS)}, "
                               f"got {short_repr(v)}")
    bad = [x for x in v if x not in COMPONENTS]
    if bad:
        raise MachineFileError(f"{path}: key '{where}.{key}': unknown component error {bad[0]!r} "
                               f"(expected some of {list(COMPONENTS)})")
    return tuple(c for c in COMPONENTS if c in v)


def _joint_entry(d, where, path, side, words):
    check_known_keys(d, ("joint", "axis", "along", "direction", "stroke", "unit", "errors", "location", "squareness"),
                     where, path)
    kind = d.get("joint")
    if kind not in JOINT_KINDS:
        raise MachineFileError(f"{path}: key '{where}.joint': unknown joint type {short_repr(kind)} "
                               f"(expected one of {list(JOINT_KINDS)})")
    word = d.get("axis")
    if word not in AXIS_WORDS:
        raise MachineFileError(f"{path}: key '{where}.axis': expected an axis word {list(AXIS_WORDS)}, "
                               f"got {short_repr(word)}")
    if word in words:
        raise MachineFileError(f"{path}: key '{where}.axis': duplicate axis word {word!r} (already at {words[word]})")
    words[word] = where
    if (kind == "linear") != (word in LINEAR_WORDS):
        raise MachineFileError(f"{path}: key '{where}.axis': axis word {word!r} is "
                               f"{'linear' if word in LINEAR_WORDS else 'rotary'}, the joint {kind}")
    unit = "mm" if kind == "linear" else "deg"
    if "unit" in d and d["unit"] != unit:
        raise MachineFileError(f"{path}: key '{where}.unit': a {kind} axis is in {unit}, got {short_repr(d['unit'])}"
                               + (" (degrees where mm are expected)" if d["unit"] in ("deg", "rad") else ""))
    along = d.get("along", DEFAULT_ALONG[word])
    if along not in ("x", "y", "z"):
        raise MachineFileError(f"{path}: key '{where}.along': expected one of ['x', 'y', 'z'], got {short_repr(along)}")
    sign = check_number(d, "direction", where, path) if "direction" in d else 1.0
    if sign not in (1.0, -1.0):
        raise MachineFileError(f"{path}: key '{where}.direction': expected 1 or -1, got {short_repr(d['direction'])}")
    if "stroke" not in d:
        raise MachineFileError(f"{path}: missing key '{where}.stroke' ([lo, hi] in {unit})")
    stroke = check_range(d["stroke"], f"{where}.stroke", path, kind == "rotary", "rotary strokes")
    return ChainAxis(word, kind, AXES.index(along), float(sign), stroke, side)


def _squareness(d, where, path, ax: ChainAxis):
    """``R_w(+s)·[motion]·R_w(−s)`` ETs (before, after) and slots of a linear axis' squareness entries."""
    items = d.get("squareness", [])
    if not isinstance(items, list):
        raise MachineFileError(f"{path}: key '{where}.squareness': expected a list of tables "
                               "{ name = \"s_xz\", toward = \"x\", iso = \"EB0Z\" }")
    if items and ax.kind != "linear":
        raise MachineFileError(f"{path}: key '{where}.squareness': squareness belongs to a linear axis")
    before, after, slots = [], [], []
    for i, s in enumerate(items):
        w = f"{where}.squareness[{i}]"
        if not isinstance(s, dict):
            raise MachineFileError(f"{path}: '{w}': expected a table, got {short_repr(s)}")
        check_known_keys(s, ("name", "toward", "iso"), w, path)
        name = s.get("name")
        if not isinstance(name, str) or not name.isidentifier():
            raise MachineFileError(f"{path}: key '{w}.name': expected a slot name (identifier), got {short_repr(name)}")
        tw = s.get("toward")
        if tw not in ("x", "y", "z") or AXES.index(tw) == ax.along:
            raise MachineFileError(f"{path}: key '{w}.toward': expected one of the two frame axes across "
                                   f"{AXES[ax.along]} ({[a for a in AXES if a != AXES[ax.along]]}), got {short_repr(tw)}")
        d_vec, t_vec = np.eye(3)[ax.along], np.eye(3)[AXES.index(tw)]
        w_vec = np.cross(d_vec, t_vec)          # R_w(s)·e_d = cos s·e_d + sin s·e_t
        about = int(np.argmax(np.abs(w_vec)))
        sgn = float(np.sign(w_vec[about]))
        iso = s.get("iso", f"E{'ABC'[about]}0{ax.word}")
        if not isinstance(iso, str):
            raise MachineFileError(f"{path}: key '{w}.iso': expected a string, got {short_repr(iso)}")
        before.append(et("r" + AXES[about], 0.0, slot=name, coef=sgn * URAD_RAD))
        after.insert(0, et("r" + AXES[about], 0.0, slot=name, coef=-sgn * URAD_RAD))
        slots.append(Slot(name, iso, "squareness", ax.word, "urad"))
    return before, after, slots


def _location_ets(ax: ChainAxis, d, where, path):
    if "location" in d and not isinstance(d["location"], bool):
        raise MachineFileError(f"{path}: key '{where}.location': expected true or false, got {short_repr(d['location'])}")
    if ax.kind != "rotary":
        if d.get("location"):
            raise MachineFileError(f"{path}: key '{where}.location': location errors belong to a rotary axis")
        return [], []
    if not d.get("location", True):
        return [], []
    across = [i for i in range(3) if i != ax.along]
    ets, slots = [], []
    w = ax.word.lower()
    for kind, coef, unit in (("t", UM_MM, "um"), ("r", URAD_RAD, "urad")):
        for i in across:
            name = f"{'d' if kind == 't' else 'e'}{AXES[i]}_o{w}"
            ets.append(et(kind + AXES[i], 0.0, slot=name, coef=coef))
            iso = f"E{'XYZ'[i] if kind == 't' else 'ABC'[i]}0{ax.word}"
            slots.append(Slot(name, iso, "location", ax.word, unit))
    return ets, slots


def chain_side(items, side, path, geometry, words, axes, slots, placed):
    """ETs of one side (``work`` or ``tool``) in file order; fills ``axes``, ``slots``."""
    if not isinstance(items, list) or not items:
        raise MachineFileError(f"{path}: missing or empty table array '[[{side}]]'")
    ets, pending, body = [], {}, {}
    for i, d in enumerate(items):
        where = f"{side}[{i}]"
        if not isinstance(d, dict):
            raise MachineFileError(f"{path}: '{where}': expected a table, got {short_repr(d)}")
        if "joint" in d:
            ax = _joint_entry(d, where, path, side, words)
            comps = _component_list(d, "errors", where, path)
            loc, loc_slots = _location_ets(ax, d, where, path)
            before, after, sq_slots = _squareness(d, where, path, ax)
            jtype = "revolute" if ax.kind == "rotary" else "prismatic"
            axes.append((ax, Joint(ax.word.lower(), jtype, *ax.stroke)))
            ets += loc
            slots += loc_slots
            ets += before
            ets.append(et(("r" if ax.kind == "rotary" else "t") + AXES[ax.along], 0.0, joint=ax.word, sign=ax.direction))
            ets += after
            slots += sq_slots
            cets, cslots = _component_ets(ax.word, comps)
            pending[ax.word] = (cets, cslots, where)
            if not _has_marker(items, ax.word):  # else an errors_of entry below places them
                ets += cets
                slots += cslots
                placed.add(ax.word)
                body[ax.word] = len(ets)
            continue
        if "errors_of" in d:
            check_known_keys(d, ("errors_of",), where, path)
            w = d["errors_of"]
            if not isinstance(w, str) or w not in pending or w in placed:
                raise MachineFileError(f"{path}: key '{where}.errors_of': {short_repr(w)} names no axis of this "
                                       f"[[{side}]] chain above it whose errors are still to be placed")
            cets, cslots, _ = pending[w]
            ets += cets
            slots += cslots
            placed.add(w)
            body[w] = len(ets)
            continue
        ets += _fixed_ets(d, where, path, geometry)
    unplaced = [w for w in pending if w not in placed]
    if unplaced:
        raise MachineFileError(f"{path}: '{pending[unplaced[0]][2]}': the errors of axis {unplaced[0]} are marked "
                               "for an errors_of entry that does not follow it")
    return ets, body


def _fixed_ets(d, where, path, geometry) -> list:
    """The ETs of one fixed-transform entry (``tx ty tz`` mm, ``rx ry rz`` deg, ``rotation`` 3×3; none for 0)."""
    keys = [k for k in ("tx", "ty", "tz", "rx", "ry", "rz", "rotation") if k in d]
    if "error" in d or any(k in d for k in ("errors", "location", "squareness", "stroke")):
        k = next(k for k in ("error", "errors", "location", "squareness", "stroke") if k in d)
        raise MachineFileError(f"{path}: key '{where}.{k}': an error slot on a fixed transform; error slots "
                               "belong to a joint (component, location and squareness errors)")
    if len(keys) != 1:
        raise MachineFileError(f"{path}: '{where}': expected exactly one of tx ty tz (mm), rx ry rz (deg), "
                               f"rotation (3×3), a joint (joint = \"linear\"|\"rotary\") or errors_of; got "
                               f"{sorted(d) or 'an empty table'}")
    check_known_keys(d, (keys[0],), where, path)
    k = keys[0]
    if k == "rotation":
        return _rotation_ets(d, where, path)
    v = _value(d, k, where, path, geometry)
    if k[0] == "r" and abs(v) > MAX_ROTARY_ANGLE_DEG:
        raise MachineFileError(f"{path}: key '{where}.{k}': {v:g} is no angle in degrees (a length in mm?)")
    return [et(k, np.radians(v) if k[0] == "r" else v)] if v != 0.0 else []


def _has_marker(items, word) -> bool:
    return any(isinstance(d, dict) and d.get("errors_of") == word for d in items)


def read_tcp(t, path, axes):
    """``[tcp]``: ``switch_on`` / ``switch_off`` lists of M codes (``"M428"``) that switch the controller's
    tool-centre-point kinematics on and off; the codes are the machine's configuration, so they live in its
    file. ``tool_length_under_g49 = "machine"`` (optional): with no tool length offset active (``G49``) the
    kinematics' tool offset is zero, so their controlled point is the point the axes are referenced to: the
    file's own tool point (its ``[geometry] tool_length``); without the key TCP with ``G49`` is refused.
    A machine without a rotary axis has no TCP mode."""
    if t is None:
        return None
    check_known_keys(t, ("switch_on", "switch_off", "tool_length_under_g49"), "tcp", path)
    if not any(a.kind != "linear" for a in axes):
        raise MachineFileError(f"{path}: 'tcp': the machine has no rotary axis (tool-centre-point kinematics need one)")
    out = {k: _m_codes(t.get(k), f"tcp.{k}", "M428", path) for k in ("switch_on", "switch_off")}
    if set(out["switch_on"]) & set(out["switch_off"]):
        raise MachineFileError(f"{path}: 'tcp': an M code both switches TCP on and off")
    if "tool_length_under_g49" in t:
        if t["tool_length_under_g49"] != "machine":
            raise MachineFileError(f"{path}: key 'tcp.tool_length_under_g49': expected \"machine\" (the file's own tool "
                                   f"point), got {short_repr(t['tool_length_under_g49'])}")
        out["tool_length_under_g49"] = "machine"
    return out


def read_controller(t, path):
    """``[controller]``: ``harmless_m``, a list of M codes (``"M252"``) of this machine's controller that move no
    axis and call no program (a vendor's door, light or air code) beyond its dialect's own: the G-code reader
    passes them as it passes the dialect's and the summary lists the lines (``machine_m_codes``). The codes are
    the machine's, so they live in its file; None without the table."""
    if t is None:
        return None
    check_known_keys(t, ("harmless_m",), "controller", path)
    return {"harmless_m": _m_codes(t.get("harmless_m"), "controller.harmless_m", "M252", path)}


def read_spindle(t, path, axes):
    """``[spindle]``: ``axis`` a rotary axis word of the machine; ``turning_on`` / ``turning_off`` lists
    of M codes (``"M3"``); the codes are the machine's, so they live in its file. Optional ``x_words``:
    ``"diameter"`` or ``"radius"``, what the control's X words are where a parameter says it (Fanuc, Haas,
    Siemens ISO lathes; Fanuc parameter 1006 bit 3); absent: unset (such programs' X is refused)."""
    if t is None:
        return None
    check_known_keys(t, ("axis", "turning_on", "turning_off", "x_words"), "spindle", path)
    rotary = [a.word for a in axes if a.kind != "linear"]
    if t.get("axis") not in rotary:
        raise MachineFileError(f"{path}: key 'spindle.axis': expected a rotary axis of the machine {rotary}, "
                               f"got {short_repr(t.get('axis'))}")
    codes = {k: _m_codes(t.get(k), f"spindle.{k}", "M3", path) for k in ("turning_on", "turning_off")}
    if "x_words" in t and t["x_words"] not in ("diameter", "radius"):
        raise MachineFileError(f"{path}: key 'spindle.x_words': expected \"diameter\" or \"radius\", "
                               f"got {short_repr(t['x_words'])}")
    return {"axis": t["axis"], **codes, "x_words": t.get("x_words")}


def _m_codes(v, key: str, example: str, path) -> tuple:
    """A machine file's list of M codes (``["M3", "M4"]``) as their numbers; anything else names ``key``."""
    if not (isinstance(v, list) and v and all(isinstance(c, str) and re.fullmatch(r"M\d+", c) for c in v)):
        raise MachineFileError(f"{path}: key '{key}': expected a list of M codes like [\"{example}\"], "
                               f"got {short_repr(v)}")
    return tuple(int(c[1:]) for c in v)


def read_targets(t, path, axes):
    words = [a.word for a in axes]
    out = {}
    for k, v in t.items():
        if k not in words:
            raise MachineFileError(f"{path}: key 'targets.{k}': no moving axis {k!r} (axes {words})")
        n = len(v) if isinstance(v, list) else 0
        if n < 1:
            raise MachineFileError(f"{path}: key 'targets.{k}': expected a list of [x, y, z] mm, got {short_repr(v)}")
        out[k] = check_array(v, (n, 3), f"targets.{k}", path)
    return out
