"""Identification of every machine tool's error slots from laser-tracker sweeps: the one method.

A chain file, and a ``kind = "grinder"`` file through its chain (:func:`errormap.grinder_file.parse_grinder_file`):
one Gauss–Newton least squares on all ball positions of all sweeps of one tracker set-up, with the exact
chain (:mod:`errormap.chain_sweeps`); its unknowns, gauges (:data:`GAUGES`, :func:`gauge_rows`), checks and
covariance as ``docs/explanation/identification.md`` describes them. Solved by the block structure of the
normal equations (:mod:`errormap.chain_normal`), by a dense pivoted QR where the blocks cannot decide the
rank. Shapes: ball residuals (m, 3) μm per axis; covariance (N, N) over ``param_slot``/``param_station``
(station −1: a constant), μm² / μrad²."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg
from scipy.spatial.transform import Rotation

from .settings import keep_settings
from .io import InputError
from .machine_tool import AXIS_WORDS, MachineTool
from .chain_elements import ChainElementSet
from .chain_normal import BlockLayout, BlockNormal, Undecided
from .chain_sweeps import body_chain, park_axes, swept_words
from .sweeps import GAUGES, Sweeps  # GAUGES: documented here, kept with the sweeps for the CLI's choices
from .transforms import apply, skew

UM = 1e-3     # mm per μm
URAD = 1e-6   # rad per μrad
PARK_TOL = 1e-6
"""A sweep's first command must equal the parked position (lower stroke end) to this (mm or deg, relative to
max(1, |lo|)): the other sweeps were taken with this axis there."""
TURN_TOL_DEG = 1e-6
RANK_TOL = 1e-9
"""A pivoted-QR diagonal below this fraction of the largest (column-scaled Jacobian) is an unobservable direction."""
COV_FORMAT = "volcomp-chain-covariance/1"
LEVERAGE_FLOOR = 1e-6
"""A ball coordinate the fit reproduces exactly (leverage within this of 1) has no residual to draw from."""


# -- geometric checks (every machine) ----------------------------------------------------------
def rigid_fit(src, dst):
    """Least-squares rigid transform (SVD, Kabsch) with ``R·src + t ≈ dst``.

    ``src`` shape (k, 3) or (n, k, 3), ``dst`` shape (n, k, 3) -> (R (n,3,3), t (n,3)).
    """
    dst = np.asarray(dst, dtype=float)
    src = np.broadcast_to(np.asarray(src, dtype=float), dst.shape)
    cs, cd = src.mean(axis=-2), dst.mean(axis=-2)
    H = np.einsum("nki,nkj->nij", src - cs[:, None], dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.broadcast_to(np.eye(3), H.shape).copy()
    D[:, 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    return R, cd - apply(R, cs)


BALL_PAIRS = ((0, 1), (0, 2), (1, 2))


def ball_distances(balls_mm) -> np.ndarray:
    """Distances (..., 3) mm between the three balls of ``balls_mm`` (..., 3, 3), pairs :data:`BALL_PAIRS`."""
    b = np.asarray(balls_mm, dtype=float)
    return np.stack([np.linalg.norm(b[..., i, :] - b[..., j, :], axis=-1) for i, j in BALL_PAIRS], axis=-1)


def layout_problem(points_mm, min_separation_mm: float = 1.0):
    """``None`` if three ball centres (3, 3) form a usable triangle, else why not (a string)."""
    p = np.asarray(points_mm, dtype=float)
    dist = ball_distances(p)
    for (i, j), d in zip(BALL_PAIRS, dist):
        if d < min_separation_mm:
            return f"targets {i + 1} and {j + 1} coincide ({d:.3g} mm apart)"
    height = np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0])) / max(dist)
    if height < min_separation_mm:
        return (f"targets are collinear (triangle height {height:.3g} mm); the rotation about their line "
                "cannot be observed")
    return None


def _layout_suspects(balls_mm, min_separation_mm: float) -> np.ndarray:
    """Indices of the stations (balls (m, 3, 3)) that :func:`layout_problem` may refuse, in order:
    the same tests at every station at once, with a 1 % margin so that rounding cannot hide one."""
    b = np.asarray(balls_mm, dtype=float)
    dist = ball_distances(b)
    height = np.linalg.norm(np.cross(b[:, 1] - b[:, 0], b[:, 2] - b[:, 0]), axis=1) / dist.max(axis=1)
    return np.flatnonzero((dist.min(axis=1) < 1.01 * min_separation_mm) | ~(height >= 0.99 * min_separation_mm))


def check_motion(sw, ax, travel_tol_mm: float = 1.0, angle_tol_deg: float = 0.5) -> None:
    """Refuse a sweep whose measured motion from its first station does not match the commands (mixed units:
    inches, radians), naming axis and station: the rigid motion of the three balls (Kabsch) turns by the
    commanded angle of a rotary axis, and a linear axis' ball centroid travels the commanded distance."""
    b = np.asarray(sw.balls_mm, dtype=float)
    d_cmd = sw.command - sw.command[0]
    if ax.kind == "rotary":
        R, _ = rigid_fit(b[0], b)
        got = np.rad2deg(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
        want = np.abs((d_cmd + 180.0) % 360.0 - 180.0)
        bad = np.abs(got - want) > angle_tol_deg
        what = "rotation {:.4g} deg from the first station, commanded {:.4g} deg"
    else:
        got = np.linalg.norm(b.mean(axis=1) - b[0].mean(axis=0), axis=1)
        want = np.abs(d_cmd)
        bad = np.abs(got - want) > travel_tol_mm
        what = "travel {:.4g} mm from the first station, commanded {:.4g} mm"
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"{sw.source}: axis {sw.axis}, station {sw.stations[i]}: measured "
                         f"{what.format(got[i], want[i])} (mixed units?)")


