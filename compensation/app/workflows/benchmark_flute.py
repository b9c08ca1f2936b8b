"""The learned vs parametric rows on the flute (the built-in machine's part): sweeps → identification →
the element field with ``exact`` against the network on its feature points with ``batched-ga``/``exact``, each
condition before and after the closed loop, judged by the TRUE residual along the flute
(:mod:`compensation.app.workflows.benchmark`)."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.stats import residual_stats

from ..families import family_kind
from .benchmark_common import (EFFECTS_LOOP, EXPERIMENT, FEATURE_REUSE_TOL_UM, LEARNED_GRID, PATH_CONDITIONS,
                               TRUTH_CONDITIONS, USER_LOOP, BenchmarkSettings, RowLog, Tracker, bench_row, rng_streams,
                               say, scored, with_volume)


def at_conditions(field_, mt, conditions: dict):
    """``field_`` with ``conditions`` (``{name: value}``) for the conditions its terms need."""
    from .compensate import field_conditions
    return field_conditions(field_, {c: conditions[c] for c in getattr(field_, "needs", ())}, mt)


def loop_models(machine, model_path, conditions: dict) -> dict:
    """``{"parametric": (terms, stage, field), "hybrid": ...}`` of a diagnose run's ``model.json``: the loop
    alone (without the learned part; its ``loop_alone`` elements and terms when the base was backfitted) and
    the kept model, each at ``conditions`` (the benchmark's flute conditions)."""
    import json
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
                           at_conditions(base, machine, conditions)),
            "hybrid": (doc["terms"], doc["kept_stage"], at_conditions(kept, machine, conditions))}


@dataclass
class GrinderCondition:
    name: str
    group: str
    stations: int
    noise_um: float
    effect: str | None = None
    n_checks: int | None = None   # check measurements of the closed loop (None: the settings' n_checks)
    loop: bool = False            # run the closed loop (and its hybrid stage) even without an effect


def grinder_conditions(s: BenchmarkSettings) -> list[GrinderCondition]:
    """Density sweep (at the base noise), noise sweep (at the base density), each effect (base)."""
    out = {}
    for st in s.stations:
        name = f"stations={st}, noise={s.base_noise_um:g}um"
        out.setdefault(name, GrinderCondition(name, "density", st, s.base_noise_um))
    for nz in s.noises_um:
        name = f"stations={s.base_stations}, noise={nz:g}um"
        out.setdefault(name, GrinderCondition(name, "noise", s.base_stations, nz))
    for eff in s.effects:
        name = f"effect={eff}"
        out[name] = GrinderCondition(name, "effect", s.base_stations, s.base_noise_um, eff)
    if s.ooc_effects:  # out of any catalogue, and the same machine without an effect, at each check count
        for eff in (*s.ooc_effects, "none"):
            for nc in dict.fromkeys(s.ooc_checks):
                name = f"effect={eff}" + (f", checks={nc}" if nc != s.n_checks else "")
                out[name] = GrinderCondition(name, "out-of-catalogue", s.base_stations, s.base_noise_um,
                                             None if eff == "none" else eff, nc, True)
    return list(out.values())


def _subset(n: int, m: int) -> np.ndarray:
    return np.unique(np.round(np.linspace(0, n - 1, min(n, m))).astype(int))


@dataclass
class GrinderTestPoints:
    """Where the grinder rows are evaluated, the same for every condition (truth-independent).

    targets_mm, nominal_axes : (n, 3)   the flute path's WCS targets and nominal axes
    ga_idx : (m,)                       the evenly spaced flute points the batched GA solves
    path_cond : {name: (n,)}            :data:`PATH_CONDITIONS` the truth needs, per point
    volume_axes, volume_targets_mm : (k, 3), volume_cond : {name: (k,)}   random volume points
    """

    targets_mm: np.ndarray
    nominal_axes: np.ndarray
    ga_idx: np.ndarray
    path_cond: dict
    volume_axes: np.ndarray
    volume_targets_mm: np.ndarray
    volume_cond: dict

    def select(self, idx=None, volume: bool = False):
        """(targets, nominal axes, conditions) of the path (or the volume points), at ``idx``."""
        tg, nom, cond = (self.volume_targets_mm, self.volume_axes, self.volume_cond) if volume else \
            (self.targets_mm, self.nominal_axes, self.path_cond)
        if idx is not None:
            tg, nom, cond = tg[idx], nom[idx], {k: v[idx] for k, v in cond.items()}
        return tg, nom, cond


