"""The measurement side of every machine tool (a chain file, the built-in grinder, a ``kind = "grinder"`` file read
as its chain): ``simulate``, ``sweeps`` and ``diagnose``, and the truth overlay of ``identify`` (:func:`truth_in_gauge`;
the identification itself: :mod:`.identification`). ``errormap/chain_truth.py``, ``chain_sweeps.py`` and
``diagnosis/chain_loop.py`` underneath."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from errormap.io import InputError, companion_path, read_document_text, sha256_file, write_csv, write_json
from errormap.machine import made_on
from errormap.seeds import spawn_seeds
from compensation.app.validate import UsageError


TRUTH_FORMAT = "volcomp-chain-truth/1"
"""``truth.json`` of ``simulate --machine``: the hidden truth (element file beside it + effect parameters), for
testers and benchmarks (``compensate --truth``), never for an estimator."""


def load_chain_truth(path, machine):
    """The truth's error field at the reference conditions (20 °C, positive approach on every axis) from
    ``truth.json`` of ``simulate --machine`` (elements + effects) or a truth element set; InputError naming
    the file and key otherwise."""
    from errormap.chain_elements import ELEMENTS_FORMAT, ChainElementSet
    from errormap.chain_field import ChainField
    p = Path(path)
    try:
        d = json.loads(read_document_text(p, "a model or element set"))
    except (OSError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{p}: not a truth file ({exc})") from None
    fmt = d.get("format") if isinstance(d, dict) else None
    if fmt == ELEMENTS_FORMAT:
        return ChainField(machine, ChainElementSet.load(p, machine))
    if fmt != TRUTH_FORMAT:
        raise InputError(f"{p}: key 'format': expected {TRUTH_FORMAT!r} (truth.json of simulate --machine) or "
                         f"{ELEMENTS_FORMAT!r}, got {fmt!r}")
    if not made_on(machine, d.get("machine_sha256")):
        raise InputError(f"{p}: key 'machine_sha256': the truth belongs to machine {d.get('machine')!r}, "
                         f"not {machine.name!r}")
    from errormap.chain_truth import ChainTruth
    truth = ChainTruth(machine, ChainElementSet.load(p.parent / str(d.get("elements")), machine), d.get("effects") or {})
    return _TruthAtReference(truth)


class _TruthAtReference:
    """A truth machine (with its effects) at the reference conditions, ``predict(axes) -> (n, 3)`` μm."""

    def __init__(self, truth):
        self.truth = truth

    def predict(self, axes):
        axes = np.atleast_2d(np.asarray(axes, float))
        return self.truth.spatial_error(axes, **self.truth.default_conditions(len(axes)))


def parse_effects(machine, effects) -> list:
    """``KIND[:AXES]`` strings checked against the machine (one-line UsageError naming the known kinds)."""
    from errormap.chain_truth import effect_key, parse_effect
    out = []
    for e in effects:
        try:
            out.append(effect_key(*parse_effect(machine, e)))
        except ValueError as exc:
            raise UsageError(f"--effect: {exc}") from None
    return out


def make_truth(machine, seed: int, effects=(), family: str = "default"):
    from errormap.chain_truth import make_chain_truth
    return make_chain_truth(machine, seed, effects=parse_effects(machine, effects), family=family)


def simulate_chain(machine, seed: int, out, effects=(), noise_um: float = 1.0, checks: int = 400,
                   family: str = "default", check_noise_seed=None) -> dict:
    """Write ``out/truth_elements.json`` (hidden truth), ``featurepoints.csv`` (the truth's error on the default
    grid over the axes, :func:`errormap.featurepoints.make_feature_points`), ``checks.csv`` and ``truth.json``;
    returns the ``truth.json`` document (``files``: the paths written, ``max_spatial_error_um`` over the volume).
    The truth takes the seed itself, the check measurements a child stream of it; ``check_noise_seed``: None
    (default) the checks' noise from that stream, an int redraws only the checks' noise (same machine, points
    and conditions)."""
    from errormap.chain_field import ChainField
    from errormap.chain_truth import volume_grid
    from errormap.featurepoints import make_feature_points
    from .simulate import check_noise_comments, check_noise_record
    out = Path(out)
    truth = make_truth(machine, seed, effects, family)
    el_path = truth.elements.save(out / "truth_elements.json")
    fp = make_feature_points(machine, ChainField(machine, truth.elements),
                             meta={"elements_file": str(el_path), "source": f"simulate seed={seed}"})
    fp.meta["elements_sha256"] = sha256_file(el_path)
    fp_path = fp.save(out / "featurepoints.csv")
    measured = truth.check_measurements(n=checks, noise_um=noise_um, seed=spawn_seeds(seed, 1)[0],
                                        noise_seed=check_noise_seed)
    ck_path = write_csv(out / "checks.csv", measured, header_comments=[
        "format: volcomp-checks/1", f"machine: {machine.name}", f"machine_sha256: {machine.sha256}",
        f"noise_um: {noise_um}", f"effects: {','.join(truth.effects) or 'none'}"]
        + check_noise_comments(check_noise_seed))
    grid = volume_grid(machine)
    e = np.linalg.norm(truth.spatial_error(grid, **truth.default_conditions(len(grid))), axis=1)
    info = {"format": TRUTH_FORMAT, "seed": seed, "machine": machine.name, "machine_file": machine.path,
            "machine_sha256": machine.sha256, "family": family,
            "effects": truth.effects, "noise_um": noise_um, **check_noise_record(check_noise_seed),
            "max_spatial_error_um": float(e.max()),
            "elements": el_path.name,
            "files": {"elements": str(el_path), "featurepoints": str(fp_path), "checks": str(ck_path)}}
    write_json(out / "truth.json", info)
    return info


def sweeps_chain(machine, out, seed=None, truth_file=None, effects=(), family="default", noise_um=2.0, seed_noise=0,
                 bidirectional=False, warmup_c=0.0, setup="setup-1") -> tuple:
    """Simulate and write a sweep file of a truth (seeded, or an element-set file); ``(path, rows)``."""
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_truth import ChainTruth
    from errormap.chain_sweeps import simulated_sweeps, write_sweeps
    if truth_file is not None:
        if effects:
            raise UsageError("--effect needs --seed (a truth element file carries no effects)")
        truth = ChainTruth(machine, ChainElementSet.load(truth_file, machine), {})
        what = f"truth {truth_file}"
    else:
        truth = make_truth(machine, seed, effects, family)
        what = f"truth seed {seed} ({family} family)"
    cols = simulated_sweeps(truth, noise_um=noise_um, seed=seed_noise, bidirectional=bidirectional, warmup_c=warmup_c)
    path = write_sweeps(out, cols, comments=[
        f"setup: {setup}", f"machine: {machine.name}", f"machine_sha256: {machine.sha256}", f"truth: {what}",
        f"effects: {','.join(truth.effects) or 'none'}", f"noise_um: {noise_um}", f"seed_noise: {seed_noise}",
        "tracker pose: seeded, unknown to the identification",
        "each axis swept with the others parked at the lower ends of their strokes"])
    return path, len(cols["axis"]), what


def truth_in_gauge(machine, truth, gauge: str = "station-mean", stations: dict | None = None):
    """A truth element set (``truth_elements.json`` of ``simulate``, a
    :class:`errormap.chain_elements.ChainElementSet` of ``machine``) as the identification expresses its estimate:
    in ``gauge`` with its squareness split, at ``stations`` (per axis column, the identified set's; None: the
    sweep default), so that a plot overlays like with like. The two frames differ by a rigid frame change, so
    the truth's noise-free sweeps are identified in ``gauge`` (tool points to 1e-6 μm,
    ``tests/test_chain_loop.py``)."""
    from errormap.identification import ChainIdentification
    from errormap.chain_truth import ChainTruth
    from errormap.chain_sweeps import simulated_sweeps, swept_words
    from errormap.sweeps import sweeps_from_columns
    cols = simulated_sweeps(ChainTruth(machine, truth, {}), noise_um=0.0, seed=0, stations=stations)
    sw = sweeps_from_columns(cols, "<noise-free sweeps of the truth>", axes=swept_words(machine))
    return ChainIdentification(gauge=gauge).fit(sw, machine).elements_


def load_chain_model(path, machine, prior: bool = False):
    """An element set of ``machine`` (a chain, or a ``kind = "grinder"`` file's chain; format key
    ``volcomp-elements/1``) and its covariance beside it (``NAME.cov.npz``) when present:
    ``(elements, (slot names, stations, Σ) or None, covariance path or None)``. ``prior``: Σ as the prior of
    an element update, with the smoother's ``prior_extra`` on its diagonal (:func:`read_chain_covariance`)."""
    from errormap.chain_elements import ChainElementSet
    p = Path(path)
    el = ChainElementSet.load(p, machine)   # read once: its format, then the set (errors name file and key)
    cp = companion_path(p, ".cov.npz")
    if not cp.is_file():
        return el, None, None
    from errormap.chain_covariance import read_chain_covariance
    return el, read_chain_covariance(cp, el, prior), cp


