"""The benchmark's rows on a machine tool: one pipeline for every machine-tool chain (the built-in grinder,
``--machine mill-xyz``, ``five-axis-ac``, ``lathe-xzc``, a user's file; :mod:`compensation.app.workflows.benchmark`).

Per condition (:func:`bench_conditions`: sweep density, tracker noise, each undeclared catalogue effect, each
out-of-catalogue effect and none at each check count), the user's path through the CLI's workflow functions
(:mod:`.measurement`), files left in ``DIR/chains/MACHINE/CONDITION/``: hidden truth and check measurements
(``simulate``) → tracker sweeps → ``identify`` (its defaults) → on a condition with the closed loop ``diagnose``
(element update + effects; on an out-of-catalogue condition also its learned residual, the hybrid). The test
part (:mod:`.benchmark_paths`: the part the machine can make — the flute where the machine turns a workpiece
about X, else the four body diagonals, else a turning centre's lines and face/diameter set) and ``volume_points``
random points are compensated by ``exact`` with the identified set (parametric), with the chain network trained on
its feature points (learned; ``batched-ga`` on a subset beside it) and with the loop's ``model.json``. Residual:
TRUE (the truth at the part's conditions driven with the compensated axes, minus the target, μm) beside the
uncompensated baseline. docs/reference/benchmark.md.
"""
from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .benchmark_common import (EXPERIMENT, FEATURE_REUSE_TOL_UM, USER_LOOP, BenchmarkSettings, RowLog, bench_row,
                               rng_streams, say, scored, with_volume)
from .benchmark_paths import ChainPath, compensate_true, judging_path, volume_path, with_path_conditions

EFFECTS = {"thermal": "thermal:X", "reversal": "reversal:Z", "pitch": "periodic:X", "worm": "harmonic:{rot}",
           "interaction": "interaction:X*Z"}
"""The settings' undeclared catalogue effects (``effects``) on a chain: the kinds on the chain's axes; ``worm`` on
the first full-turn rotary axis."""


@dataclass
class BenchCondition:
    name: str
    group: str
    stations: int
    noise_um: float
    effect: str | None = None     # the settings' name (thermal, bump …)
    spec: str | None = None       # the truth's effect on this machine (thermal:X …)
    n_checks: int | None = None   # check measurements of the closed loop (None: the settings' n_checks)
    loop: bool = False            # run the closed loop (and its hybrid stage) even without an effect


def chain_effects(machine, names) -> tuple[list, list]:
    """``([(settings name, chain effect)], [skipped why])`` of the settings' catalogue effect names on ``machine``."""
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


def _truth_only_effects(machine, names) -> tuple[list, list]:
    """``([(name, chain effect)], [skipped why])`` of out-of-catalogue effect names, on their default axes."""
    from errormap.chain_truth import effect_key, parse_effect
    out, skipped = [], []
    for n in names:
        try:
            out.append((n, effect_key(*parse_effect(machine, n))))
        except ValueError as exc:
            skipped.append(f"effect {n}: {exc}")
    return out, skipped


def bench_conditions(machine, s: BenchmarkSettings) -> tuple[list[BenchCondition], list[str]]:
    """Density sweep (at the base noise), noise sweep (at the base density), each catalogue effect (base, with the
    loop), each out-of-catalogue effect and none at each check count (with the loop and its hybrid stage); and why
    an effect was left out on ``machine``."""
    out = {}
    for st in s.stations:
        name = f"stations={st}, noise={s.base_noise_um:g}um"
        out.setdefault(name, BenchCondition(name, "density", st, s.base_noise_um))
    for nz in s.noises_um:
        name = f"stations={s.base_stations}, noise={nz:g}um"
        out.setdefault(name, BenchCondition(name, "noise", s.base_stations, nz))
    effects, skipped = chain_effects(machine, s.effects)
    for eff, spec in effects:
        name = f"effect={eff}"
        out[name] = BenchCondition(name, "effect", s.base_stations, s.base_noise_um, eff, spec)
    ooc, why = _truth_only_effects(machine, s.ooc_effects)
    if s.ooc_effects:
        for eff, spec in (*ooc, ("none", None)):
            for nc in dict.fromkeys(s.ooc_checks):
                name = f"effect={eff}" + (f", checks={nc}" if nc != s.n_checks else "")
                out[name] = BenchCondition(name, "out-of-catalogue", s.base_stations, s.base_noise_um,
                                           None if eff == "none" else eff, spec, nc, True)
    return list(out.values()), skipped + why


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)


