"""The benchmark's rows on a machine-tool chain file (``volcomp benchmark --machine mill-xyz``).

Per condition (no effect, then each of the settings' undeclared effects the machine has axes for), the
user's path through the CLI's workflow functions (:mod:`.measurement`), files left in
``DIR/chains/MACHINE/CONDITION/``: hidden truth → tracker sweeps → ``identify`` → ``n_checks`` check
measurements → ``diagnose``; then the test path (the four body diagonals of the linear axes' volume, inset
:data:`INSET`; a turning centre: :func:`turning_path` at :data:`TURNING_C_POSITIONS`) compensated by the
``exact`` chain solver with the identified set, with the loop's ``model.json`` and with the chain network
(:func:`learned_chain_row`), beside ``volume_points`` random points. Residual: TRUE (the truth at
:data:`PATH_TEMP_C` and each axis' approach direction, driven with the compensated axes, minus the target,
μm), beside the uncompensated baseline; the diagnosis's held-out MEASURED residual beside the loop row with
its plain baselines and the noise floor. docs/reference/benchmark.md ("Machine-tool chain files").
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.stats import residual_stats

from .benchmark_common import bench_row, rng_streams, say, scored, with_volume

INSET = 0.02
"""The diagonals start and end this fraction of each linear stroke inside its ends (the compensated axes
must stay inside the strokes)."""
PATH_TEMP_C = 24.0
"""Temperature of the test path (a warm machine, as the grinder's flute path)."""
EFFECTS = {"thermal": "thermal:X", "reversal": "reversal:Z", "pitch": "periodic:X", "worm": "harmonic:{rot}",
           "interaction": "interaction:X*Z"}
"""The grinder's undeclared effects (settings ``effects``) on a chain: the same kinds on the chain's
axes; ``worm`` on the first full-turn rotary axis."""


TURNING_C_POSITIONS = 8
"""Positions of the rotary axis (equally spaced over the turn) of the turning path's face/diameter set."""
TURNING_CLEARANCE_MM = 10.0
"""Points whose nominal tool point is closer than this to the rotary axis' line are left out of the turning
path: there the rotary axis' lever (|d tool point / d angle| in mm per rad) vanishes and the exact solver
must turn it far for a sideways error (``tests/test_lathe_compensate.py``); a turning program does not
ask a C move on the centre line."""
TURNING_RADIUS_FRACTION = 0.75
"""The diameter line and set: the radial axis at this fraction of its stroke."""


@dataclass
class ChainPath:
    """Test points: ``axes`` (n, k) nominal axes, ``cond`` {name: (n,)} the truth's conditions, ``name``."""

    name: str
    axes: np.ndarray
    cond: dict


def chain_effects(machine, names) -> tuple[list, list]:
    """``([(grinder name, chain effect)], [skipped why])`` of the settings' effect names on ``machine``."""
    words = [a.word for a in machine.axes]
    rot = next((a.word for a in machine.axes if a.full_turn), None)
    out, skipped = [], []
    for n in names:
        if n not in EFFECTS:
            skipped.append(f"effect {n}: no chain form (the chain's simulator draws {', '.join(EFFECTS)})")
            continue
        if n == "worm" and rot is None:
            skipped.append(f"effect {n}: {machine.name} has no full-turn rotary axis")
            continue
        e = EFFECTS[n].format(rot=rot)
        need = e.split(":")[1].split("*")
        if not all(w in words for w in need):
            skipped.append(f"effect {n} ({e}): {machine.name} has no axis {[w for w in need if w not in words][0]}")
            continue
        out.append((n, e))
    return out, skipped


def _rotary_home(machine) -> np.ndarray:
    """(k,) the value each rotary axis is held at on the diagonals: 0 where inside its stroke, else the middle."""
    lo, hi = machine.stroke_lo, machine.stroke_hi
    return np.where((lo <= 0.0) & (hi >= 0.0), 0.0, 0.5 * (lo + hi))


def diagonal_path(machine, points_per_diagonal: int) -> ChainPath:
    """The four body diagonals of the linear axes' box (ISO 230-6), each from a corner to the opposite one;
    the approach direction of each axis is that of its motion along the diagonal."""
    from ...solvers.chain_exact import linear_axes
    lin, _ = linear_axes(machine)
    lo, hi = machine.stroke_lo, machine.stroke_hi
    span = hi - lo
    a0, a1 = lo + INSET * span, hi - INSET * span
    home = _rotary_home(machine)
    t = np.linspace(0.0, 1.0, points_per_diagonal)
    axes, dirs = [], []
    for flip in ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)):   # start corners; the end is the opposite corner
        start, end = home.copy(), home.copy()
        d = np.ones(len(machine.axes))
        for f, j in zip(flip, lin):
            start[j], end[j] = (a1[j], a0[j]) if f else (a0[j], a1[j])
            d[j] = -1.0 if f else 1.0
        axes.append(start + t[:, None] * (end - start))
        dirs.append(np.broadcast_to(d, (len(t), len(d))))
    axes, dirs = np.vstack(axes), np.vstack(dirs)
    return ChainPath(f"4 body diagonals ({len(axes)} points)", axes, _conditions(machine, len(axes), dirs))


