"""Why a machine-tool chain's identification is weak or strong: a simulation study of its sweep design.

For a machine file and a seeded truth (:mod:`errormap.chain_truth`): the sweeps identified without noise (the
truth in the identification's gauge, ``noise_free_max_um``) and with ``noise_um`` (per parameter ``z``, the
error in standard errors); per slot the volume RMS its identification error alone causes, per group (one
axis' component errors; the constants) its rank, condition and propagated σ; the identified field minus the
truth's over a grid (``grid_max_um``, ``grid_rms_um``). The report's keys:
``docs/reference/machine-tool-chains.md``. A study for the machine file's author: it reads the hidden truth
and never feeds it to an estimator."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .machine_tool import MachineTool
from .identification import ChainIdentification
from .chain_truth import make_chain_truth, volume_grid
from .chain_sweeps import simulated_sweeps, swept_words
from .seeds import spawn_rngs
from .sweeps import sweeps_from_columns

GRID_POINTS = 4000
SIGMA_DRAWS = 32
"""Draws from a group's covariance block for its propagated σ (the RMS over 32 draws is within ~13 % of its
expectation: a ranking figure, not a bound)."""


@dataclass
class IdentifiabilityReport:
    machine: str
    seed: int
    noise_um: float
    grid_max_um: float
    grid_rms_um: float
    noise_free_max_um: float
    z_rms: float
    condition: float
    unobservable: list
    slots: list
    groups: list

    def lines(self) -> list[str]:
        out = [f"{self.machine}, seed {self.seed}, tracker noise {self.noise_um:g} um: identified model minus truth "
               f"over the volume grid max {self.grid_max_um:.3g} um, RMS {self.grid_rms_um:.3g} um "
               f"(noise-free identification {self.noise_free_max_um:.2g} um); z-score RMS {self.z_rms:.2f}; "
               f"scaled condition {self.condition:.3g}"]
        if self.unobservable:
            out.append("unobservable (held at zero): " + ", ".join(self.unobservable))
        out += [f"  group {g['group']}: {g['rank']}/{g['n']} identified, condition {g['condition']:.3g}, "
                f"propagated sigma RMS {g['sigma_rms_um']:.3g} um" for g in self.groups]
        top = sorted(self.slots, key=lambda r: -r["volume_rms_um"])[:6]
        out.append("  largest slots at the tool point: " + ", ".join(f"{r['slot']} {r['volume_rms_um']:.2g} um"
                                                                       for r in top))
        return out


def _vector(result) -> np.ndarray:
    el = result.elements_
    return np.array([el.constants[s] if st < 0 else el.functions[s][st]
                     for s, st in zip(result.param_slot, result.param_station)])


def _with(elements, slots, stations, values):
    """A copy of ``elements`` with the given (slot, station) parameters set (station −1: a constant)."""
    out = elements.copy()
    out._splines = {}
    for s, st, v in zip(slots, stations, values):
        if st < 0:
            out.constants[s] = float(v)
        else:
            out.functions[s][st] = v
            ax = next(a for a in out.machine.axes if a.word == next(t for t in out.machine.slots if t.name == s).axis)
            if ax.full_turn and st == 0:
                out.functions[s][-1] = v
    return out


def identifiability(machine: MachineTool, seed: int = 0, noise_um: float = 2.0, seed_noise: int | None = None,
                    grid_points: int = GRID_POINTS) -> IdentifiabilityReport:
    """The study of the module doc for ``machine`` on the default-family truth of ``seed`` (tracker noise
    seed ``seed_noise``, default ``seed``)."""
    if not noise_um > 0:
        raise ValueError(f"Expected noise_um > 0, got {noise_um}")
    words = swept_words(machine)
    truth = make_chain_truth(machine, seed)
    sn = seed if seed_noise is None else seed_noise

    def fit(noise):
        sw = sweeps_from_columns(simulated_sweeps(truth, noise_um=noise, seed=sn), axes=words)
        return ChainIdentification().fit(sw, machine).result_

    r0, r = fit(0.0), fit(noise_um)
    grid = volume_grid(machine, grid_points)
    field = lambda el: machine.spatial_error(grid, el.values(grid))  # noqa: E731
    e_true, e0 = field(truth.elements), field(r0.elements_)
    err = np.linalg.norm(field(r.elements_) - e_true, axis=1)
    v0, v = _vector(r0), _vector(r)
    slot_of, st_of = np.array(r.param_slot), np.asarray(r.param_station)
    sd = np.sqrt(np.clip(np.diag(r.cov), 0.0, None))
    ok = sd > 0
    z = np.where(ok, (v - v0) / np.where(ok, sd, 1.0), np.nan)
    axis_of = {t.name: (t.axis if t.is_function else "constants") for t in machine.slots}
    slots = []
    for s in dict.fromkeys(r.param_slot):
        k = slot_of == s
        zz = z[k][np.isfinite(z[k])]
        el = _with(r0.elements_, slot_of[k], st_of[k], v[k])
        slots.append({"slot": s, "group": axis_of[s], "n": int(k.sum()), "sd_median": float(np.median(sd[k])),
                      "z_rms": float(np.sqrt(np.mean(zz**2))) if zz.size else float("nan"),
                      "volume_rms_um": float(np.sqrt(np.mean(np.sum((field(el) - e0) ** 2, axis=1))))})
    groups = []
    rng = spawn_rngs(seed, 1)[0]
    for g in dict.fromkeys(axis_of[s] for s in r.param_slot):
        k = np.flatnonzero([axis_of[s] == g for s in r.param_slot])
        kk = k[ok[k]]
        # one parameter per tie (a full turn's last station is its first; a squareness' straightness ends)
        rho = r.cov[np.ix_(kk, kk)] / np.outer(sd[kk], sd[kk])
        kk = kk[[not np.any(np.abs(rho[j, :j]) > 1.0 - 1e-9) for j in range(kk.size)]]
        C = r.cov[np.ix_(kk, kk)]
        d = np.sqrt(np.diag(C))
        ev = np.linalg.eigvalsh(C / np.outer(d, d))
        # draws from the block's covariance (eigen-decomposition: semidefinite blocks are fine)
        w, V = np.linalg.eigh(C)
        L = V * np.sqrt(np.clip(w, 0.0, None))
        rms = []
        for _ in range(SIGMA_DRAWS):
            el = _with(r0.elements_, slot_of[kk], st_of[kk], v0[kk] + L @ rng.normal(size=kk.size))
            rms.append(np.mean(np.sum((field(el) - e0) ** 2, axis=1)))
        groups.append({"group": g, "n": int(k.size), "rank": int(kk.size),
                       "condition": float(np.sqrt(ev.max() / max(ev.min(), 1e-300))),
                       "sigma_rms_um": float(np.sqrt(np.mean(rms)))})
    zz = z[np.isfinite(z)]
    return IdentifiabilityReport(machine.name, seed, noise_um, float(err.max()), float(np.sqrt(np.mean(err**2))),
                                 float(np.linalg.norm(e0 - e_true, axis=1).max()), float(np.sqrt(np.mean(zz**2))),
                                 r.condition, list(r.unobservable), slots, groups)


__all__ = ["IdentifiabilityReport", "identifiability"]