def _check_length_unit(sw, ax: str, mounts) -> None:
    """Refuse (InputError naming the file, the axis and the columns) sweeps whose ball distances are
    a unit factor off the nominal mounts' (metres, centimetres, inches, μm written as mm): the median
    measured/nominal distance ratio outside :data:`errormap.units.LENGTH_RATIO_BAND`, with a unit named."""
    from .units import LENGTH_RATIO_BAND, length_unit_guess
    ratio = float(np.median(ball_distances(sw.balls_mm) / ball_distances(mounts)))
    guess = length_unit_guess(ratio)
    if guess and not LENGTH_RATIO_BAND[0] <= ratio <= LENGTH_RATIO_BAND[1]:
        raise InputError(f"{sw.source}: axis {ax}, columns 'x_mm', 'y_mm', 'z_mm': units do not fit: the balls lie "
                         f"{ratio:.4g} times as far apart as the machine file's [targets] mounts (expected 1 for "
                         f"mm){guess}")


def check_ball_distances(sw, axis_word: str, mounts_mm, tol_mm: float) -> None:
    """Refuse a sweep whose measured ball-to-ball distances differ from the nominal mounts' by more
    than ``tol_mm`` at any station (mixed units, or a wrong [targets] entry), naming axis and station.
    ``sw.balls_mm`` (m, 3, 3), ``mounts_mm`` (3, 3)."""
    nominal, measured = ball_distances(mounts_mm), ball_distances(sw.balls_mm)
    bad = np.abs(measured - nominal).max(axis=1) > tol_mm
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"{sw.source}: axis {axis_word}, station {sw.stations[i]}: ball distances "
                         f"{np.round(measured[i], 3).tolist()} mm do not match the nominal mounts' "
                         f"{np.round(nominal, 3).tolist()} mm (mixed units, or a wrong [targets] entry?)")


@dataclass
class ChainIdentificationResult:
    """``elements_``, ``machine_in_tracker`` (R (3,3), t (3,) mm), per-axis ball residual RMS
    (μm, per station), ``sigma_um`` (σ̂ per coordinate), ``iterations``, ``condition`` (of the
    column-scaled Jacobian), ``unobservable`` (names held at zero), ``warnings``, and the
    covariance ``cov`` over ``param_slot``/``param_station``."""

    elements_: ChainElementSet
    machine_in_tracker: tuple
    residual_rms_um: dict
    sigma_um: float
    iterations: int
    condition: float
    param_slot: list
    param_station: np.ndarray
    cov: np.ndarray
    unobservable: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    noise_um: float | None = None
    """The known tracker σ the covariance was scaled with (``ChainIdentification(noise_um=...)``); None: σ̂."""
    ball_residual_um: dict = field(default_factory=dict)
    """Per swept axis, measured − fitted ball positions (m, 3, 3) μm [station, target, xyz], tracker frame."""
    leverage: dict = field(default_factory=dict)
    """Per swept axis, the hat matrix' diagonal (m, 3, 3) of every ball coordinate (its share of the fit)."""
    covariance_info: dict = field(default_factory=lambda: {"method": "gauss-newton"})
    """How ``cov`` was obtained: ``gauss-newton`` (σ̂²·(JᵀJ)⁻¹) or ``residual-bootstrap`` (with n_boot, seed)."""
    gauge: str = "first-station"
    reversal_um: dict = field(default_factory=dict)
    """Per axis swept both ways, the RMS ball-position difference (m,) μm between the + and − runs per station."""
    prior_extra: np.ndarray | None = None
    """(N,) the smoother's whole mean-square change per parameter (:func:`smooth_chain`; a prior's extra variance
    when the set seeds an update, :data:`errormap.chain_covariance.PRIOR_EXTRA_KEY`); None: not smoothed."""

    def summary_lines(self) -> list[str]:
        lines = [f"axis {w}: {len(r)} stations, ball residual RMS max {r.max():.3g} um" +
                 (f", reversal (+/- runs) max {self.reversal_um[w].max():.3g} um" if w in self.reversal_um else "")
                 for w, r in self.residual_rms_um.items()]
        lines.append(f"Gauss-Newton: {self.iterations} iterations, sigma {self.sigma_um:.3g} um per coordinate, "
                     f"scaled condition {self.condition:.3g}")
        if self.noise_um is not None:
            lines.append(f"covariance scaled with the given tracker noise {self.noise_um:.3g} um (not the estimate)")
        c = self.elements_.constants
        if c:
            lines.append("constants: " + ", ".join(f"{k} {v:.4g}" for k, v in c.items()))
        if self.unobservable:
            lines.append(f"unobservable (held at zero): {', '.join(self.unobservable)}")
        if self.covariance_info["method"] != "gauss-newton":
            lines.append(f"covariance: residual bootstrap, {self.covariance_info['n_boot']} draws, "
                         f"seed {self.covariance_info['seed']}")
        return lines + [f"warning: {w}" for w in self.warnings]

    def to_dict(self) -> dict:
        sm = self.covariance_info.get("smoothing")
        return {"format": "volcomp-identification/2", "gauge": self.gauge,
                "smoothing": sm if sm else "none: interpolating splines through the stations (identify --raw's form)",
                "machine_in_tracker": {"R": self.machine_in_tracker[0].tolist(), "t_mm": self.machine_in_tracker[1].tolist()},
                "residual_rms_um": {k: v.tolist() for k, v in self.residual_rms_um.items()},
                "sigma_um": self.sigma_um, "noise_um": self.noise_um,
                "covariance_sigma_um": self.sigma_um if self.noise_um is None else self.noise_um,
                "iterations": self.iterations, "condition": self.condition,
                "unobservable": self.unobservable, "warnings": self.warnings,
                "constants": self.elements_.constants, "covariance": dict(self.covariance_info)}