def turning_path(machine, points_per_line: int) -> ChainPath:
    """The judging path of a machine with two linear axes and one full-turn rotary axis (module doc): a
    line along each linear axis (the other linear axis at :data:`TURNING_RADIUS_FRACTION` of its stroke
    for the first axis' line, at its stroke middle for the second's, the rotary axis at 0), then at
    :data:`TURNING_C_POSITIONS` rotary positions a face set (first linear axis' lower end + inset, four
    positions of the second) and a diameter set (second axis at the radius fraction, four positions of the
    first). Points nearer than :data:`TURNING_CLEARANCE_MM` to the rotary axis' line are left out. Positive
    approach on every axis. ValueError for any other machine."""
    from ...solvers.chain_exact import nominal_and_jacobian
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    rot = [j for j, a in enumerate(machine.axes) if a.kind == "rotary"]
    if len(machine.axes) != 3 or len(lin) != 2 or len(rot) != 1 or not machine.axes[rot[0]].full_turn:
        raise ValueError(f"{machine.name}: the turning path needs two linear axes and one full-turn rotary axis "
                         f"(its axes: {' '.join(a.word for a in machine.axes)})")
    lo, hi = machine.stroke_lo, machine.stroke_hi
    a0, a1 = lo + INSET * (hi - lo), hi - INSET * (hi - lo)
    r = rot[0]
    pts = []
    for j, other, at in ((lin[0], lin[1], TURNING_RADIUS_FRACTION), (lin[1], lin[0], 0.5)):
        line = np.zeros((points_per_line, 3))
        line[:, j] = np.linspace(a0[j], a1[j], points_per_line)
        line[:, other] = lo[other] + at * (hi[other] - lo[other])
        pts.append(line)
    u = np.linspace(0.0, 1.0, 4)
    for c in lo[r] + (hi[r] - lo[r]) * np.arange(TURNING_C_POSITIONS) / TURNING_C_POSITIONS:
        for j, other, at in ((lin[1], lin[0], None), (lin[0], lin[1], TURNING_RADIUS_FRACTION)):
            blk = np.zeros((4, 3))
            blk[:, j] = a0[j] + u * (a1[j] - a0[j])
            blk[:, other] = a0[other] if at is None else lo[other] + at * (hi[other] - lo[other])
            blk[:, r] = c
            pts.append(blk)
    axes = np.vstack(pts)
    _, J = nominal_and_jacobian(machine, axes)
    lever_mm = np.linalg.norm(J[:, :, r], axis=1) * (180.0 / np.pi)  # mm per rad
    axes = axes[lever_mm >= TURNING_CLEARANCE_MM]
    n = len(axes)
    name = (f"turning: lines along {machine.axes[lin[0]].word} and {machine.axes[lin[1]].word}, face/diameter set "
            f"at {TURNING_C_POSITIONS} {machine.axes[r].word} positions ({n} points)")
    return ChainPath(name, axes, _conditions(machine, n, np.ones((n, 3))))