def grinder_test_points(machine, s: BenchmarkSettings) -> GrinderTestPoints:
    """The flute (``s.flute_turns`` × ``s.flute_points_per_turn``) and ``s.volume_points`` volume
    points: uniform over the strokes, rho >= 5 mm (away from the A axis, where the WCS is
    singular), nominal axes -> targets."""
    from errormap.chain_kernel import forward
    from errormap.chain_truth import random_axes

    from ...toolpath import flute_path
    flute = flute_path(turns=s.flute_turns, points_per_turn=s.flute_points_per_turn)
    targets, nominal = flute.targets_mm, flute.axes(machine)
    rng = np.random.default_rng(rng_streams(s.seed)["volume_points"])
    ax = random_axes(machine, 4 * s.volume_points, rng)
    ax = ax[ax[:, 1] >= machine.strokes["z_mm"][0] + 5.0][: s.volume_points]

    def at(n):
        return {k: np.full(n, v) for k, v in PATH_CONDITIONS.items() if k in TRUTH_CONDITIONS}

    return GrinderTestPoints(targets, nominal, _subset(len(targets), s.ga_points), at(len(targets)),
                             ax, forward(machine, ax), at(len(ax)))


def grinder_truth(machine, s: BenchmarkSettings, effect=None):
    """The simulated truth grinder of ``s.truth_seed``, with the undeclared ``effect`` if given."""
    from errormap.chain_truth import make_chain_truth
    return make_chain_truth(machine, s.truth_seed, effects=(effect,) if effect else ())


def condition_sweeps(s: BenchmarkSettings, truth, c: GrinderCondition) -> dict:
    """Simulated tracker sweeps of ``truth`` under condition ``c`` (columns, as a sweep file holds them)."""
    from errormap.chain_sweeps import simulated_sweeps
    return simulated_sweeps(truth, noise_um=c.noise_um, seed=rng_streams(s.seed)["sweep_noise"], n_stations=c.stations)


def identify_from_sweeps(machine, s: BenchmarkSettings, truth, c: GrinderCondition):
    """Simulated tracker sweeps of ``truth`` under condition ``c`` → the 23 identified elements.
    Returns ``(elements, identification seconds, number of ball-centre measurements)``."""
    from errormap.identification import ChainIdentification
    from errormap.sweeps import sweeps_from_columns
    sw = condition_sweeps(s, truth, c)
    t0 = time.perf_counter()
    res = ChainIdentification(gauge="first-station").fit(sweeps_from_columns(sw), machine).result_
    return res.elements_, time.perf_counter() - t0, len(sw["axis"])


def identify_with_covariance(machine, s: BenchmarkSettings, truth, c: GrinderCondition):
    """The same sweeps identified as ``volcomp identify`` does with its defaults
    (:func:`compensation.app.workflows.identification.identify_chain_files` → :class:`errormap.estimators.Identification`:
    penalised smoothing, station-mean gauge, tracker noise estimated from the ball residuals, the covariance
    Gauss-Newton's or ``s.identify_bootstrap`` residual-bootstrap draws of seed 0). Returns
    ``(identification, seconds)``: its ``elements_`` and covariance, what ``volcomp diagnose`` finds beside
    the element-set file."""
    from errormap.estimators import Identification
    from errormap.sweeps import sweeps_from_columns
    sw = condition_sweeps(s, truth, c)
    t0 = time.perf_counter()
    res = Identification(machine, n_boot=s.identify_bootstrap, seed=0).fit(sweeps_from_columns(sw)).result_
    return res, time.perf_counter() - t0