def _squareness_toward(machine: MachineTool, name: str) -> int:
    """Frame axis (0, 1, 2) a squareness slot tilts its axis towards (from its ETs)."""
    s = next(s for s in machine.slots if s.name == name)
    ax = next(a for a in machine.axes if a.word == s.axis)
    e = next(e for e in (*machine.work_ets, *machine.tool_ets) if e.slot == name)
    return 3 - e.axis - ax.along


def root_axis(machine: MachineTool) -> str:
    """The axis whose body at its first station is the machine frame (module doc): the first linear
    axis of the work chain, else of the tool chain (a rotary axis' line is placed relative to the
    linear axes, as ISO 230-7 does), else the first axis of the work chain."""
    kind = {a.word: a.kind for a in machine.axes}
    for want in ("linear", None):
        for side in ("work", "tool"):
            cand = [(k, w) for w, (s, k) in machine.body_index.items() if s == side and want in (None, kind[w])]
            if cand:
                return min(cand)[1]
    raise ValueError(f"{machine.name!r}: no axis with component errors")


def _rotary_rows(w, ax, sl, cmd_deg, at, n) -> list:
    """The station-mean conditions of a rotary axis' line: the part of its component errors across the axis
    that turns with it (δ and ε across, rotated back by the angle) sums to zero over the distinct stations."""
    from .transforms import rot_x, rot_y, rot_z
    distinct = cmd_deg.size - 1 if ax.full_turn else cmd_deg.size
    R = (rot_x, rot_y, rot_z)[ax.along](np.deg2rad(ax.direction * np.asarray(cmd_deg, float)))
    across = [c for c in range(3) if c != ax.along]
    rows = []
    for kind in "de":
        names = [f"{kind}{'xyz'[c]}_{w.lower()}" for c in across]
        if not all(k in sl for k in names):
            continue
        for r in across:
            row = np.zeros(n)
            for i in range(distinct):
                for c, k in zip(across, names):
                    row[at(i, k)] += R[i][r, c]
            rows.append(row)
    return rows


def _reference_rows(machine: MachineTool, root: str, words) -> list:
    """How the reference-line gauge fixes the frame's rotation, ``[(axis, slot, "slope" | "first")]``: a frame
    rotation about frame axis k tilts a linear axis that moves on the base (the first axis of its chain) along
    ``a`` towards ``c`` (k = 3 − a − c); per k the linear trend of one such straightness is set to zero, the root
    axis' first, skipping a straightness a squareness carries; a k no free straightness sees keeps the root axis'
    rotation about k zero at its first station (as the first-station gauge)."""
    axes = {a.word: a for a in machine.axes}
    tied = {f"d{'xyz'[_squareness_toward(machine, t.name)]}_{t.axis.lower()}" for t in machine.slots
            if t.kind == "squareness"}
    on_base = [w for w in words if axes[w].kind == "linear" and len(body_chain(machine, w).joint_cols) == 1]
    picked = {}
    for w in sorted(on_base, key=lambda w: w != root):
        a = axes[w].along
        for c in range(3):
            s = f"d{'xyz'[c]}_{w.lower()}"
            if c != a and s not in tied and s in machine.slots_of(w) and 3 - a - c not in picked:
                picked[3 - a - c] = (w, s, "slope")
    for k in range(3):
        if k not in picked and f"e{'xyz'[k]}_{root.lower()}" in machine.slots_of(root):
            picked[k] = (root, f"e{'xyz'[k]}_{root.lower()}", "first")
    return [picked[k] for k in sorted(picked)]


