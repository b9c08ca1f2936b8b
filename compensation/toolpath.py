"""The grinder paper's test path: the variable-helix-angle flute of a micro drill.

The path is the bottom line of one flute, as WCS targets (mm) on the default grinder, whose A axis is the
drill axis: along ``u ∈ [0, 1]`` the angle ``θ = 360°·turns·u`` (the A command, unwrapped), the flute-bottom
radius ``r(u)`` and the helix angle ``β(u)`` (``lead_law`` says whether β or the lead is linear in ``u``)
give ``p = (px, r·sin θ, r·cos θ)`` with ``dpx/dθ = ∓r/tan β`` (``-`` for a right-hand flute, the default):
the tool point of ``(x, z, a) = (x(px), r - ρ0, θ)``. The parameters and :data:`FLUTE_DEFAULTS` (7 turns of
400 points, radius 0.4 mm, helix 30° → 40°, px from 110 mm): docs/reference/tool-paths.md; the kinematics:
docs/explanation/kinematics.md."""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


LEAD_LAWS = ("linear-helix", "linear-lead")
HANDS = ("right", "left")
SUBSTEPS = 16  # integration sub-steps between consecutive path points


@dataclass(frozen=True)
class FluteSettings:
    """Settings of the flute path (lengths mm, angles deg); see the module docstring."""

    turns: float = 7.0
    points_per_turn: int = 400
    radius_mm: float = 0.4
    radius_end_mm: float | None = None
    helix_start_deg: float = 30.0
    helix_end_deg: float = 40.0
    lead_law: str = "linear-helix"
    hand: str = "right"
    px_start_mm: float = 110.0
    a_start_deg: float = 0.0

    def validate(self) -> "FluteSettings":
        """Raise ValueError ("Expected ..., got ...") for settings that make no flute."""
        if not self.turns > 0:
            raise ValueError(f"Expected turns > 0, got {self.turns}")
        if int(self.points_per_turn) != self.points_per_turn or self.points_per_turn < 2:
            raise ValueError(f"Expected an integer points_per_turn >= 2, got {self.points_per_turn}")
        for name in ("radius_mm", "radius_end_mm"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"Expected {name} > 0, got {v}")
        for name in ("helix_start_deg", "helix_end_deg"):
            v = getattr(self, name)
            if not (0.0 < v < 90.0):
                raise ValueError(f"Expected {name} strictly between 0 and 90 deg, got {v}")
        if self.lead_law not in LEAD_LAWS:
            raise ValueError(f"Expected lead_law in {list(LEAD_LAWS)}, got {self.lead_law!r}")
        if self.hand not in HANDS:
            raise ValueError(f"Expected hand in {list(HANDS)}, got {self.hand!r}")
        if not (np.isfinite(self.px_start_mm) and np.isfinite(self.a_start_deg)):
            raise ValueError("Expected finite px_start_mm and a_start_deg")
        return self

    @property
    def n_points(self) -> int:
        """Number of path points: ``round(turns · points_per_turn)``."""
        return int(round(self.turns * self.points_per_turn))

    def to_dict(self) -> dict:
        return asdict(self)


FLUTE_DEFAULTS = FluteSettings()


@dataclass
class FlutePath:
    """A generated flute: WCS targets and the per-point flute quantities.

    targets_mm : shape (n, 3)   (px_mm, py_mm, pz_mm) in the WCS
    theta_deg : shape (n,)      angle about the drill axis, unwrapped (the nominal A)
    radius_mm : shape (n,)      flute-bottom radius r(u)
    helix_deg : shape (n,)      helix angle β(u)
    lead_mm : shape (n,)        lead L(u) = 2πr/tan β (mm per turn)
    u : shape (n,)              flute parameter in [0, 1]
    settings : FluteSettings
    """

    targets_mm: np.ndarray
    theta_deg: np.ndarray
    radius_mm: np.ndarray
    helix_deg: np.ndarray
    lead_mm: np.ndarray
    u: np.ndarray
    settings: FluteSettings

    def __len__(self) -> int:
        return self.targets_mm.shape[0]

    @property
    def turn_index(self) -> np.ndarray:
        """Which turn (0-based) each point is on, shape (n,)."""
        return np.minimum(np.floor((self.theta_deg - self.theta_deg[0]) / 360.0),
                          np.ceil(self.settings.turns) - 1).astype(int)

    def axes(self, machine) -> np.ndarray:
        """Nominal axis commands (x_mm, z_mm, a_deg) of the targets, A unwrapped from ``a_start_deg``."""
        from errormap.chain_kernel import inverse
        return inverse(machine, self.targets_mm, unwrap=True, a_start_deg=self.settings.a_start_deg)