def judging_path(machine, points: int) -> ChainPath:
    """The benchmark's test path of ``machine``: the body diagonals where it has three linear axes, else the
    turning path; ValueError naming both reasons for any other machine."""
    try:
        return diagonal_path(machine, points)
    except ValueError as exc:
        try:
            return turning_path(machine, points)
        except ValueError as exc2:
            raise ValueError(f"{exc}; {exc2}") from None


def volume_path(machine, n: int, seed) -> ChainPath:
    """``n`` uniform random points over every stroke, positive approach."""
    rng = np.random.default_rng(seed)
    lo, hi = machine.stroke_lo, machine.stroke_hi
    axes = lo + (hi - lo) * rng.random((n, len(machine.axes)))
    return ChainPath(f"volume ({n} points)", axes, _conditions(machine, n, np.ones((n, len(machine.axes)))))


def _conditions(machine, n, dirs) -> dict:
    return {"temp_c": np.full(n, PATH_TEMP_C), **{f"dir_{a.word.lower()}": dirs[:, j] for j, a in enumerate(machine.axes)}}


class _TruthAt:
    """The truth at a path's conditions: ``predict(axes) -> (n, 3)`` μm (axes: the path's points, in order)."""

    def __init__(self, truth, cond):
        self.truth, self.cond = truth, cond

    def predict(self, axes):
        return self.truth.spatial_error(axes, **self.cond)


def compensate_chain_true(machine, truth, field_, path: ChainPath) -> dict:
    """Exact compensation of ``path`` with ``field_`` (None: the program run as written); TRUE residual (RMS,
    max) on ``truth`` at the path's conditions, and with a field the solver's time per point, worst model
    residual and failures."""
    from ...solvers import solve
    from ...solvers.chain_exact import nominal_and_jacobian
    from .compensate_report import true_residual_um
    targets, _ = nominal_and_jacobian(machine, path.axes)
    r = None if field_ is None else solve("exact", field_, targets, machine, target_axes=path.axes,
                                          progress=False)
    axes = path.axes if r is None else r.axes
    st = residual_stats(true_residual_um(_TruthAt(truth, path.cond), machine, axes, targets))
    out = {"true_rms_um": st["rms_um"], "true_max_um": st["max_um"]}
    if r is not None:
        out.update(seconds_per_point=r.seconds / len(targets), points=len(targets),
                   model_max_um=float(np.max(r.residual_norm_um)), failures=int(np.count_nonzero(~r.success)))
    return out


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)