def loop_models(machine, model_path, cond: dict) -> dict:
    """``{"parametric": (terms, stage, field), "hybrid": ...}`` of a diagnose run's ``model.json``: the loop
    alone (without the learned part; its ``loop_alone`` elements and terms when the base was backfitted) and
    the kept model, each told the conditions ``cond`` (a test part's) its terms need."""
    from errormap.chain_elements import ChainElementSet
    from errormap.diagnosis.loop_model import ChainModelField, read_terms
    from ...model_file import read_model
    kept = read_model(model_path, machine).field   # checks the file (format, machine) before it is read here
    doc = json.loads(Path(model_path).read_text(encoding="utf-8"))
    # the loop alone had the terms the learned part replaced
    alone = doc.get("loop_alone") or {"elements": doc["elements"],
                                      "terms": doc["terms"] + doc.get("base_terms_replaced", [])}
    elements = ChainElementSet.load(Path(model_path).parent / alone["elements"], machine)
    key = "loop_alone" if "loop_alone" in doc else "terms"
    base = ChainModelField(machine, elements, read_terms(alone["terms"], machine, model_path, key))
    return {"parametric": (alone["terms"], doc.get("base_stage", doc["kept_stage"]),
                           with_path_conditions(base, cond)),
            "hybrid": (doc["terms"], doc["kept_stage"], with_path_conditions(kept, cond))}


class NetworkTrainer:
    """Trains the machine's network on an identified set's feature points as ``volcomp featurepoints`` → ``volcomp
    train --machine`` do (the default grid, the settings' network, LM, selection on off-grid points of the same
    model, the OLS baseline beside it), once per distinct feature-point set and network setting."""

    def __init__(self, machine, tracker, warm_up_axes):
        self.m, self.tracker, self.warm_up_axes = machine, tracker, warm_up_axes
        self.kind = machine.kind
        self.cache = []  # (network settings, feature-point errors, fit result, feature points, condition)

    def train(self, el_path, cond_name: str, s: BenchmarkSettings):
        """``(fit result, feature points, name of the condition reused or None)``."""
        from errormap.featurepoints import make_feature_points
        from training.trainers import TrackSettings, TrainSettings, fit_field
        from ...model_file import read_model
        fp = make_feature_points(self.m, read_model(el_path, self.m).field,
                                 meta={"elements_file": str(el_path), "benchmark_condition": cond_name})
        key = (tuple(s.hidden), s.activation, s.a_encoding, s.train_iter, s.train_s)
        for k, errs, res, fp0, name in self.cache:
            if k == key and errs.shape == fp.errors_um.shape and \
                    np.max(np.abs(errs - fp.errors_um)) < FEATURE_REUSE_TOL_UM:
                return res, fp0, name
        say(f"{self.m.name}: training the network ({cond_name}, LM, {s.train_iter} iterations"
            + (f", ≤ {s.train_s:g} s)" if s.train_s is not None else ")"))
        tr = self.tracker
        settings = TrainSettings(trainer="lm", max_iter=s.train_iter, seed=s.seed,
                                 max_time_s=math.inf if s.train_s is None else s.train_s,
                                 hidden=tuple(s.hidden), activation=s.activation, a_encoding=s.a_encoding)
        tracking = TrackSettings(track=tr.enabled, tracking_uri=tr.uri if tr.enabled else None,
                                 parent_run_id=tr.parent_id, experiment=EXPERIMENT,
                                 run_name=f"{self.kind}/learned/train/{cond_name}",
                                 tags={"benchmark_condition": cond_name})
        res = fit_field(fp, settings, machine=self.m, tracking=tracking, quiet=True)
        res.field.predict(self.warm_up_axes)  # warm-up, so that compensation timings exclude it
        self.cache.append((key, fp.errors_um.copy(), res, fp, cond_name))
        return res, fp, None