def gauge_rows(gauge: str, machine: MachineTool, sweeps: Sweeps, block: dict, n: int) -> np.ndarray:
    """Linear conditions ``C θ = 0`` (k, n) of a gauge beyond what :meth:`ChainIdentification._layout` holds at
    zero (module doc): ``station-mean`` the root axis' six component errors sum to zero over its stations and a
    rotary axis' line is its mean over the turn (:func:`_rotary_rows`); ``reference-line`` the root axis'
    translations zero at its first station and three straightness slots without linear trend
    (:func:`_reference_rows`: the root axis' own first, so the frame lies on its fitted line, the paper's
    reference frame); ``first-station`` none."""
    rows = []
    if gauge == "first-station":
        return np.zeros((0, n))
    root = root_axis(machine)
    words = swept_words(machine)
    axes = {a.word: a for a in machine.axes}

    def index(w):
        sl = machine.slots_of(w)
        return sl, sweeps[w].command, lambda i, s: block[w] + i * len(sl) + sl.index(s)

    sl, cmd, at = index(root)
    if gauge == "station-mean":
        for s in sl:
            row = np.zeros(n)
            row[[at(i, s) for i in range(cmd.size)]] = 1.0
            rows.append(row)
        for w in words:
            ax = axes[w]
            if ax.kind == "rotary" and any(t.kind == "location" and t.axis == w for t in machine.slots):
                slw, cw, atw = index(w)
                rows += _rotary_rows(w, ax, slw, cw, atw, n)
    else:
        for c in range(3):
            s = f"d{'xyz'[c]}_{root.lower()}"
            if s in sl:
                row = np.zeros(n)
                row[at(0, s)] = 1.0
                rows.append(row)
        for w, s, how in _reference_rows(machine, root, words):
            slw, cw, atw = index(w)
            row = np.zeros(n)
            if how == "slope":
                row[[atw(i, s) for i in range(cw.size)]] = cw - cw.mean()
            else:
                row[atw(0, s)] = 1.0
            rows.append(row)
    return np.array(rows).reshape(-1, n)