def run_chain(machine, s, log, out_dir) -> list:
    """The rows of ``machine`` (a machine-tool chain) under the settings ``s`` into ``log`` (the benchmark's
    :class:`RowLog`). Returns the skipped conditions (``[{"machine", "why"}]``)."""
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.chain_truth import ChainTruth
    from .identification import identify_chain_files
    from .measurement import simulate_chain, sweeps_chain
    streams, skipped = rng_streams(s.seed), []
    try:
        path = judging_path(machine, s.chain_path_points)
    except ValueError as exc:  # neither three linear axes (body diagonals) nor a turning centre
        return [{"machine": machine.name, "why": f"compensation not available: {exc}"}]
    volume = volume_path(machine, s.volume_points, streams["volume_points"]) if s.volume_points else None
    effects, why = chain_effects(machine, s.effects)
    skipped += [{"machine": machine.name, "why": w} for w in why]
    sweep_seed = int(streams["sweep_noise"].generate_state(1)[0])
    base = Path(out_dir) / "chains" / _slug(machine.name)
    for gname, eff in [(None, None), *effects]:
        cname = "effect=none" if eff is None else f"effect={gname} ({eff})"
        d = base / _slug(cname)
        say(f"{machine.name}: {cname}")
        common = {"group": "chain", "effect": eff, "noise_um": s.base_noise_um, "test_path": path.name,
                  "family": "default"}
        try:
            info = simulate_chain(machine, s.truth_seed, d / "sim", effects=() if eff is None else (eff,),
                                  noise_um=s.check_noise_um, checks=s.n_checks)
            # scoring only: the hidden truth, read back from the files the simulation wrote
            truth = ChainTruth(machine, ChainElementSet.load(d / "sim" / info["elements"], machine), info["effects"])
            unc = compensate_chain_true(machine, truth, None, path)
            common.update(uncompensated_rms_um=unc["true_rms_um"], uncompensated_max_um=unc["true_max_um"])
            if volume is not None:
                uv = compensate_chain_true(machine, truth, None, volume)
                common.update(volume_uncompensated_rms_um=uv["true_rms_um"])
            sw_path, n_sweep, _ = sweeps_chain(machine, d / "sweeps.csv", seed=s.truth_seed,
                                               effects=() if eff is None else (eff,), noise_um=s.base_noise_um,
                                               seed_noise=sweep_seed)
            t0 = time.perf_counter()
            _, el_path, _, _ = identify_chain_files(machine, [sw_path], d / "identified.json")
            id_s = time.perf_counter() - t0
            common["n_measurements"] = n_sweep
            fields = [("before closed loop", ChainField(machine, ChainElementSet.load(el_path, machine)), id_s,
                       {"closed_loop": False})]
            for n in s.chain_checks or (s.n_checks,):   # --checks N (repeatable): the loop once per count
                sim = d / "sim" if n == s.n_checks else d / f"sim_checks_{n}"
                if n != s.n_checks:   # the same truth (its seed), n check measurements
                    simulate_chain(machine, s.truth_seed, sim, effects=() if eff is None else (eff,),
                                   noise_um=s.check_noise_um, checks=n)
                label = "after closed loop" + (f", checks={n}" if s.chain_checks else "")
                fields.append((label, *_loop_model(machine, s, sim / "checks.csv", el_path, d, n, n_sweep, id_s)))
        except Exception as exc:  # the other conditions still run; the failure is a row, never faked numbers
            log.add(bench_row(machine.name, machine.kind, "parametric", cname, available=False,
                        not_available=f"condition failed: {type(exc).__name__}: {exc}", **common))
            continue
        for label, fld, fit_s, extra in fields:
            ex = compensate_chain_true(machine, truth, _at(fld, path.cond), path)
            r = bench_row(machine.name, machine.kind, "parametric", f"{cname} ({label})", solver="exact",
                          fit_seconds=fit_s, identify_seconds=id_s, **scored(ex), solvers={"exact": ex},
                          **{**common, **extra})
            vol = volume and compensate_chain_true(machine, truth, _at(fld, volume.cond), volume)
            log.add(with_volume(r, vol))
        log.add(learned_chain_row(machine, s, truth, el_path, (path, volume), f"{cname} (before closed loop)",
                                  {**common, "closed_loop": False}, id_s))
    return skipped