def check_chain_covariance(machine, elements, cov, cov_path="<covariance>") -> None:
    """Refuse (InputError naming ``cov_path`` and its key) a covariance ``(slot names, stations, Σ)`` that is not
    one of ``elements``' parameters: shape, a slot the machine lacks, a station beyond the set's, a negative or
    non-finite variance."""
    slots, stations, C = cov
    known = set(machine.slot_names)
    col = {a.word: a.column for a in machine.axes}
    slot_axis = {s.name: s.axis for s in machine.slots}
    if C.shape != (len(slots), len(slots)) or len(stations) != len(slots):
        raise InputError(f"{cov_path}: key 'cov': shape {C.shape} does not match its {len(slots)} parameters")
    for j, (s, i) in enumerate(zip(slots, stations)):
        if s not in known:
            raise InputError(f"{cov_path}: key 'slot', entry {j}: {s!r} is not a slot of machine {machine.name!r}")
        if i >= 0 and i >= len(elements.stations.get(col[slot_axis[s]], ())):
            raise InputError(f"{cov_path}: key 'station', entry {j}: station {i} of {s} beyond the element set's "
                             "stations (the covariance of another identification?)")
    if not np.all(np.isfinite(C)) or np.any(np.diagonal(C) < 0):
        raise InputError(f"{cov_path}: key 'cov': not a covariance (non-finite or negative variance)")