class ChainIdentification:
    """Gauss–Newton identification of a machine-tool chain (module doc). ``fit(sweeps, machine)``
    returns self with ``elements_`` and ``result_``.

    Settings: ``max_iter`` / ``tol`` (largest update, μm or μrad) of the Gauss–Newton loop;
    ``min_separation_mm``: balls closer than this coincide; ``distance_tol_mm``: allowed
    difference between measured and nominal ball distances (mixed units, wrong mounts); ``noise_um``: the
    known tracker σ per coordinate (μm) the covariance is scaled with (as the grinder's ``identify
    --noise-um``), None: the residuals' σ̂; ``gauge``: one of :data:`GAUGES` (module doc).
    """

    def __init__(self, max_iter: int = 30, tol: float = 1e-7, min_separation_mm: float = 1.0,
                 distance_tol_mm: float = 2.0, noise_um: float | None = None, gauge: str = "first-station"):
        keep_settings(self, locals())

    # -- validation ------------------------------------------------------------------------
    def _check(self, sweeps: Sweeps, machine: MachineTool) -> list:
        if self.gauge not in GAUGES:
            raise ValueError(f"Expected gauge in {GAUGES}, got {self.gauge!r}")
        if not 1 <= self.max_iter <= 1000 or not self.tol > 0:
            raise ValueError(f"Expected 1 <= max_iter <= 1000 and tol > 0, got {self.max_iter}, {self.tol}")
        src = ", ".join(sweeps.sources) or "sweeps"
        words = swept_words(machine)
        missing = [w for w in words if w not in sweeps]
        if missing:
            raise InputError(f"{src}: axis/axes {missing} missing; every axis with error slots ({list(words)}) is "
                             "needed from one tracker set-up (the bodies are related through it)")
        warnings = []
        for w in words:
            ax = next(a for a in machine.axes if a.word == w)
            if w not in machine.targets or machine.targets[w].shape[0] != 3:
                raise InputError(f"{machine.path or machine.name}: key 'targets.{w}': three target balls are needed "
                                 f"on the body of axis {w}")
            mounts = machine.targets[w]
            why = layout_problem(mounts, self.min_separation_mm)
            if why:
                raise InputError(f"{machine.path or machine.name}: key 'targets.{w}': degenerate target layout: {why}")
            sw = sweeps[w]
            _check_length_unit(sw, w, mounts)
            for i in _layout_suspects(sw.balls_mm, self.min_separation_mm):  # vectorised screen, then the message
                why = layout_problem(sw.balls_mm[i], self.min_separation_mm)
                if why:
                    raise InputError(f"{sw.source}: axis {w}, station {sw.stations[i]}: degenerate target layout: {why}")
            check_ball_distances(sw, w, mounts, self.distance_tol_mm)
            lo, hi = ax.stroke
            if abs(sw.command[0] - lo) > PARK_TOL * max(1.0, abs(lo)):
                raise InputError(f"{sw.source}: axis {w}, station {sw.stations[0]}: the first station must be at the "
                                 f"lower stroke end {lo:g} {ax.unit} (where the other sweeps park axis {w}), got "
                                 f"{sw.command[0]:g}")
            if ax.full_turn and abs(sw.command[-1] - sw.command[0] - 360.0) > TURN_TOL_DEG:
                raise InputError(f"{sw.source}: axis {w}: stations of a full-turn axis must span one turn (360 deg), "
                                 f"got {sw.command[0]:g}..{sw.command[-1]:g} deg (mixed units?)")
            check_motion(sw, ax)
            if not ax.full_turn and sw.command[-1] < hi - PARK_TOL * max(1.0, abs(hi)):
                warnings.append(f"axis {w}: stations cover {sw.command[0]:g}..{sw.command[-1]:g} of the stroke "
                                f"{lo:g}..{hi:g}; elements are extrapolated beyond")
            if sw.temp_c is not None and np.ptp(sw.temp_c) > 1.0:
                warnings.append(f"axis {w}: temperature varied by {np.ptp(sw.temp_c):.2g} degC during the sweep; "
                                "thermal drift is identified as geometry")
        self._check_handedness(sweeps, machine, words, src)
        return warnings

    @staticmethod
    def _check_handedness(sweeps: Sweeps, machine: MachineTool, words, src) -> None:
        """Refuse ball coordinates that are a mirror image of the machine (two columns exchanged): the nominal
        ball centres of every sweep (the other axes parked, no errors) against the measured ones
        (:func:`errormap.diagnosis.plausibility.mirrored_ball_columns`)."""
        from .diagnosis.plausibility import mirrored_ball_columns
        col = {a.word: j for j, a in enumerate(machine.axes)}
        nominal, measured = [], []
        for w in words:
            sw = sweeps[w]
            axes = np.tile(park_axes(machine), (len(sw.command), 1))
            axes[:, col[w]] = sw.command
            values = np.zeros((len(axes), len(machine.slot_names)))
            nominal.append(body_chain(machine, w).balls(axes, values, machine.targets[w]).reshape(-1, 3))
            measured.append(np.asarray(sw.balls_mm, float).reshape(-1, 3))
        m = mirrored_ball_columns(np.concatenate(nominal), np.concatenate(measured))
        if m is not None:
            raise InputError(f"{src}: {m}")

    # -- parameters -------------------------------------------------------------------------
    def _layout(self, sweeps, machine):
        """Full parameter list θ: G (6), per swept axis (station, component) values, constants; the map
        ``A`` (n_θ, n_free) of the free parameters to θ (held at zero, tied, and the gauge's conditions,
        :func:`gauge_rows`)."""
        words = swept_words(machine)
        names, stations = ["G.rx", "G.ry", "G.rz", "G.tx", "G.ty", "G.tz"], [-1] * 6
        block = {}
        for w in words:
            m = sweeps[w].command.size
            sl = machine.slots_of(w)
            block[w] = len(names)
            for i in range(m):
                for s in sl:
                    names.append(s)
                    stations.append(i)
        const0 = len(names)
        for s in machine.constant_slots:
            names.append(s)
            stations.append(-1)
        n = len(names)
        free = np.arange(n)
        root = root_axis(machine)
        for w in words:
            ax = next(a for a in machine.axes if a.word == w)
            sl = machine.slots_of(w)
            m = sweeps[w].command.size
            at = lambda i, s: block[w] + i * len(sl) + sl.index(s)  # noqa: E731
            for s in sl:
                comp = s.split("_")[0]
                across = comp[1] != "xyz"[ax.along]
                has_loc = any(t.kind == "location" and t.axis == w for t in machine.slots)
                if (w == root and self.gauge == "first-station") or (
                        ax.kind == "rotary" and has_loc and across and self.gauge != "station-mean"):
                    free[at(0, s)] = -1
                if ax.full_turn:
                    free[at(m - 1, s)] = free[at(0, s)]
            for t in machine.slots:
                if t.kind == "squareness" and t.axis == w:
                    s = f"d{'xyz'[_squareness_toward(machine, t.name)]}_{w.lower()}"
                    if s in sl:
                        free[at(m - 1, s)] = free[at(0, s)]
        # renumber the free parameters 0..nf-1
        uniq = sorted(set(free[free >= 0].tolist()))
        ren = {u: k for k, u in enumerate(uniq)}
        free = np.array([ren[f] if f >= 0 else -1 for f in free])
        C = gauge_rows(self.gauge, machine, sweeps, block, n)
        ok = free >= 0
        Cf = np.zeros((C.shape[0], int(free.max()) + 1))   # the conditions on the free parameters, C·A₀
        np.add.at(Cf.T, free[ok], C[:, ok].T)
        return names, np.array(stations), free, Cf, block, const0

    # -- the method -------------------------------------------------------------------------
    def fit(self, sweeps: Sweeps, machine: MachineTool) -> "ChainIdentification":
        """Identify every error slot of ``machine`` from ``sweeps`` (:class:`errormap.sweeps.Sweeps`)."""
        if self.noise_um is not None and not (np.isfinite(self.noise_um) and self.noise_um > 0):
            raise ValueError(f"Expected a positive, finite tracker noise σ in μm, got {self.noise_um}")
        warnings = self._check(sweeps, machine)
        words = swept_words(machine)
        names, stations, free, Cf, block, const0 = self._layout(sweeps, machine)
        P = len(machine.slots)
        sidx = {s: j for j, s in enumerate(machine.slot_names)}
        park = park_axes(machine)
        col = {a.word: j for j, a in enumerate(machine.axes)}
        bodies = {w: body_chain(machine, w) for w in words}
        # per sweep: poses, the θ index of every slot value per pose (n_w, P) (−1: none)
        setup = {}
        for w in words:
            sw = sweeps[w]
            m = sw.command.size
            pts = np.tile(park, (m, 1))
            pts[:, col[w]] = sw.command
            tidx = np.full((m, P), -1)
            for u in words:
                sl = machine.slots_of(u)
                for s in sl:
                    if u == w:
                        tidx[:, sidx[s]] = block[u] + np.arange(m) * len(sl) + sl.index(s)
                    else:
                        tidx[:, sidx[s]] = block[u] + sl.index(s)
            for k, s in enumerate(machine.constant_slots):
                tidx[:, sidx[s]] = const0 + k
            setup[w] = (pts, tidx, sw.balls_mm)
        # initial tracker pose: Kabsch of the nominal balls on the measured ones
        nom = np.concatenate([bodies[w].balls(setup[w][0], np.zeros((len(setup[w][0]), P)), machine.targets[w])
                              .reshape(-1, 3) for w in words])
        meas = np.concatenate([setup[w][2].reshape(-1, 3) for w in words])
        RG, tG = rigid_fit(nom[None], meas[None])
        args = (words, setup, bodies, machine, len(names))
        try:
            out = self._solve_blocked(args, free, Cf, RG[0], tG[0])
        except Undecided:
            out = self._solve_dense(args, free, Cf, RG[0], tG[0], names, stations, warnings)
        theta, (RG, tG), it, r, cov, lev, condition, sigma, unobservable = out
        # element set
        st, fun = {}, {}
        for w in words:
            ax = next(a for a in machine.axes if a.word == w)
            sl = machine.slots_of(w)
            m = sweeps[w].command.size
            vals = theta[block[w]:block[w] + m * len(sl)].reshape(m, len(sl))
            st[ax.column] = sweeps[w].command.copy()
            for j, s in enumerate(sl):
                fun[s] = vals[:, j].copy()
        const = {s: float(theta[const0 + k]) for k, s in enumerate(machine.constant_slots)}
        elements = ChainElementSet(machine, st, fun, const, machine.name, machine.sha256)
        rr, lev = r.reshape(-1, 3), lev.reshape(-1, 3)
        res, balls_res, leverage, o = {}, {}, {}, 0
        for w in words:
            m = setup[w][2].shape[0]
            balls_res[w] = rr[o:o + 3 * m].reshape(m, 3, 3)
            leverage[w] = lev[o:o + 3 * m].reshape(m, 3, 3)
            res[w] = np.sqrt(np.mean(balls_res[w] ** 2, axis=(1, 2)) * 3)
            o += 3 * m
        self.elements_ = elements
        reversal = {w: np.sqrt(np.mean(np.sum((sweeps[w].by_direction[1] - sweeps[w].by_direction[-1]) ** 2,
                                              axis=2), axis=1)) / UM
                    for w in words if len(sweeps[w].by_direction) == 2}
        self.result_ = ChainIdentificationResult(elements, (RG, tG), res, sigma, it, condition,
                                                 names[6:], stations[6:], cov, unobservable, warnings,
                                                 noise_um=None if self.noise_um is None else float(self.noise_um),
                                                 ball_residual_um=balls_res, leverage=leverage, gauge=self.gauge,
                                                 reversal_um=reversal)
        return self

    def _step(self, theta, RG, tG, dth):
        """Apply the update ``dth`` (n_θ,): b_tracker = R_G·(Exp(ω)·b + τ) + t_G, linearised at ω = τ = 0."""
        tG = tG + RG @ (dth[3:6] * UM)
        RG = RG @ Rotation.from_rotvec(dth[:3] * URAD).as_matrix()
        theta[6:] += dth[6:]
        return RG, tG

    def _solve_blocked(self, args, free, Cf, RG, tG) -> tuple:
        """Gauss–Newton through the block normal equations (:mod:`errormap.chain_normal`); raises
        :class:`Undecided` where the blocks cannot decide the rank. Returns (θ, (R_G, t_G), iterations, r, cov,
        leverage, condition, σ̂, unobservable)."""
        theta = np.zeros(args[-1])
        fcols = [np.where(c >= 0, free[np.maximum(c, 0)], -1) for c in self._columns(args)]
        lay = BlockLayout(fcols, int(free.max()) + 1)
        C = scipy.linalg.orth(Cf.T).T if Cf.shape[0] else Cf
        it = 0
        for it in range(1, self.max_iter + 1):
            r, vals = self._system(*args, theta, RG, tG)
            x = BlockNormal(lay, *lay.assemble(vals), C).solve(r)
            dth = np.where(free >= 0, x[np.maximum(free, 0)], 0.0)
            RG, tG = self._step(theta, RG, tG, dth)
            if np.abs(dth).max() < self.tol:
                break
        r, vals = self._system(*args, theta, RG, tG)
        nrm = BlockNormal(lay, *lay.assemble(vals), C)
        sigma = float(np.sqrt(r @ r / max(r.size - (Cf.shape[1] - C.shape[0]), 1)))
        s_cov = sigma if self.noise_um is None else float(self.noise_um)
        return (theta, (RG, tG), it, r, nrm.covariance(free[6:], s_cov**2), nrm.leverage(), nrm.condition(),
                sigma, [])

    def _solve_dense(self, args, free, Cf, RG, tG, names, stations, warnings) -> tuple:
        """Gauss–Newton with the dense Jacobian and pivoted QR, which names (and holds at zero) the parameters the
        sweeps leave unobservable (appending a warning). Same return as :meth:`_solve_blocked`."""
        ok = free >= 0   # θ = A₀·N·x: held at zero, tied, N a basis of the null space of the gauge's conditions
        A = np.zeros((free.size, int(free.max()) + 1))
        A[np.flatnonzero(ok), free[ok]] = 1.0
        A = A @ scipy.linalg.null_space(Cf) if Cf.shape[0] else A
        theta = np.zeros(args[-1])
        n_theta, nf = A.shape
        unobservable, it = [], 0
        keep = np.ones(nf, dtype=bool)
        for it in range(1, self.max_iter + 1):
            r, vals = self._system(*args, theta, RG, tG)
            Jf = self._dense(args, vals) @ A
            scale = np.linalg.norm(Jf, axis=0)
            scale[scale == 0] = 1.0
            Js = Jf / scale
            if it == 1:  # the gauge left nothing free? pivoted QR names what is not
                _, Rq, piv = scipy.linalg.qr(Js, mode="economic", pivoting=True)
                d = np.abs(np.diag(Rq))
                dead = piv[d < RANK_TOL * d[0]]
                if dead.size:
                    keep[dead] = False
                    for f in dead:
                        j = int(np.argmax(np.abs(A[:, f])))
                        unobservable.append(names[j] + (f"@station{stations[j]}" if stations[j] >= 0 else ""))
                    warnings.append(f"{len(dead)} parameter(s) unobservable from these sweeps, held at zero: "
                                    f"{', '.join(unobservable[:8])}{' …' if len(unobservable) > 8 else ''}")
            x = np.zeros(nf)
            x[keep] = np.linalg.lstsq(Js[:, keep], r, rcond=None)[0] / scale[keep]
            dth = A @ x
            RG, tG = self._step(theta, RG, tG, dth)
            if np.abs(dth).max() < self.tol:
                break
        r, vals = self._system(*args, theta, RG, tG)
        Jf = (self._dense(args, vals) @ A)[:, keep]
        scale = np.linalg.norm(Jf, axis=0)
        scale[scale == 0] = 1.0
        sv = np.linalg.svd(Jf / scale, compute_uv=False)
        sigma = float(np.sqrt(r @ r / max(r.size - int(keep.sum()), 1)))
        s_cov = sigma if self.noise_um is None else float(self.noise_um)
        Jinv = np.linalg.pinv(Jf / scale)
        lev = np.sum(np.linalg.qr(Jf / scale)[0] ** 2, axis=1)
        cov_f = np.zeros((nf, nf))
        cov_f[np.ix_(keep, keep)] = s_cov**2 * (Jinv @ Jinv.T) / np.outer(scale, scale)
        return (theta, (RG, tG), it, r, A[6:] @ cov_f @ A[6:].T, lev, float(sv[0] / sv[-1]), sigma,
                unobservable)

    @staticmethod
    def _columns(args) -> list:
        """Per sweep, the θ index (m, 6 + P) of every column of :meth:`_system`'s compact Jacobian (−1: none)."""
        words, setup = args[0], args[1]
        return [np.concatenate([np.tile(np.arange(6), (setup[w][1].shape[0], 1)), setup[w][1]], axis=1)
                for w in words]

    @classmethod
    def _dense(cls, args, vals) -> np.ndarray:
        """The dense Jacobian (rows, n_θ) of :meth:`_system`'s compact one."""
        J = np.zeros((sum(v.shape[0] * 9 for v in vals), args[-1]))
        o = 0
        for v, c in zip(vals, cls._columns(args)):
            m = v.shape[0]
            i, q = np.nonzero(c >= 0)
            np.add.at(J, (o + 9 * i[:, None] + np.arange(9), c[i, q][:, None]), v[i, :, q])
            o += 9 * m
        return J

    @staticmethod
    def _system(words, setup, bodies, machine, n_theta, theta, RG, tG):
        """Residual (μm, measured − predicted, flattened: sweep, station, ball, xyz) and its compact Jacobian:
        per sweep (m, 9, 6 + P) in μm per μm/μrad, columns G (rotation μrad, translation μm in the machine frame),
        then every slot (θ index :meth:`_columns`)."""
        rs, vals = [], []
        for w in words:
            pts, tidx, meas = setup[w]
            v = np.where(tidx >= 0, theta[np.maximum(tidx, 0)], 0.0)
            b, Jb = bodies[w].balls_and_jacobian(pts, v, machine.targets[w])   # (m,3,3), (m,3,3,P) mm per unit
            pred = b @ RG.T + tG
            rs.append(((meas - pred) / UM).reshape(-1))
            m = b.shape[0]
            J = np.empty((m, 3, 3, 6 + tidx.shape[1]))
            J[..., 6:] = np.einsum("ij,nkjp->nkip", RG, Jb) / UM                          # μm per unit
            J[..., 0:3] = -np.einsum("ij,nkjl->nkil", RG, skew(b)) * (URAD / UM)
            J[..., 3:6] = RG
            vals.append(J.reshape(m, 9, -1))
        return np.concatenate(rs), vals