class ChainBench:
    """The rows of one machine-tool chain: per condition the user's path (simulate → sweeps → identify →
    diagnose, files kept), parametric and learned on the test part and the volume, the closed loop after."""

    def __init__(self, machine, s: BenchmarkSettings, log: RowLog, out_dir, path: ChainPath):
        self.m, self.s, self.log, self.kind = machine, s, log, machine.kind
        self.path = path
        self.ga_idx = _subset(len(path.axes), s.ga_points)
        streams = rng_streams(s.seed)
        self.volume = volume_path(machine, s.volume_points, streams["volume_points"]) if s.volume_points else None
        self.sweep_seed = int(streams["sweep_noise"].generate_state(1)[0])
        self.base = Path(out_dir) / "chains" / _slug(machine.name)
        self.trainer = NetworkTrainer(machine, log.tracker, path.axes[:2])

    def row(self, path: str, label: str, **kw) -> dict:
        """A result row of this machine (:func:`bench_row`; its kind the registry's)."""
        return bench_row(self.m.name, self.kind, path, label, **kw)

    def _solve(self, truth, field_, method="exact", idx=None) -> dict:
        return compensate_true(self.m, self.s, self.path, truth, field_, method, idx=idx)

    def _volume(self, truth, field_):
        return compensate_true(self.m, self.s, self.volume, truth, field_) if self.volume is not None else None

    def measure(self, c: BenchCondition, d: Path):
        """Hidden truth + checks (``simulate``), sweeps, ``identify``: ``(truth, element-set path, identify
        seconds, sweep rows)``."""
        from errormap.chain_elements import ChainElementSet
        from errormap.chain_sweeps import simulated_sweeps
        from errormap.chain_truth import ChainTruth
        from errormap.sweeps import write_sweeps
        from .identification import identify_chain_files
        from .measurement import simulate_chain
        effects = () if c.spec is None else (c.spec,)
        info = simulate_chain(self.m, self.s.truth_seed, d / "sim", effects=effects, noise_um=self.s.check_noise_um,
                              checks=c.n_checks or self.s.n_checks)
        # scoring only: the hidden truth, read back from the files the simulation wrote
        truth = ChainTruth(self.m, ChainElementSet.load(d / "sim" / info["elements"], self.m), info["effects"])
        cols = simulated_sweeps(truth, noise_um=c.noise_um, seed=self.sweep_seed, n_stations=c.stations)
        sw = write_sweeps(d / "sweeps.csv", cols, comments=[
            f"machine: {self.m.name}", f"machine_sha256: {self.m.sha256}",
            f"truth: seed {self.s.truth_seed}", f"effects: {','.join(truth.effects) or 'none'}",
            f"noise_um: {c.noise_um}", f"seed_noise: {self.sweep_seed}", f"stations: {c.stations}",
            "tracker pose: seeded, unknown to the identification"])
        t0 = time.perf_counter()
        # volcomp identify with its defaults (smoothed, station-mean gauge, covariance)
        _, el_path, _, _ = identify_chain_files(self.m, [sw], d / "identified.json", n_boot=self.s.identify_bootstrap,
                                                seed=0)
        return truth, el_path, time.perf_counter() - t0, len(cols["axis"])

    def run_condition(self, c: BenchCondition) -> None:
        from errormap.chain_elements import ChainElementSet
        from errormap.chain_field import ChainField
        d = self.base / _slug(c.name)
        say(f"{self.m.name}: {c.name}")
        truth, el_path, id_s, n_sweep = self.measure(c, d)
        unc = self._solve(truth, None)
        common = {"group": c.group, "stations": c.stations, "noise_um": c.noise_um, "effect": c.effect,
                  "truth_effect": c.spec, "test_path": self.path.name, "n_measurements": n_sweep,
                  "uncompensated_rms_um": unc["true_rms_um"], "uncompensated_max_um": unc["true_max_um"]}
        if self.volume is not None:
            common["volume_uncompensated_rms_um"] = self._volume(truth, None)["true_rms_um"]
        loop = bool(c.effect or c.loop)
        label = c.name + (" (before closed loop)" if loop else "")
        field_ = ChainField(self.m, ChainElementSet.load(el_path, self.m))
        say(f"{self.m.name}: parametric, {label}")
        ex = self._solve(truth, field_)
        row = self.row("parametric", label, closed_loop=False, solver="exact", fit_seconds=id_s,
                       identify_seconds=id_s, **scored(ex), solvers={"exact": ex}, **common)
        self.log.add(with_volume(row, self._volume(truth, field_)))
        self.learned_row(truth, el_path, id_s, c.name, label, common)
        if loop:
            self.loop_rows(c, truth, el_path, id_s, d, common)

    def learned_row(self, truth, el_path, id_s, cond_name, label, common) -> None:
        """Feature points → the chain network → ``exact`` (whole part, volume) and ``batched-ga`` (subset); a
        network that fails or does not beat its OLS baseline is a row that says so."""
        try:
            fit, fp, reused = self.trainer.train(el_path, cond_name, self.s)
        except Exception as exc:  # training unavailable, or no better than its baseline: said, never faked
            self.log.add(self.row("learned", label, available=False, closed_loop=False,
                                  not_available=f"training failed: {type(exc).__name__}: {exc}", **common))
            return
        say(f"{self.m.name}: learned, {label}")
        ex = self._solve(truth, fit.field)
        ga = self._solve(truth, fit.field, "batched-ga", idx=self.ga_idx)
        m = fit.metrics
        row = self.row("learned", label, closed_loop=False, solver="exact", fit_seconds=id_s + fit.seconds,
                       identify_seconds=id_s, train_seconds=fit.seconds, training_run_id=fit.run_id,
                       reused_training_of=reused, train_iterations=int(fit.history.iterations),
                       train_val_rms_um=m.get("val_rms_um"), train_val_max_um=m.get("val_max_um"),
                       train_baseline_ols_val_rms_um=m.get("baseline_ols_val_rms_um"),
                       n_featurepoints=len(fp.axes), **scored(ex), solvers={"exact": ex, "batched-ga": ga}, **common)
        self.log.add(with_volume(row, self._volume(truth, fit.field)))

    def loop_rows(self, c, truth, el_path, id_s, d, common) -> None:
        """``volcomp diagnose`` on the condition's checks with the identified set and its covariance (the
        element update, the effects; on an out-of-catalogue condition also the learned residual, backfitted
        with the update, gated on the held-out checks) → compensate, judged by the truth. The parametric row is
        the loop alone (``model.json`` without a learned part), the hybrid row (out-of-catalogue) the kept model."""
        from .measurement import diagnose_chain
        s, n = self.s, c.n_checks or self.s.n_checks
        learn = c.group == "out-of-catalogue"
        label = f"{c.name} (after closed loop)"
        paths = ("parametric", "hybrid") if learn else ("parametric",)
        done = []
        try:
            t0 = time.perf_counter()
            summary, _ = diagnose_chain(d / "sim" / "checks.csv", self.m, el_path, d / "diagnosis",
                                        noise_um=s.check_noise_um, learn=learn)
            loop_s = time.perf_counter() - t0
            models = loop_models(self.m, summary["model_file"], self.path.cond)
            vmodels = loop_models(self.m, summary["model_file"], self.volume.cond) if self.volume else None
            fields = _loop_fields(summary, s, n, common["n_measurements"])
            for path in paths:
                terms, stage, field_ = models[path]
                say(f"{self.m.name}: {path}, {label}")
                sol = {"exact": self._solve(truth, field_)}
                if path == "hybrid" and fields["learned_kept"]:
                    sol["batched-ga"] = self._solve(truth, field_, "batched-ga", idx=self.ga_idx)
                extra = ({"checks_rms_after_um": fields.pop("held_out_rms_base_um")} if path == "parametric"
                         else {"checks_rms_after_um": summary["held_out_rms_um"]})
                row = self.row(path, label, closed_loop=True, loop_method=USER_LOOP, solver="exact",
                               fit_seconds=id_s + loop_s, identify_seconds=id_s, diagnosis_seconds=loop_s,
                               **scored(sol["exact"]), solvers=sol, stage=stage,
                               effects_found=[f"{e['kind']}:{e['axis']}" for e in terms],
                               **{**common, **{k: v for k, v in fields.items()
                                               if path == "hybrid" or not k.startswith("learned")}, **extra})
                vol = vmodels and compensate_true(self.m, s, self.volume, truth, vmodels[path][2])
                self.log.add(with_volume(row, vol))
                done.append(path)
        except Exception as exc:  # never fake numbers: the rows say why they are missing
            why = f"closed loop failed: {type(exc).__name__}: {exc}"
            for path in paths:
                if path not in done:
                    self.log.add(self.row(path, label, available=False, closed_loop=True, loop_method=USER_LOOP,
                                          not_available=why, **common))