def learned_chain_row(machine, s, truth, el_path, paths, label: str, common: dict, id_s: float) -> dict:
    """The learned row of one condition: the identified set's feature points over the chain's axes (the
    default grid, ``volcomp featurepoints --machine``) → the chain network (``volcomp train``: LM, ``train_iter``
    iterations, ``train_s`` on top, the settings' network) → ``exact`` compensation of ``paths`` (the judging
    path, the volume points or None) → TRUE residual. A network that does not beat its plain baseline (OLS on
    the axes) is refused by the trainer: the row then says so (never faked numbers)."""
    import math
    from errormap.featurepoints import make_feature_points
    from training.trainers import TrainSettings, fit_field
    from ...model_file import read_model
    path, volume = paths
    try:
        fp = make_feature_points(machine, read_model(el_path, machine).field, meta={"elements_file": str(el_path)})
        settings = TrainSettings(max_iter=s.train_iter, max_time_s=math.inf if s.train_s is None else s.train_s,
                                 seed=s.seed, hidden=tuple(s.hidden), activation=s.activation,
                                 a_encoding=s.a_encoding)
        fit = fit_field(fp, settings, machine=machine, quiet=True, track=False)
    except Exception as exc:  # training unavailable, or no better than its baseline: said, never faked
        return bench_row(machine.name, machine.kind, "learned", label, available=False,
                         not_available=f"training failed: {type(exc).__name__}: {exc}", **common)
    say(f"{machine.name}: learned, {label}")
    ex = compensate_chain_true(machine, truth, fit.field, path)
    m = fit.metrics
    r = bench_row(machine.name, machine.kind, "learned", label, solver="exact",
                  fit_seconds=id_s + fit.seconds, identify_seconds=id_s, train_seconds=fit.seconds,
                  train_iterations=int(fit.history.iterations), train_val_rms_um=m.get("val_rms_um"),
                  train_val_max_um=m.get("val_max_um"),
                  train_baseline_ols_val_rms_um=m.get("baseline_ols_val_rms_um"),
                  n_featurepoints=len(fp.axes), **scored(ex), solvers={"exact": ex}, **common)
    return with_volume(r, volume and compensate_chain_true(machine, truth, fit.field, volume))


def _loop_model(machine, s, checks_path, el_path, d, n: int, n_sweep: int, id_s: float) -> tuple:
    """``(the loop's model, fit seconds, row fields)`` of ``volcomp diagnose`` on ``n`` checks (the parametric
    column: the loop alone, no learned stage), its held-out MEASURED residual beside its plain baselines."""
    from errormap.diagnosis.loop_model import load_chain_model_file
    from .measurement import diagnose_chain
    t0 = time.perf_counter()
    out = d / "diagnosis" if n == s.n_checks else d / f"diagnosis_checks_{n}"
    summary, _ = diagnose_chain(checks_path, machine, el_path, out, noise_um=s.check_noise_um, learn=False)
    diag_s = time.perf_counter() - t0
    st = summary["stages"]
    floor = float(np.sqrt(3.0) * s.check_noise_um)
    loop = {"closed_loop": True, "diagnosis_seconds": diag_s, "n_checks": n, "kept_stage": summary["kept_stage"],
            "effects_found": [f"{e['kind']}:{e['axis']}" for e in summary["effects"]],
            "checks_rms_before_um": st["identified"]["held_out"]["rms_um"],
            "checks_rms_after_um": summary["held_out_rms_um"],
            "held_out_ols_linear_um": st["baseline_ols_linear"]["held_out"]["rms_um"],
            "held_out_ols_update_um": st["baseline_ols_update"].get("held_out", {}).get("rms_um"),
            "noise_floor_um": floor, "held_out_over_floor": summary["held_out_rms_um"] / floor,
            "n_measurements": n_sweep + n, "model_verdict": summary.get("verdict")}
    return load_chain_model_file(summary["model_file"], machine), id_s + diag_s, loop


def _at(field_, cond: dict):
    """``field_`` told the path's conditions its effect terms need (as ``compensate --temp-c/--dir-x`` tells it)."""
    needs = tuple(getattr(field_, "needs", ()))
    # a condition constant along the path is told as one value: the solver may evaluate the field on a subset
    # of the points (its retries of unconverged points, as near a turning centre's spindle axis)
    return field_.with_conditions({c: (float(cond[c][0]) if np.all(cond[c] == cond[c][0]) else cond[c])
                                   for c in needs}) if needs else field_