def parameter_vector(elements: ChainElementSet, slots, stations) -> np.ndarray:
    """The element set's values (N,) in the covariance's parameter order ``slots``/``stations`` (station −1: a
    constant)."""
    return np.array([elements.constants[s] if i < 0 else elements.functions[s][i] for s, i in zip(slots, stations)])


def resampled_sweeps(sweeps: Sweeps, result: ChainIdentificationResult, rng) -> Sweeps:
    """One residual-bootstrap draw: the fitted ball positions plus residuals drawn with replacement from every
    ball coordinate of all sweeps. The residuals are first leverage-corrected, ``rᵢ/√(1 − hᵢᵢ)``, and centred
    (Davison & Hinkley's modified residuals): a sweep fit spends about two thirds of its coordinates on the
    parameters, and what is left is the noise across the directions the fit cannot see (a ball's residual is
    mostly along its axis' travel), so raw residual vectors drawn as they are gave a third of the Gauss–Newton
    variance (measured on mill-xyz at 2 μm); the modified residuals restore noise of variance ≈ σ̂² in every
    coordinate."""
    r = np.concatenate([v.reshape(-1) for v in result.ball_residual_um.values()])
    h = np.concatenate([v.reshape(-1) for v in result.leverage.values()])
    pool = r / np.sqrt(np.clip(1.0 - h, LEVERAGE_FLOOR, None))
    pool = pool[h < 1.0 - LEVERAGE_FLOOR] - pool[h < 1.0 - LEVERAGE_FLOOR].mean()
    axes = {}
    for w, v in result.ball_residual_um.items():
        sw = sweeps[w]
        draw = pool[rng.integers(0, len(pool), size=v.shape)]
        axes[w] = replace(sw, balls_mm=sw.balls_mm - v * UM + draw * UM, by_direction={})
    return replace(sweeps, axes={**sweeps.axes, **axes})