def _laws(s: FluteSettings, u: np.ndarray):
    r1 = s.radius_mm if s.radius_end_mm is None else s.radius_end_mm
    r = s.radius_mm + (r1 - s.radius_mm) * u
    b0, b1 = np.deg2rad(s.helix_start_deg), np.deg2rad(s.helix_end_deg)
    if s.lead_law == "linear-helix":
        beta = b0 + (b1 - b0) * u
        lead = 2 * np.pi * r / np.tan(beta)
    else:  # linear-lead: lead between the leads of the end angles (each at its own end radius)
        lead0 = 2 * np.pi * s.radius_mm / np.tan(b0)
        lead1 = 2 * np.pi * r1 / np.tan(b1)
        lead = lead0 + (lead1 - lead0) * u
        beta = np.arctan2(2 * np.pi * r, lead)
    return r, beta, lead


def flute_path(settings: FluteSettings | None = None, **overrides) -> FlutePath:
    """Generate the flute's WCS targets; ``overrides`` replace fields of ``settings``.

    ``flute_path()`` gives the documented defaults (2,800 points over 7 turns). The
    axial position is integrated with the trapezoidal rule on ``SUBSTEPS`` sub-steps per
    point spacing (relative error below 1e-9 for the defaults).
    """
    s = settings or FLUTE_DEFAULTS
    if overrides:
        s = FluteSettings(**{**s.to_dict(), **overrides})
    s.validate()
    n = s.n_points
    m = (n - 1) * SUBSTEPS + 1
    u_f = np.linspace(0.0, 1.0, m)
    theta_total_rad = 2 * np.pi * s.turns
    r_f, beta_f, _ = _laws(s, u_f)
    dpx_dtheta = r_f / np.tan(beta_f)  # mm per rad
    dtheta = theta_total_rad / (m - 1)
    s_f = np.concatenate([[0.0], np.cumsum(0.5 * (dpx_dtheta[1:] + dpx_dtheta[:-1]) * dtheta)])
    u = u_f[::SUBSTEPS]
    axial_mm = s_f[::SUBSTEPS]
    r, beta, lead = _laws(s, u)
    sign = -1.0 if s.hand == "right" else 1.0
    theta_deg = s.a_start_deg + np.rad2deg(theta_total_rad) * u
    th = np.deg2rad(theta_deg)
    px = s.px_start_mm + sign * axial_mm
    targets = np.stack([px, r * np.sin(th), r * np.cos(th)], axis=1)
    return FlutePath(targets, theta_deg, r, np.rad2deg(beta), lead, u, s)


FLUTE_ROTARY = "A"
"""The flute's drill axis is the WCS x axis: the workpiece is turned about X, by an A axis (ISO 841)."""
FLUTE_DRILL_AXIS = "X"
"""The axis that feeds along the drill axis (the flute's axial position ``px``)."""


def runs_flute(machine) -> bool:
    """Whether the flute path runs on this machine tool: the one rule of ``demo``, ``report --flute``, the
    benchmark's test part and the export check's flute set.

    The path's physics decides it, not the names of the grinder's axes: its targets are points at the
    flute-bottom radius ``r`` about the WCS x axis (the drill axis) at angle ``θ``, over several turns. So the
    workpiece is turned about X by a full-turn ``A`` (its word is ``θ``, unwrapped past 360°), on the work
    side (the drill blank turns, the wheel stays); ``X`` feeds along the drill axis (``px``); one more linear
    axis, whichever its word (Z on the grinder, Y on another build), sets the radius. Exactly these three
    axes, and the chain's closed-form inverse (:meth:`errormap.machine_tool.MachineTool.closed_form_constants`)
    places the points (:meth:`FlutePath.axes`). The path's strokes are checked per path
    (:func:`check_in_strokes`)."""
    rot = [a for a in machine.axes if a.kind == "rotary"]
    lin = [a.word for a in machine.axes if a.kind == "linear"]
    return (len(machine.axes) == 3 and len(rot) == 1 and rot[0].word == FLUTE_ROTARY and rot[0].full_turn
            and rot[0].side == "work" and len(lin) == 2 and FLUTE_DRILL_AXIS in lin
            and machine.closed_form_constants() is not None)


def check_in_strokes(machine, axes, label: str = "path") -> None:
    """Raise ValueError naming the first points whose command of an axis that does not turn fully is outside
    its stroke.

    ``axes`` shape (n, k), the machine's axis columns. A full-turn axis may run past one turn (multi-turn
    paths), so it is not checked.
    """
    axes = np.asarray(axes, dtype=float)
    bad = []
    for j, a in enumerate(machine.axes):
        if a.full_turn:
            continue
        lo, hi = a.stroke
        idx = np.flatnonzero((axes[:, j] < lo) | (axes[:, j] > hi))
        bad += [(int(i), a.column, float(axes[i, j]), (lo, hi)) for i in idx[:5]]
    if bad:
        words = "/".join(a.word for a in machine.axes if not a.full_turn)
        lines = "; ".join(f"point {i}: {k} = {v:.6f} outside [{lo}, {hi}]" for i, k, v, (lo, hi) in bad)
        raise ValueError(f"Expected {label} inside the {words} strokes, got {lines}")