def chain_learned_stage(machine, checks, elements, terms, summary, seed: int = 0, families=None, refit=None,
                        refit_all: bool = False):
    """The learned-residual stage after the chain loop (:func:`compensation.hybrid.learned_stage`, whose
    docstring states the gate, the per-term rule for condition terms and the backfitting): fitted on what the
    loop's kept model (``elements`` + ``terms``, at the checks' own conditions) leaves at the fitting checks.
    ``refit``: None, or the loop's re-estimation of its kept stage (``closed_loop_chain``'s ``_models["refit"]``:
    ``(terms, offset_um, idx) -> (elements, terms, residual)``), with which the learned part is backfitted;
    ``refit_all``: the chosen base and learned part re-estimated on ALL checks before they are shipped.
    → ``(learned or None, stage, static terms, elements)``: the terms and elements the hybrid keeps (the
    backfitted base of the last round where backfitted)."""
    from compensation.hybrid import learned_stage
    from errormap.diagnosis.loop_model import ChainModelField, term_needs
    n, n_fit = len(checks), int(summary["n_fit"])

    def prediction(el, ts):
        f = ChainModelField(machine, el, ts)
        f = f.with_conditions({c: checks.conditions[c] for c in f.needs})
        return f.predict(checks.axes)

    r_prev = checks.measured_um - prediction(elements, terms)
    static = [t for t in terms if not term_needs(machine, t)]
    cond = [t for t in terms if term_needs(machine, t)]
    r_static, c_terms = None, None
    if cond:   # each condition term's own contribution (the terms' columns add up: ChainModelField)
        p_static = prediction(elements, static)
        r_static = checks.measured_um - p_static
        c_terms = np.stack([prediction(elements, static + [t]) - p_static for t in cond])
    last = {}

    def without(replaced) -> list:
        """``terms`` without the condition terms ``replaced`` (indices into them, or True / False: all / none)."""
        replaced = (tuple(range(len(cond))) if replaced is True else () if replaced is False else tuple(replaced))
        gone = {id(cond[k]) for k in replaced}
        return [t for t in terms if id(t) not in gone]

    def base_update(replaced, offset_um, idx):
        """The loop's kept stage without the condition terms ``replaced`` re-estimated on the checks ``idx`` with
        ``offset_um`` taken off → its residual at every check, at the checks' own conditions."""
        el, ts, _ = refit(without(replaced), offset_um, idx)
        last["all" if len(idx) == n else "fit"] = (el, ts)
        return checks.measured_um - prediction(el, ts)

    def refit_residual(replaced):
        """The base re-estimated on all checks (without ``replaced``) → its residual at every check."""
        el, ts, _ = refit(without(replaced), np.zeros((n, 3)), np.arange(n))
        return checks.measured_um - prediction(el, ts)

    learned, stage = learned_stage(machine, r_prev, checks.axes, np.arange(n_fit), np.arange(n_fit, n), seed=seed,
                                   families=families, r_static_um=r_static, condition_terms_um=c_terms,
                                   base_update=None if refit is None else base_update,
                                   refit_residual=refit_residual if (refit is not None and refit_all) else None)
    base = last.get("all" if refit_all else "fit")
    if learned is not None and base is not None and "backfit" in stage["learned"]:   # the last round's base
        el, ts = base
        return learned, stage, ts, el
    if learned is None or not stage["learned"]["replaces_condition_terms"]:
        return learned, stage, list(terms), elements
    return learned, stage, without(stage["learned"]["replaced_condition_terms"]), elements