def compensate_true(machine, s: BenchmarkSettings, points: GrinderTestPoints, truth, field_, method: str,
                    idx=None, volume: bool = False) -> dict:
    """Compensate with ``field_`` and ``method``; the TRUE residual on ``truth`` (RMS, max), the
    solver's time per point, its worst model residual and its failures."""
    from ...evaluate import true_residual_um
    from ...solvers import solve
    tg, nom, cond = points.select(idx, volume)
    opts = {"target_axes": nom, "progress": False}
    if method == "batched-ga":
        opts.update(seed=s.seed, generations=s.ga_generations)
    r = solve(method, field_, tg, machine, **opts)
    st = residual_stats(true_residual_um(truth, r.axes, tg, cond))
    return {"true_rms_um": st["rms_um"], "true_max_um": st["max_um"], "seconds_per_point": r.seconds / len(tg), "points": len(tg),
            "model_max_um": float(np.max(r.residual_norm_um)), "failures": int(np.count_nonzero(~r.success))}


def uncompensated_true(points: GrinderTestPoints, truth) -> tuple[float, float]:
    """(RMS, max) TRUE residual of the nominal flute commands."""
    from ...evaluate import true_residual_um
    st = residual_stats(true_residual_um(truth, points.nominal_axes, points.targets_mm, points.path_cond))
    return st["rms_um"], st["max_um"]


class NetworkTrainer:
    """Trains the learned field on identified elements, once per distinct feature-point set and
    network setting (a condition whose identified elements equal an earlier one's reuses it)."""

    def __init__(self, machine, tracker: Tracker, warm_up_axes):
        self.m, self.tracker, self.warm_up_axes = machine, tracker, warm_up_axes
        self.kind = family_kind(machine)
        self.cache = []  # (network settings, feature-point errors, fit result, seconds, condition)

    def train(self, elements, cond_name: str, s: BenchmarkSettings):
        """``(fit result, seconds, name of the condition reused or None)``."""
        from errormap.featurepoints import make_feature_points
        from errormap.chain_field import ChainField
        from training import TrackSettings, TrainSettings, fit_field, validation_points
        fp = make_feature_points(self.m, ChainField(self.m, elements), n=LEARNED_GRID, meta={"benchmark_condition": cond_name})
        key = (tuple(s.hidden), s.activation, s.a_encoding, s.train_iter, s.train_s)
        for k, errs, res, secs, name in self.cache:
            if k == key and np.max(np.abs(errs - fp.errors_um)) < FEATURE_REUSE_TOL_UM:
                return res, secs, name
        streams = rng_streams(s.seed)
        val = validation_points(self.m, elements, n=2000, seed=streams["validation"])
        # model selection on other off-grid points of the same identified model (not the validation set)
        sel = validation_points(self.m, elements, n=2000, seed=streams["selection"])
        say(f"{self.kind}: training the network ({cond_name}, LM, {s.train_iter} iterations"
             + (f", ≤ {s.train_s:g} s)" if s.train_s is not None else ")"))
        t0 = time.perf_counter()
        tr = self.tracker
        settings = TrainSettings(trainer="lm", max_iter=s.train_iter, seed=s.seed,
                                 max_time_s=math.inf if s.train_s is None else s.train_s,
                                 hidden=s.hidden, activation=s.activation, a_encoding=s.a_encoding)
        tracking = TrackSettings(track=tr.enabled, tracking_uri=tr.uri if tr.enabled else None,
                                 parent_run_id=tr.parent_id, experiment=EXPERIMENT,
                                 run_name=f"{self.kind}/learned/train/{cond_name}",
                                 tags={"benchmark_condition": cond_name})
        res = fit_field(fp, settings, validation=val, selection=sel, tracking=tracking, quiet=True)
        secs = time.perf_counter() - t0
        res.field.jacobian(self.warm_up_axes)  # torch.func warm-up, so that compensation timings exclude it
        self.cache.append((key, fp.errors_um.copy(), res, secs, cond_name))
        return res, secs, None