def bootstrap_covariance(sweeps: Sweeps, machine: MachineTool, result: ChainIdentificationResult, n_boot: int,
                         seed: int = 0, **settings) -> ChainIdentificationResult:
    """``result`` with ``cov`` replaced by the residual bootstrap's (``n_boot`` ≥ 2 draws of
    :func:`resampled_sweeps`, each identified again with ``settings``; the sample covariance of the parameter
    vectors), through the bootstrap loop every family shares (:func:`errormap.smoothing.bootstrap_draws`).
    Unlike σ̂²·(JᵀJ)⁻¹ it keeps the nonlinear method's spread and does not assume Gaussian tracker noise."""
    from .smoothing import bootstrap_draws
    if n_boot < 2:
        raise ValueError(f"Expected n_boot >= 2 (a covariance needs two draws), got {n_boot}")

    def draw(s: int) -> np.ndarray:
        sw = resampled_sweeps(sweeps, result, np.random.default_rng(s))
        el = ChainIdentification(**settings).fit(sw, machine).elements_
        return parameter_vector(el, result.param_slot, result.param_station)
    Y = bootstrap_draws(draw, n_boot, seed, len(result.param_slot))
    return replace(result, cov=np.cov(Y.T),
                   covariance_info={"method": "residual-bootstrap", "n_boot": n_boot, "seed": seed})