def closed_loop(checks_path, machine, elements, checks, **kw) -> tuple:
    """:func:`errormap.diagnosis.chain_loop.closed_loop_chain` on the read ``checks`` (its ValueError: an
    InputError naming ``checks_path``) → ``(summary, its models, the kept stage's effect terms)``."""
    from errormap.diagnosis.chain_loop import closed_loop_chain
    try:
        summary = closed_loop_chain(machine, elements, checks, **kw)
    except InputError:   # names the file itself
        raise
    except ValueError as exc:
        raise InputError(f"{checks_path}: {exc}") from None
    models = summary.pop("_models")
    return summary, models, models["terms"] if summary["kept_stage"].endswith("plus_effects") else []


def diagnose_chain(checks_path, machine, model, out, fit_fraction=0.6, noise_um=None, effects=True,
                   max_effects=4, update=True, units="check", learn: bool = True, refit_all: bool = True,
                   track: bool = False, tracking_uri=None) -> tuple:
    """Held-out measured residual of an element set on checks (stages, noise floor, effects), then (``learn``)
    the learned-residual stage on what the kept stage leaves (:func:`chain_learned_stage`); ``refit_all``: once
    chosen on the fitting/held-out split, the kept stage (elements, effect terms, learned part) is re-estimated
    on ALL checks and shipped (the held-out figures stay the validated ones). Writes ``out/diagnosis.json``,
    ``out/updated_elements.json`` and ``out/model.json`` (with ``learned_residual`` when that stage is kept:
    :mod:`compensation.chain_hybrid`). ``machine``: a machine-tool chain or a grinder file (its chain).
    ``track``: a kept learned residual is also logged as an MLflow run (``tracking_uri``; its id recorded in
    diagnosis.json and model.json)."""
    from errormap.diagnosis.chain_loop import ChainChecks, load_chain_checks, ship_on_all_checks
    el, cov, cov_path = load_chain_model(model, machine, prior=True)
    checks = (checks_path if isinstance(checks_path, ChainChecks)   # checks in memory (the benchmark's)
              else load_chain_checks(checks_path, machine, units=units))
    checks_path = checks.path if isinstance(checks_path, ChainChecks) else checks_path
    summary, models, terms = closed_loop(checks_path, machine, el, checks, cov=cov if update else None,
                                         fit_fraction=fit_fraction, noise_um=noise_um, effects=effects,
                                         max_effects=max_effects, units=units)
    from compensation.fields import resolve_model
    summary.update({"checks": str(checks_path), "model": str(model), "model_source": resolve_model(model).to_dict(),
                    "covariance": str(cov_path) if cov_path else None, "update": bool(update and cov is not None)})
    refit, n = models.get("refit"), len(checks)
    refit_all = bool(refit_all and refit is not None)
    extra, learned = None, None
    loop_alone = None   # with backfitting: the loop's own elements and terms (what it ships without the learned part)
    if learn:
        loop_terms = list(terms)
        learned, stage, terms, backfit_el = chain_learned_stage(machine, checks, models["elements"], terms, summary,
                                                                refit=refit, refit_all=refit_all)
        if learned is not None and "backfit" in stage["learned"]:   # the backfitted base is the hybrid's
            kept_labels = {(t.kind, tuple(t.axes), t.element) for t in terms}
            alone_terms = [t for t in loop_terms if (t.kind, tuple(t.axes), t.element) in kept_labels]
            loop_alone = (refit(alone_terms, np.zeros((n, 3)), np.arange(n))[:2] if refit_all
                          else (models["elements"], alone_terms))
            models["elements"] = backfit_el
            stage["learned"]["backfit"]["shipped_base"] = (
                "the elements and terms shipped are the base of the last backfitting round on "
                f"{'all' if refit_all else 'the fitting'} checks (estimated with the learned part's prediction taken "
                "off their residual); diagnosis.json's effect coefficients are the loop's, model.json's the "
                "backfitted ones")
        stage["base_stage"] = summary["kept_stage"]
        if "held_out" in stage:  # the stage ran (enough checks): a stage beside the others
            summary["stages"] = dict(summary["stages"], learned_residual=stage)
        summary["learned_residual"] = stage["learned"]
        if learned is not None:
            extra = _learned_kept(summary, stage, learned, terms, loop_alone)
    if refit_all:   # the kept stage on all checks (backfitted with a learned part: already there)
        models["elements"], terms = ship_on_all_checks(summary, models, terms, learned is not None,
                                                       reestimate=learned is None or loop_alone is None)
    from errormap.diagnosis.plausibility import diagnosis_verdict
    summary["verdict"] = diagnosis_verdict(summary)   # failed: the command exits 1 (volcomp diagnose)
    extra = dict(extra or {}, verdict=summary["verdict"])
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    el_path = models["elements"].save(out / "updated_elements.json")   # each file written whole (temporary file, rename)
    paths_extra = [] if loop_alone is None else [loop_alone[0].save(out / "loop_elements.json")]
    from errormap.diagnosis.loop_model import save_chain_model
    if track and learned is not None:   # the kept learned residual as an MLflow run (training.tracking)
        from training.tracking import log_learned_residual
        rid = log_learned_residual(summary["stages"]["learned_residual"], extra["learned_residual"], model_doc=extra,
                                   tracking_uri=tracking_uri, tags={"checks": str(checks_path), "model": str(model)})
        summary["learned_residual"] = dict(summary["learned_residual"], mlflow_run_id=rid)
        extra["mlflow_run_id"] = rid
    model_path = save_chain_model(out / "model.json", machine, el_path, terms, summary["kept_stage"], extra,
                                  provenance={"written_by": "volcomp diagnose", "checks": str(checks_path),
                                              "model": str(model)})
    summary["model_file"] = str(model_path)
    write_json(out / "diagnosis.json", summary)
    return summary, [out / "diagnosis.json", out / "updated_elements.json", model_path] + paths_extra