class GrinderBench:
    """The grinder rows: for each condition, parametric and learned, then the closed loop when
    the condition adds an undeclared effect. Measurement, identification, training and the TRUE
    residual are the functions and classes above; this class only puts the rows together."""

    def __init__(self, machine, s: BenchmarkSettings, log: RowLog):
        self.m, self.s, self.log, self.kind = machine, s, log, family_kind(machine)
        self.points = grinder_test_points(machine, s)
        self.trainer = NetworkTrainer(machine, log.tracker, self.points.nominal_axes[:2])

    @property
    def rows(self) -> list:
        return self.log.rows

    def row(self, path: str, label: str, **kw) -> dict:
        """A result row of this machine (:func:`bench_row`; its kind the registry's)."""
        return bench_row(self.m.name, self.kind, path, label, **kw)

    def _compensate(self, truth, field_, method, idx=None, volume=False) -> dict:
        return compensate_true(self.m, self.s, self.points, truth, field_, method, idx=idx, volume=volume)

    def _volume(self, truth, field_):
        return self._compensate(truth, field_, "exact", volume=True) if self.s.volume_points else None

    def run_condition(self, c: GrinderCondition) -> None:
        truth = grinder_truth(self.m, self.s, c.effect)
        unc_rms, unc_max = uncompensated_true(self.points, truth)
        elements, id_s, n_meas = identify_from_sweeps(self.m, self.s, truth, c)
        common = {"group": c.group, "stations": c.stations, "noise_um": c.noise_um, "effect": c.effect,
                  "test_path": f"flute ({len(self.points.targets_mm)} points)", "n_measurements": n_meas,
                  "uncompensated_rms_um": unc_rms, "uncompensated_max_um": unc_max}
        loop = bool(c.effect or c.loop)
        label = c.name + (" (before closed loop)" if loop else "")
        par_field, par = self.parametric_row(truth, elements, id_s, label, common)
        # the network is trained once per identified element set (a condition with other checks reuses it)
        learned = self.learned_row(truth, elements, id_s, c.name, label, common)
        if loop and learned is not None:
            mlp, lrn = learned
            self.closed_loop(c, truth, ((par, par_field), (lrn, mlp)), common)

    def parametric_row(self, truth, elements, id_s, label, common):
        """The exact inverse of the identified HTM field; returns (field, row)."""
        from errormap.chain_field import ChainField
        field_ = ChainField(self.m, elements)
        say(f"{self.kind}: parametric, {label}")
        ex = self._compensate(truth, field_, "exact")
        row = self.row("parametric", label, closed_loop=False, solver="exact",
                   fit_seconds=id_s, identify_seconds=id_s, **scored(ex), solvers={"exact": ex}, **common)
        self.log.add(with_volume(row, self._volume(truth, field_)))
        return field_, row

    def learned_row(self, truth, elements, id_s, cond_name, label, common):
        """Feature points → network → batched GA (subset) + exact (whole path); returns (network,
        row), or None when training failed (the row then says why)."""
        try:
            fit, _, reused = self.trainer.train(elements, cond_name, self.s)
        except Exception as exc:  # training unavailable or failed: say so, never fake numbers
            self.log.add(self.row("learned", label, available=False,
                                  not_available=f"training failed: {type(exc).__name__}: {exc}", **common))
            return None
        mlp = fit.field
        say(f"{self.kind}: learned, {label}")
        ex = self._compensate(truth, mlp, "exact")
        ga = self._compensate(truth, mlp, "batched-ga", idx=self.points.ga_idx)
        vol = self._volume(truth, mlp)
        row = self.row("learned", label, closed_loop=False, solver="exact",
                   fit_seconds=id_s + fit.seconds, identify_seconds=id_s, train_seconds=fit.seconds,
                   training_run_id=fit.run_id, reused_training_of=reused,
                   train_val_rms_um=fit.metrics.get("val_rms_um"), train_val_max_um=fit.metrics.get("val_max_um"),
                   train_iterations=fit.metrics.get("iterations"), **scored(ex),
                   solvers={"exact": ex, "batched-ga": ga}, **common)
        self.log.add(with_volume(row, vol))
        return mlp, row

    def closed_loop(self, c, truth, bases, common) -> None:
        """Checks → the closed loop → compensate → true residual, for each ``(base row, base field)`` of
        ``bases``: on an out-of-catalogue condition the parametric base runs the user's path
        (:meth:`user_loop_rows`: the parametric loop and the hybrid), every other base the effect
        search on its field (:meth:`closed_loop_row`)."""
        from errormap.diagnosis.chain_loop import ChainChecks
        s = self.s
        n_checks = c.n_checks or s.n_checks
        cols = truth.check_measurements(n=n_checks, noise_um=s.check_noise_um, seed=rng_streams(s.seed)["checks"])
        checks = ChainChecks.from_columns(self.m, cols, path=f"<simulated checks, {c.name}>")
        label = f"{c.name} (after closed loop)"
        for base_row, base in bases:
            if base_row["path"] == "parametric" and c.group == "out-of-catalogue":
                self.user_loop_rows(c, truth, label, checks, common)
                continue
            say(f"{self.kind}: {base_row['path']}, {label}")
            try:
                self.closed_loop_row(truth, label, checks, base_row, base, common)
            except Exception as exc:  # never fake numbers: the row says why it is missing
                why = f"closed loop failed: {type(exc).__name__}: {exc}"
                self.log.add(self.row(base_row["path"], label, available=False, closed_loop=True,
                                      loop_method=EFFECTS_LOOP, not_available=why, **common))

    def user_loop_rows(self, c, truth, label, checks, common) -> None:
        """The user's path on the checks: ``volcomp identify`` (:func:`identify_with_covariance`) → ``volcomp
        diagnose`` with that element set (:func:`compensation.app.workflows.measurement.diagnose_chain`: the
        element update, the effects, the learned residual backfitted with the update and gated on the held-out
        checks, the kept stage re-estimated on all checks) → compensate, judged by the truth. Two rows: the
        parametric loop is the loop alone (``model.json`` without its learned part, its ``loop_alone`` when the
        base was backfitted), the hybrid the kept model (``model.json``); both at :data:`PATH_CONDITIONS`."""
        import tempfile
        from .measurement import diagnose_chain
        s = self.s
        say(f"{self.kind}: identify + diagnose (the user's path), {label}")
        done = []
        try:
            cov, id_s = identify_with_covariance(self.m, s, truth, c)
            with tempfile.TemporaryDirectory(prefix="volcomp-benchmark-") as td:
                from errormap.chain_covariance import covariance_path, save_chain_covariance
                el_path = cov.elements_.save(Path(td) / "elements.json")
                save_chain_covariance(cov, covariance_path(el_path))
                t0 = time.perf_counter()
                summary, _ = diagnose_chain(checks, self.m, el_path, Path(td) / "diagnosis")
                loop_s = time.perf_counter() - t0
                models = loop_models(self.m, Path(td) / "diagnosis" / "model.json", PATH_CONDITIONS)
            lr = summary.get("learned_residual") or {}
            kept_learned = summary["kept_stage"] == "learned_residual"
            learned = {"learned_kept": kept_learned, "learned_family": lr.get("family"),
                       "learned_why": lr.get("why"), "learned_gain_z": lr.get("held_out_gain_z"),
                       "learned_band95_cover": lr.get("held_out_band95_cover"), "learned_backfitted": "backfit" in lr}
            rms_after = {"parametric": summary.get("held_out_rms_base_um", summary["held_out_rms_um"]),
                         "hybrid": summary["held_out_rms_um"]}
            for path, (terms, stage, field_) in models.items():
                say(f"{self.kind}: {path}, {label}")
                sol = {"exact": self._compensate(truth, field_, "exact")}
                if path == "hybrid" and kept_learned:
                    sol["batched-ga"] = self._compensate(truth, field_, "batched-ga", idx=self.points.ga_idx)
                row = self.row(path, label, closed_loop=True, loop_method=USER_LOOP,
                           solver="exact", fit_seconds=id_s + loop_s, identify_seconds=id_s, diagnosis_seconds=loop_s,
                           **scored(sol["exact"]), solvers=sol,
                           effects_found=[f"{e['kind']}:{e['axis']}:{e['element']}" for e in terms],
                           stage=stage, n_checks=len(checks),
                           checks_rms_before_um=summary["stages"]["identified"]["held_out"]["rms_um"],
                           checks_rms_after_um=rms_after[path],
                           check_noise_um=s.check_noise_um, model_verdict=summary.get("verdict"),
                           **(learned if path == "hybrid" else {}),
                           **{**common, "n_measurements": common["n_measurements"] + len(checks)})
                self.log.add(with_volume(row, self._volume(truth, field_)))
                done.append(path)
        except Exception as exc:  # never fake numbers: the rows say why they are missing
            why = f"closed loop failed: {type(exc).__name__}: {exc}"
            for path in ("parametric", "hybrid"):
                if path not in done:
                    self.log.add(self.row(path, label, available=False, closed_loop=True,
                                          loop_method=USER_LOOP, not_available=why, **common))

    def closed_loop_row(self, truth, label, checks, base_row, base, common):
        """The effect search on the base's element set (the closed loop without the element update); a base without
        elements (the learned field) is a row that says so."""
        from errormap.diagnosis.chain_loop import closed_loop_chain
        from errormap.diagnosis.loop_model import ChainModelField
        s = self.s
        if getattr(base, "elements", None) is None:
            raise ValueError("the closed loop searches effects on an element set; a trained network is not one")
        mt = self.m
        el = base.elements
        t0 = time.perf_counter()
        d = closed_loop_chain(mt, el, checks, cov=None)
        diag_s = time.perf_counter() - t0
        terms = d["_models"]["terms"] if d["kept_stage"].endswith("plus_effects") else []
        found = [f"{t.kind}:{'*'.join(t.axes)}:{t.element}" for t in terms]
        corrected = at_conditions(ChainModelField(mt, el, terms), mt, PATH_CONDITIONS)
        sol = {"exact": self._compensate(truth, corrected, "exact")}
        vol = self._volume(truth, corrected)
        extra = {k: base_row.get(k) for k in ("identify_seconds", "train_seconds", "training_run_id",
                                               "reused_training_of") if base_row.get(k) is not None}
        row = self.row(base_row["path"], label, closed_loop=True, loop_method=EFFECTS_LOOP,
                   solver="exact", fit_seconds=base_row["fit_seconds"] + diag_s, diagnosis_seconds=diag_s,
                   **scored(sol["exact"]), solvers=sol, effects_found=found, n_checks=len(checks),
                   checks_rms_before_um=d["stages"]["identified"]["held_out"]["rms_um"],
                   checks_rms_after_um=d["held_out_rms_um"],
                   **{**common, "n_measurements": common["n_measurements"] + len(checks)}, **extra)
        self.log.add(with_volume(row, vol))
        return d, row


def run_grinder(machine, s: BenchmarkSettings, log: RowLog, out_dir=None) -> list:
    """Both paths on every grinder condition, rows in condition order into ``log``; nothing is skipped."""
    g = GrinderBench(machine, s, log)
    for c in grinder_conditions(s):
        try:
            g.run_condition(c)
        except Exception as exc:  # the other conditions still run; the failure is a row
            say(f"{g.kind}: {c.name} failed: {type(exc).__name__}: {exc}")
            done = {r["path"] for r in g.rows if r["condition"].startswith(c.name)}
            for path in ("parametric", "learned"):
                if path not in done:
                    log.add(g.row(path, c.name, available=False, group=c.group,
                                  not_available=f"condition failed: {type(exc).__name__}: {exc}"))
    return []