def _loop_fields(summary: dict, s: BenchmarkSettings, n: int, n_sweep: int) -> dict:
    """The loop rows' figures from ``diagnosis.json``: the held-out MEASURED residual before and after beside the
    plain baselines and the noise floor, the learned stage's verdict."""
    st = summary["stages"]
    floor = float(np.sqrt(3.0) * s.check_noise_um)
    lr = summary.get("learned_residual") or {}
    base = summary.get("held_out_rms_base_um", summary["held_out_rms_um"])
    return {"n_checks": n, "kept_stage": summary["kept_stage"], "check_noise_um": s.check_noise_um,
            "checks_rms_before_um": st["identified"]["held_out"]["rms_um"], "held_out_rms_base_um": base,
            "held_out_ols_linear_um": st["baseline_ols_linear"]["held_out"]["rms_um"],
            "held_out_ols_update_um": st["baseline_ols_update"].get("held_out", {}).get("rms_um"),
            "noise_floor_um": floor, "held_out_over_floor": base / floor,
            "n_measurements": n_sweep + n, "model_verdict": summary.get("verdict"),
            "learned_kept": summary["kept_stage"] == "learned_residual", "learned_family": lr.get("family"),
            "learned_why": lr.get("why"), "learned_gain_z": lr.get("held_out_gain_z"),
            "learned_band95_cover": lr.get("held_out_band95_cover"), "learned_backfitted": "backfit" in lr}