def _learned_kept(summary, stage, learned, terms, loop_alone) -> dict:
    """``summary`` updated for a kept learned residual (the kept stage, the effects it replaced); → model.json's
    extra keys (the learned part, its family, the replaced terms, the loop alone)."""
    if stage["learned"]["replaces_condition_terms"]:
        kept_terms = {(t.kind, "*".join(t.axes), t.element) for t in terms}   # the terms the hybrid keeps
        summary["effects_replaced_by_learned"] = [e for e in summary["effects"]
                                                  if (e["kind"], e["axis"], e["element"]) not in kept_terms]
        summary["effects"] = [e for e in summary["effects"] if e not in summary["effects_replaced_by_learned"]]
    summary["base_stage"] = summary["kept_stage"]
    summary["held_out_rms_base_um"] = summary["held_out_rms_um"]
    summary["kept_stage"] = "learned_residual"
    summary["kept_why"] = f"{summary['kept_why']}; then the learned residual was {stage['learned']['why']}"
    summary["held_out_rms_um"] = stage["held_out"]["rms_um"]
    if summary.get("noise_floor_um"):
        summary["held_out_over_floor"] = float(summary["held_out_rms_um"] / summary["noise_floor_um"])
    lr = stage["learned"]
    extra = {"learned_residual": learned.to_dict(), "base_stage": summary["base_stage"],
             "learned_family": {"family": lr["family"], "name": lr.get("family_name", lr["family"]),
                                "compared": lr.get("families_compared"),
                                "estimated_on_checks": (lr.get("shipped") or {}).get("estimated_on_checks")}}
    if summary.get("effects_replaced_by_learned"):
        extra["base_terms_replaced"] = summary["effects_replaced_by_learned"]
    if loop_alone is not None:
        extra["loop_alone"] = {"elements": "loop_elements.json", "terms": [t.to_dict() for t in loop_alone[1]],
                               "note": ("the base stage's elements and terms as the loop alone estimates them "
                                        "(not backfitted with the learned part): a model.json with these in "
                                        "place of 'elements' and 'terms' and without 'learned_residual' is the "
                                        "loop alone")}
    return extra


