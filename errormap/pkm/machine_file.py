"""Machine files for the parallel kinematic machines (``kind = "hexapod"`` / ``"tripod"``).

Sections ``[machine]``, ``[geometry]`` (explicit base / platform joints (k, 3) mm, or radii with side
ratios or pair angles; the tool tip in the platform frame), ``[legs]`` (``min_mm``, ``max_mm``, ``scale``,
``offset_mm``: ``l = scale * q + offset_mm``, q in drive units; a number or k numbers) and ``[home]``
(``tool_tip_mm``, the start of forward kinematics); k = 6 for the hexapod, 3 for the tripod. Schema with
full examples: ``docs/reference/file-formats.md`` and ``docs/explanation/parallel-kinematics.md``. Every
error names the file and the key.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..machine_checks import MachineFileError, check_array, check_known_keys, check_number, check_table, optional_table

HEXAPOD_GEOMETRY_KEYS = (
    "base_joints_mm", "platform_joints_mm", "base_radius_mm", "platform_radius_mm",
    "base_side_ratio", "platform_side_ratio", "base_pair_angle_deg", "platform_pair_angle_deg",
    "tool_length_mm",
)
TRIPOD_GEOMETRY_KEYS = (
    "base_joints_mm", "platform_joints_mm", "base_radius_mm", "platform_radius_mm",
    "joint_angles_deg", "tool_offset_mm",
)
LEG_KEYS = ("min_mm", "max_mm", "scale", "offset_mm")
HOME_KEYS = ("tool_tip_mm",)


def pair_angle_from_side_ratio(ratio: float) -> float:
    """Separation angle (deg) of a joint pair on a semi-regular hexagon with short/long side ``ratio``.

    Short side subtends ``phi``, long side ``120 - phi``: ``sin(phi/2) / sin((120-phi)/2) = ratio``.
    """
    from scipy.optimize import brentq  # here: every machine file is parsed through this module's registry entry
    if not 0.0 < ratio < 1.0:
        raise ValueError(f"side ratio must be in (0, 1), got {ratio}")
    f = lambda phi: np.sin(np.radians(phi) / 2) - ratio * np.sin(np.radians(120.0 - phi) / 2)
    return float(brentq(f, 1e-9, 60.0))


def hexapod_joints_from_radii(base_radius_mm: float, platform_radius_mm: float,
                              base_pair_angle_deg: float, platform_pair_angle_deg: float):
    """Joint centres of the standard 6-6 layout, shape (6, 3) each (base frame, platform frame).

    Base pairs centred at 0, 120, 240 deg; platform pairs at 60, 180, 300 deg; leg ``i`` joins
    base joint ``i`` to the neighbouring platform joint (the crossed arrangement).
    """
    pb, pp = base_pair_angle_deg / 2, platform_pair_angle_deg / 2
    base_deg = np.array([-pb, pb, 120 - pb, 120 + pb, 240 - pb, 240 + pb])
    plat_deg = np.array([-60 + pp, 60 - pp, 60 + pp, 180 - pp, 180 + pp, 300 - pp])
    def ring(r, a):
        a = np.radians(a)
        return np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(a)], axis=1)
    return ring(base_radius_mm, base_deg), ring(platform_radius_mm, plat_deg)


@dataclass(frozen=True)
class PKM:
    """Nominal description of a parallel kinematic machine (hexapod or tripod).

    ``base_joints_mm`` shape (k, 3) in the base (machine) frame; ``platform_joints_mm`` shape
    (k, 3) in the platform frame; ``tool_in_platform_mm`` shape (3,), the tool tip in the
    platform frame; leg arrays shape (k,): ``leg_min_mm``, ``leg_max_mm``, ``leg_scale``,
    ``leg_offset_mm`` (actual leg length ``l = scale * q + offset`` for drive command ``q``);
    ``home_tool_tip_mm`` shape (3,), the start of forward kinematics.
    """

    kind: str
    name: str
    base_joints_mm: np.ndarray
    platform_joints_mm: np.ndarray
    tool_in_platform_mm: np.ndarray
    leg_min_mm: np.ndarray
    leg_max_mm: np.ndarray
    leg_scale: np.ndarray
    leg_offset_mm: np.ndarray
    home_tool_tip_mm: np.ndarray
    path: str = ""
    sha256: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def n_legs(self) -> int:
        return self.base_joints_mm.shape[0]

    def legs_to_drive(self, legs_mm: np.ndarray) -> np.ndarray:
        """Leg lengths (n, k) -> drive commands ``q = (l - offset) / scale``, shape (n, k)."""
        return (np.asarray(legs_mm, float) - self.leg_offset_mm) / self.leg_scale

    def drive_to_legs(self, q: np.ndarray) -> np.ndarray:
        """Drive commands (n, k) -> leg lengths ``l = scale * q + offset`` (mm), shape (n, k)."""
        return np.asarray(q, float) * self.leg_scale + self.leg_offset_mm



def _leg_array(legs: dict, key: str, k: int, default, path) -> np.ndarray:
    if key not in legs:
        if default is None:
            raise MachineFileError(f"{path}: missing key 'legs.{key}'")
        return np.full(k, float(default))
    v = legs[key]
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return np.full(k, float(check_number(legs, key, "legs", path)))
    return check_array(v, (k,), f"legs.{key}", path)


def _parse_common(doc, path, kind, k, geometry_keys):
    check_known_keys(doc, ("machine", "geometry", "legs", "home"), "", path)
    m = check_table(doc, "machine", path)
    check_known_keys(m, ("kind", "name"), "machine", path)
    name = m.get("name", kind)
    if not isinstance(name, str):
        raise MachineFileError(f"{path}: key 'machine.name': expected a string, got {name!r}")
    g = check_table(doc, "geometry", path)
    check_known_keys(g, geometry_keys, "geometry", path)
    legs = check_table(doc, "legs", path)
    check_known_keys(legs, LEG_KEYS, "legs", path)
    lo = _leg_array(legs, "min_mm", k, None, path)
    hi = _leg_array(legs, "max_mm", k, None, path)
    if np.any(lo <= 0) or np.any(hi <= lo):
        raise MachineFileError(f"{path}: keys 'legs.min_mm'/'legs.max_mm': expected 0 < min < max, got {lo} / {hi}")
    scale = _leg_array(legs, "scale", k, 1.0, path)
    if np.any(scale == 0):
        raise MachineFileError(f"{path}: key 'legs.scale': expected non-zero scales, got {scale}")
    offset = _leg_array(legs, "offset_mm", k, 0.0, path)
    home = optional_table(doc, "home", path, {})
    check_known_keys(home, HOME_KEYS, "home", path)
    return name, g, lo, hi, scale, offset, home


def _joints(g, k, path, from_radii):
    explicit = [key for key in ("base_joints_mm", "platform_joints_mm") if key in g]
    radii = [key for key in g if key.endswith(("radius_mm", "ratio", "angle_deg", "angles_deg"))]
    if explicit and radii:
        raise MachineFileError(f"{path}: 'geometry': give either explicit joints {explicit} or radii {radii}, not both")
    if explicit:
        if len(explicit) != 2:
            missing = {"base_joints_mm", "platform_joints_mm"} - set(explicit)
            raise MachineFileError(f"{path}: missing key 'geometry.{missing.pop()}'")
        return (check_array(g["base_joints_mm"], (k, 3), "geometry.base_joints_mm", path),
                check_array(g["platform_joints_mm"], (k, 3), "geometry.platform_joints_mm", path))
    return from_radii()


def parse_hexapod(doc: dict, path, sha: str = "") -> PKM:
    """Validate a parsed hexapod machine file (schema in the module docstring / docs/explanation/parallel-kinematics.md)."""
    name, g, lo, hi, scale, offset, home = _parse_common(doc, path, "hexapod", 6, HEXAPOD_GEOMETRY_KEYS)

    def from_radii():
        rb = check_number(g, "base_radius_mm", "geometry", path)
        rp = check_number(g, "platform_radius_mm", "geometry", path)
        angles = []
        for side in ("base", "platform"):
            rk, ak = f"{side}_side_ratio", f"{side}_pair_angle_deg"
            if (rk in g) == (ak in g):
                raise MachineFileError(f"{path}: 'geometry': give exactly one of '{rk}' and '{ak}'")
            if rk in g:
                ratio = check_number(g, rk, "geometry", path)
                if not 0 < ratio < 1:
                    raise MachineFileError(f"{path}: key 'geometry.{rk}': expected a ratio in (0, 1), got {ratio}")
                angles.append(pair_angle_from_side_ratio(ratio))
            else:
                a = check_number(g, ak, "geometry", path)
                if not 0 < a < 120:
                    raise MachineFileError(f"{path}: key 'geometry.{ak}': expected 0 < angle < 120, got {a}")
                angles.append(a)
        if rb <= 0 or rp <= 0:
            raise MachineFileError(f"{path}: keys 'geometry.base_radius_mm'/'platform_radius_mm': expected positive radii")
        return hexapod_joints_from_radii(rb, rp, *angles)

    base, plat = _joints(g, 6, path, from_radii)
    lt = check_number(g, "tool_length_mm", "geometry", path)
    tip = check_array(home.get("tool_tip_mm", [0.0, 0.0, 980.0]), (3,), "home.tool_tip_mm", path)
    return PKM(kind="hexapod", name=name, base_joints_mm=base, platform_joints_mm=plat,
               tool_in_platform_mm=np.array([0.0, 0.0, -lt]), leg_min_mm=lo, leg_max_mm=hi,
               leg_scale=scale, leg_offset_mm=offset, home_tool_tip_mm=tip, path=str(path), sha256=sha,
               extra={"tool_length_mm": lt})


def parse_tripod(doc: dict, path, sha: str = "") -> PKM:
    """Validate a parsed tripod (3-TPT) machine file."""
    name, g, lo, hi, scale, offset, home = _parse_common(doc, path, "tripod", 3, TRIPOD_GEOMETRY_KEYS)

    def from_radii():
        R = check_number(g, "base_radius_mm", "geometry", path)
        r = check_number(g, "platform_radius_mm", "geometry", path)
        if R <= 0 or r <= 0:
            raise MachineFileError(f"{path}: keys 'geometry.base_radius_mm'/'platform_radius_mm': expected positive radii")
        ang = np.radians(check_array(g.get("joint_angles_deg", [90.0, 210.0, 330.0]), (3,),
                                      "geometry.joint_angles_deg", path))
        ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], axis=1)
        return R * ring, r * ring

    base, plat = _joints(g, 3, path, from_radii)
    tool = check_array(g.get("tool_offset_mm", [0.0, 0.0, 0.0]), (3,), "geometry.tool_offset_mm", path)
    tip = check_array(home.get("tool_tip_mm", [0.0, 0.0, 1000.0]), (3,), "home.tool_tip_mm", path)
    return PKM(kind="tripod", name=name, base_joints_mm=base, platform_joints_mm=plat,
               tool_in_platform_mm=tool, leg_min_mm=lo, leg_max_mm=hi, leg_scale=scale,
               leg_offset_mm=offset, home_tool_tip_mm=tip, path=str(path), sha256=sha)