def smooth_chain(result: ChainIdentificationResult, machine: MachineTool) -> ChainIdentificationResult:
    """``result`` with every function slot's station values smoothed by the grinder's UBRE smoother
    (:func:`errormap.smoothing.smooth_blocks`, weighted by ``result.cov``: Gauss–Newton's or the bootstrap's;
    a full-turn axis periodic over its distinct stations), the constants as identified, and the covariance
    ``H Σ Hᵀ`` plus the smoother's estimated squared bias per slot on the diagonal. The interpolating set is
    what :meth:`ChainIdentification.fit` gives; this is opt-in (``covariance_info['smoothing']`` says how)."""
    from .smoothing import apply_blocks, smooth_blocks
    el = result.elements_
    slots, st = np.array(result.param_slot), result.param_station
    y = parameter_vector(el, result.param_slot, st)
    blocks, full = {}, {}
    for s in machine.slots:
        if not s.is_function:
            continue
        ax = next(a for a in machine.axes if a.word == s.axis)
        idx = np.flatnonzero((slots == s.name) & (st >= 0))
        full[s.name] = idx = idx[np.argsort(st[idx])]
        blocks[s.name] = (idx[:-1], True) if ax.full_turn else (idx, False)
    Hb, smoothing, bias_var, extra = smooth_blocks(y, result.cov, blocks)
    copies = [(full[s][0], full[s][-1]) for s, (idx, periodic) in blocks.items() if periodic]
    for src, dst in copies:   # a full turn's last station is its first pose
        bias_var[dst], extra[dst] = bias_var[src], extra[src]
    theta, cov = apply_blocks(Hb, blocks, y, result.cov, copies)
    cov[np.diag_indices_from(cov)] += bias_var
    fun = {s: theta[idx] for s, idx in full.items()}
    elements = ChainElementSet(machine, el.stations, fun, el.constants, el.machine_name, el.machine_sha256)
    info = {**result.covariance_info, "smoothing": smoothing}
    return replace(result, elements_=elements, cov=cov, covariance_info=info,
                   prior_extra=extra)


def station_error_rms(machine: MachineTool, elements: ChainElementSet, truth: ChainElementSet) -> float:
    """RMS of (``elements`` − ``truth``) over every function slot at ``elements``' stations (the truth's own
    values there, the other axes parked; μm and μrad mixed): how far an identification is from a known truth."""
    col = {a.word: j for j, a in enumerate(machine.axes)}
    sidx = {s: j for j, s in enumerate(machine.slot_names)}
    err = []
    for s in machine.slots:
        if s.is_function:
            st = elements.stations[next(a for a in machine.axes if a.word == s.axis).column]
            q = np.tile(park_axes(machine), (st.size, 1))
            q[:, col[s.axis]] = st
            err.append(elements.functions[s.name] - truth.values(q)[:, sidx[s.name]])
    return float(np.sqrt(np.mean(np.concatenate(err) ** 2)))


__all__ = ["ChainIdentification", "ChainIdentificationResult", "bootstrap_covariance",
           "parameter_vector", "resampled_sweeps", "root_axis", "smooth_chain",
           "station_error_rms", "AXIS_WORDS"]