def diagnosis_lines(summary) -> list:
    """The lines ``volcomp diagnose --machine`` prints: per stage its held-out MEASURED RMS, the effects
    named, the terms the element update absorbed (``effects_absorbed``: printed only when there are any
    and the update ran; without an update nothing absorbed them, and ``diagnosis.json`` still lists
    them), the kept stage, the noise floor and the verdict (:func:`errormap.diagnosis.plausibility.diagnosis_verdict`)."""
    st = summary["stages"]
    lines = []
    for k, v in st.items():
        if "held_out" in v:
            lines.append(f"{k}: held-out MEASURED RMS {v['held_out']['rms_um']:.3g} um (fitting {v['fitting']['rms_um']:.3g} um)")
        else:
            lines.append(f"{k}: {v.get('failed', 'not run')}")
    for e in summary["effects"]:
        lines.append(f"effect: {e['kind']} axis {e['axis']} on {e['element']} (held-out gain z = {e['held_out_gain_z']:.1f})")
    if not summary["effects"]:
        lines.append("no effect found")
    if "held_out" in st.get("updated", {}):  # absorbed only where an update ran (diagnosis.json keeps them always)
        for e in summary.get("effects_absorbed", []):
            lines.append(f"absorbed by the update: {e['note']}")
    lr = summary.get("learned_residual")
    if lr is not None:
        lines.append(f"learned residual ({lr.get('family_name', lr['family'])}): {lr['why']}")
    lines.append(f"kept stage: {summary['kept_stage']} ({summary['kept_why']})")
    if summary["noise_floor_um"] is not None:
        lines.append(f"noise floor {summary['noise_floor_um']:.3g} um (sigma {summary['noise_sigma_um']:.3g} um, "
                     f"{summary['noise_sigma_source']}); held-out / floor = {summary['held_out_over_floor']:.3g}")
    v = summary.get("verdict") or {"status": "passed", "reasons": []}
    lines.append("verdict: passed" if v["status"] == "passed" else "verdict: FAILED: " + "; ".join(v["reasons"]))
    return lines
