"""Laser-tracker axis sweeps of any machine-tool chain: the body chains and the simulator (the file and its
reader: :mod:`errormap.sweeps`).

A **body** is what an axis moves: the frame right after the axis' motion and component errors in its
side's chain, in the machine base frame; its three target balls (``[targets]``, mm in that frame) are
measured by a tracker at an unknown rigid pose. A sweep of axis ``W`` moves it through its stations (default
21 over its stroke, a full turn 0 … 360°) while every other axis is parked at the lower end of its stroke
(``docs/explanation/identification.md``). Shapes: axes (n, k) in ``machine.axis_columns`` order, slot values
(n, P) in ``machine.slot_names`` order, body frames (n, 4, 4), balls (n, 3, 3) [pose, target, xyz]."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scipy.spatial.transform import Rotation

from .chain import ET, Chain, Joint
from .machine_checks import MachineFileError
from .machine_tool import MachineTool
from .sweeps import OPTIONAL_COLUMNS, REQUIRED_COLUMNS, SWEEP_FORMAT, swept_words, write_sweeps

REF_TEMP_C = 20.0
DEFAULT_STATIONS = 21
UM_MM = 1e-3

__all__ = ["BodyChain", "body_chain", "park_axes", "sweep_stations", "simulated_sweeps", "random_tracker_pose",
           "swept_words", "write_sweeps", "SWEEP_FORMAT", "REQUIRED_COLUMNS", "OPTIONAL_COLUMNS"]


@dataclass
class BodyChain:
    """The chain from the machine base to the body of axis ``word``: ``chain`` a compiled
    :class:`~errormap.chain.Chain` over the joints it contains (``joint_cols`` their columns in
    the machine's axes), parameters ``slot_cols`` (indices into ``machine.slot_names``)."""

    word: str
    chain: Chain
    joint_cols: np.ndarray
    slot_cols: np.ndarray
    n_slots: int

    def frames(self, axes, values) -> np.ndarray:
        """All cumulative frames (n, n_et + 1, 4, 4) for machine axes (n, k) and slot values (n, P)."""
        return self.chain.frames(np.asarray(axes, float)[:, self.joint_cols],
                                 np.asarray(values, float)[:, self.slot_cols])

    def balls(self, axes, values, mounts) -> np.ndarray:
        """Ball centres in the base frame (mm), (n, m, 3) for mounts (m, 3)."""
        F = self.frames(axes, values)[:, -1]
        return np.einsum("nij,kj->nki", F[:, :3, :3], np.asarray(mounts, float)) + F[:, None, :3, 3]

    def balls_and_jacobian(self, axes, values, mounts):
        """``(balls (n, m, 3) mm, ∂balls/∂slot values (n, m, 3, P) mm per μm or μrad)`` (all P slots
        of the machine; zero columns for slots outside this body's chain)."""
        F = self.frames(axes, values)
        ne = len(self.chain.ets)
        mounts = np.asarray(mounts, float)
        last = F[:, -1]
        balls = np.einsum("nij,kj->nki", last[:, :3, :3], mounts) + last[:, None, :3, 3]
        ax = np.einsum("nmij,mj->nmi", F[:, :ne, :3, :3], np.eye(3)[self.chain.axis])   # (n, ne, 3)
        org = F[:, :ne, :3, 3]
        rot = self.chain.kind_r[None, None, :, None]
        lin = np.where(rot, np.cross(ax[:, None], balls[:, :, None] - org[:, None]), ax[:, None])  # (n, m, ne, 3)
        S = self.chain.slot_matrix()                                                    # (ne, Pb)
        J = np.zeros(balls.shape + (self.n_slots,))
        J[..., self.slot_cols] = np.einsum("nkei,ep->nkip", lin, S)
        return balls, J


def body_chain(machine: MachineTool, word: str) -> BodyChain:
    """The :class:`BodyChain` of axis ``word`` (its side's ETs up to its body index)."""
    if word not in machine.body_index:
        raise ValueError(f"axis {word!r} has no body (no component errors placed) in {machine.name!r}")
    side, k = machine.body_index[word]
    ets = list((machine.work_ets if side == "work" else machine.tool_ets)[:k])
    used = sorted({e.joint for e in ets if e.joint is not None})
    remap = {j: i for i, j in enumerate(used)}
    ets = [ET(e.kind, e.axis, e.value, None if e.joint is None else remap[e.joint], e.sign, e.slot, e.coef) for e in ets]
    joints = [Joint(machine.axes[j].word.lower(), "revolute" if machine.axes[j].kind == "rotary" else "prismatic",
                    *machine.axes[j].stroke) for j in used]
    chain = Chain.compile(ets, joints, name=f"{machine.name}:{word}", shared_slots=True)
    idx = {n: i for i, n in enumerate(machine.slot_names)}
    return BodyChain(word, chain, np.array(used, dtype=int), np.array([idx[n] for n in chain.param_names], dtype=int),
                     len(machine.slot_names))


def random_tracker_pose(rng: np.random.Generator):
    """An arbitrary rigid pose ``machine_in_tracker`` (R (3,3), t (3,) mm): a uniformly random
    rotation and a translation of 1-3 m, as a tracker standing beside the machine."""
    R = Rotation.random(random_state=rng).as_matrix()
    direction = rng.normal(size=3)
    t = direction / np.linalg.norm(direction) * rng.uniform(1000.0, 3000.0)
    return R, t


def park_axes(machine: MachineTool) -> np.ndarray:
    """Where the other axes stand during a sweep: the lower stroke ends, shape (k,)."""
    return machine.stroke_lo.copy()


def sweep_stations(machine: MachineTool, n_stations: int = DEFAULT_STATIONS) -> dict:
    """Commands per axis word, ``n_stations`` equally spaced over each stroke (a full turn: 0…360°
    from the lower end, both ends measured)."""
    return {a.word: np.linspace(*a.stroke, n_stations) for a in machine.axes if machine.slots_of(a.word)}


def simulated_sweeps(truth, noise_um: float = 2.0, seed=0, tracker_pose=None, n_stations: int = DEFAULT_STATIONS,
                       bidirectional: bool = False, dt_s: float = 20.0, warmup_c: float = 0.0, stations: dict | None = None,
                       axes=None) -> dict:
    """Simulated tracker sweeps of a truth machine (:class:`errormap.chain_truth.ChainTruth`, or the grinder's
    :class:`errormap.chain_truth.ChainTruth`; its effects included), as a dict of sweep-file columns
    (axis, station, command, target, x_mm, y_mm, z_mm, direction, time_s, temp_c; each (3·rows,), rows in
    measurement order: per time, then target).

    ``noise_um``: isotropic Gaussian noise σ per coordinate (μm). ``seed``: seeds the tracker pose (when
    not given) and the noise. ``tracker_pose``: ``(R (3,3), t (3,) mm)`` machine -> tracker; default a
    random pose. ``bidirectional``: each axis is also swept back down (``direction`` -1). ``warmup_c``:
    temperature rise over the run, ``temp_c = 20 + warmup_c·(1 - exp(-t/2400 s))`` (default 0: the
    reference temperature). ``stations``: commands per axis column (``x_mm``, ``a_deg`` …, as an element
    set's stations), default ``n_stations`` equally spaced over each stroke. ``axes``: the axis words
    swept (default every axis with error slots, :func:`swept_words`)."""
    m = truth.machine
    missing = [w for w in swept_words(m) if w not in m.targets]
    if missing:
        raise MachineFileError(f"{m.path or m.name}: no [targets] for axis {', '.join(missing)}: a sweep needs three "
                               f"target balls per moving body (add [targets] {missing[0]} = [[x, y, z], ...] to the "
                               "machine file)")
    rng = np.random.default_rng(seed)
    R_mt, t_mt = random_tracker_pose(rng) if tracker_pose is None else (np.asarray(tracker_pose[0], float),
                                                                         np.asarray(tracker_pose[1], float))
    st = sweep_stations(m, n_stations)
    if stations is not None:
        col = {a.column: a.word for a in m.axes}
        st.update({col[k]: np.asarray(v, dtype=float) for k, v in stations.items()})
    park = park_axes(m)
    words = [a.word for a in m.axes]
    cols = {k: [] for k in ("axis", "station", "command", "target", "x_mm", "y_mm", "z_mm", "direction", "time_s",
                            "temp_c")}
    t_now = 0.0
    for w in swept_words(m) if axes is None else axes:
        bc = body_chain(m, w)
        cmd = st[w]
        idx = np.arange(cmd.size)
        for order, direction in [(idx, 1)] + ([(idx[::-1], -1)] if bidirectional else []):
            n = len(order)
            pts = np.tile(park, (n, 1))
            pts[:, words.index(w)] = cmd[order]
            time_s = t_now + dt_s * np.arange(n)
            t_now = time_s[-1] + dt_s
            temp = REF_TEMP_C + warmup_c * (1.0 - np.exp(-time_s / 2400.0))
            cond = {"temp_c": temp, **{f"dir_{a.lower()}": np.ones(n) for a in words}}
            cond[f"dir_{w.lower()}"] = np.full(n, float(direction))
            balls = bc.balls(pts, truth.element_values(pts, **cond), m.targets[w])
            balls = np.einsum("ij,nkj->nki", R_mt, balls) + t_mt
            balls = balls + rng.normal(0.0, noise_um * UM_MM, balls.shape)
            for k in range(balls.shape[1]):
                cols["axis"].append(np.full(n, w))
                cols["station"].append(order)
                cols["command"].append(cmd[order])
                cols["target"].append(np.full(n, k + 1))
                for j, c in enumerate(("x_mm", "y_mm", "z_mm")):
                    cols[c].append(balls[:, k, j])
                cols["direction"].append(np.full(n, direction))
                cols["time_s"].append(time_s)
                cols["temp_c"].append(temp)
    out = {k: np.concatenate(v) for k, v in cols.items()}
    order = np.lexsort((out["target"], out["time_s"]))
    return {k: v[order] for k, v in out.items()}