def _subset(n: int, m: int) -> np.ndarray:
    return np.unique(np.round(np.linspace(0, n - 1, min(n, m))).astype(int))


def run_chain(machine, s, log, out_dir) -> list:
    """The rows of ``machine`` (a machine-tool chain) under the settings ``s`` into ``log`` (the benchmark's
    :class:`RowLog`), in condition order. Returns the skipped conditions (``[{"machine", "why"}]``)."""
    try:
        path = judging_path(machine, s)
    except ValueError as exc:  # no test part the machine can make
        return [{"machine": machine.name, "why": f"compensation not available: {exc}"}]
    conds, why = bench_conditions(machine, s)
    bench = ChainBench(machine, s, log, out_dir, path)
    for c in conds:
        try:
            bench.run_condition(c)
        except Exception as exc:  # the other conditions still run; the failure is a row, never faked numbers
            say(f"{machine.name}: {c.name} failed: {type(exc).__name__}: {exc}")
            done = {r["path"] for r in log.rows if r["machine"] == machine.name and r["condition"].startswith(c.name)}
            for p in ("parametric", "learned"):
                if p not in done:
                    log.add(bench.row(p, c.name, available=False, group=c.group,
                                      not_available=f"condition failed: {type(exc).__name__}: {exc}"))
    return [{"machine": machine.name, "why": w} for w in why]
