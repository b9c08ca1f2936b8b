"""Controller compensation tables (``volcomp export``): build, check, write, read back.

:func:`export_table` sizes a table for the tolerance, re-simulates the controller's use of it on
the flute path and random points (MODEL residual, and TRUE with a truth), refuses it when the
tolerance is not met (unless forced), writes it into a staging folder, reads it back and
compares, and renames the folder into place with ``export.json``. :func:`export_drift` does the
same for a drift model's coefficients on a log. The formats: :mod:`compensation.export`.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.io import sha256_file

from compensation.app.validate import UsageError

from ... import export as ex

READ_BACK_TOL_UM = 1e-5
"""Read-back check (μm; joint units × 1000 for LinuxCNC, i.e. μm and millidegrees): the CSV files
hold 12 significant digits and the LinuxCNC files 9 decimals of mm/deg (rounding ≤ 5e-7 μm per
value, three values per command), so the table read back must agree to 1e-5."""


@dataclass
class TableSettings:
    """One table export. ``fmt``: an :data:`compensation.export.ALL_FORMATS` name other than
    ``drift``; ``region``: ``{column: (lo, hi)}`` of linear axes or None (linuxcnc)."""

    model: str
    fmt: str
    out: str
    tolerance_um: float
    check_points: int = 2000
    seed: int = 0
    truth: str | None = None
    diagnosis: str | None = None
    points: int = ex.LINUXCNC_MAX_POINTS
    region: dict | None = None
    force: bool = False
    tracking_uri: str | None = None
    model_verdict: dict | None = None   # the model's diagnosis verdict (compensation.fields.check_verdict), recorded


@dataclass
class DriftSettings:
    """One drift-coefficient export: ``sample_period_s`` None = the check log's median step;
    ``log`` None: with ``sim`` / ``sim_seed``, a simulated log of family ``sim`` (default lumped) and seed
    ``sim_seed``; without, the model's own fitting log recorded in ``drift_model.json`` (else refused)."""

    model: str
    out: str
    tolerance_um: float
    sample_period_s: float | None = None
    log: str | None = None
    sim: str | None = None
    sim_seed: int | None = None
    force: bool = False
    model_verdict: dict | None = None   # the model's diagnosis verdict (compensation.fields.check_verdict), recorded


def load_model(s: TableSettings, machine):
    """``(ModelError, description, left_out)``: the model ``s.model`` with the reversal terms of ``s.diagnosis``
    (and the labels of the diagnosed effects a table cannot carry)."""
    try:
        model, desc, src = ex.load_model(s.model, s.fmt, machine, s.tracking_uri)
        left = []
        if s.diagnosis:
            if src.terms:
                raise ValueError("--diagnosis: MODEL is a model.json with effect terms, which carries its diagnosed terms already; "
                                 "give it alone, or its element set with --diagnosis")
            model, left = ex.reversal_from_diagnosis(s.diagnosis, model)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    print(f"export: model {src.description}", file=sys.stderr)
    return model, desc, left


def load_truth(path, machine):
    """``tool(axes, dirs) -> (n, 3)`` mm of ``--truth`` on the machine tool ``machine`` (a ``simulate`` folder, its
    ``truth.json`` or a truth element set; a grinder file's through its chain: :func:`compensation.evaluate.load_truth`)."""
    from types import SimpleNamespace
    from ...evaluate import load_truth as read_truth
    return ex.chain_truth_tool_points(SimpleNamespace(truth=read_truth(path, machine)), machine)


def notes_of(model, table, left_out) -> tuple[list[str], list[str]]:
    """``(left out, other notes)``: what the table does not carry, and how it carries a rotary joint, one line
    each (printed as notes; the first recorded in export.json)."""
    left = [f"effect {e}: not carried by a per-joint table" for e in left_out]
    if not isinstance(table, ex.JointTables):
        return left, []
    left += [f"rotary joint {a.word}: no file (LinuxCNC takes one pitch table per joint; the exact solver keeps this "
             "joint as programmed, so what its own errors do is left in the residual below)"
             for a in model.mt.axes if a.word.lower() not in table.joints]
    if "temp_c" in model.needs:
        left.append(f"thermal terms: no temperature input in a pitch table; tabulated at {ex.TABLE_TEMP_C:g} C")
    notes = [f"rotary joint {j.upper()}: table in degrees, its correction averaged over the other axes weighted by r^2 "
             "(r the tool point's distance from its axis: the least-squares angle)"
             + (f"; one turn from {table.turns[j]:g} deg, read with the position folded into it" if j in table.turns
                else "") for j, u in table.units.items() if u != "mm"]
    return left, notes


def export_table(s: TableSettings, machine, on_check=None, log=None, on_note=None) -> dict:
    """Build, check and write one table into ``s.out``; returns the ``export.json`` document
    (``files``: name → size). ``on_check(check, has_truth)`` is called with the check before the
    tolerance decides, ``on_note(line)`` with each note (default: ``log``); progress goes to ``log`` (stderr)."""
    from errormap.seeds import spawn_seeds
    log = sys.stderr if log is None else log
    say = lambda msg: print(msg, file=log)  # noqa: E731
    model, model_desc, left_out = load_model(s, machine)
    truth = load_truth(s.truth, machine) if s.truth else None
    sets = ex.check_sets(machine, s.check_points, s.seed)
    say("sizing the table and re-simulating the controller on the " + " and the ".join(sets) + " ...")
    table_seed = spawn_seeds(s.seed, 1)[0] if s.fmt == "linuxcnc" else s.seed
    try:
        table, sizing, check = ex.build_checked_table(s.fmt, model, machine, s.tolerance_um, sets, truth,
                                                      {}, n_points=s.points, region=s.region, seed=table_seed,
                                                      log=say)
    except ValueError as exc:
        raise UsageError(f"--region: {exc}" if s.region and "region" in str(exc) else str(exc)) from None
    left, notes = notes_of(model, table, left_out)
    for line in left + notes:
        (on_note or say)(f"note: {line}")
    if on_check is not None:
        on_check(check, truth is not None)
    worst = ex.worst_model_um(check)
    met = worst <= s.tolerance_um
    if not met and not s.force:
        raise UsageError(f"tolerance not met: the {s.fmt} table leaves a model residual up to {worst:.4g} um > "
                         f"--tolerance-um {s.tolerance_um:g}; nothing written (--force writes anyway, recorded "
                         "in export.json)")
    info = manifest(s, machine, model, model_desc, table, sizing, check, worst, met, sets, truth is not None)
    if s.fmt == "linuxcnc":
        info["left_out"] = left
    with ex.staged_folder(s.out) as tmp:
        files = ex.write_table(table, tmp, machine, model_desc)
        back = ex.read_back(table, tmp, machine)
        diff = ex.table_difference_um(table, back, machine, sets)
        if diff > READ_BACK_TOL_UM:
            raise RuntimeError(f"read-back check failed: the written {s.fmt} table differs from the built one by "
                               f"{diff:.3g} um")
        info["read_back_difference_um"] = diff
        info["files"] = {p.name: p.stat().st_size for p in files}
        info["table_values"] = table.n_values()
        ex.write_manifest(tmp, info)
    return info


def manifest(s: TableSettings, machine, model, model_desc, table, sizing, check, worst, met, sets, has_truth) -> dict:
    """The ``export.json`` document of a table export (before its files are written)."""
    mt = model.mt
    info = {"format": "volcomp-export/1", "table_format": s.fmt, "model": model_desc, "model_verdict": s.model_verdict,
            "machine": {"name": machine.name, "file": machine.path, "sha256": machine.sha256},
            "tolerance_um": s.tolerance_um, "tolerance_met": bool(met), "worst_model_residual_um": worst,
            "override": None if met else {"forced": True, "reason": f"worst model residual {worst:.6g} um exceeds "
                                                                    f"the tolerance {s.tolerance_um:g} um"},
            "sizing": sizing, "check": check,
            "check_points": {**({"flute": "default flute path (compensation.toolpath.flute_path)"} if "flute" in sets
                                else {}),
                             "volume": f"{s.check_points} uniform random axis points, seed {s.seed}"},
            "residuals": {"model": "fwd(q_c) + E_model(q_c) - p_d (um), q_c = the controller's command with the table",
                          "true": "truth.tool_point(q_c) - p_d (um)" if has_truth else "no --truth given"},
            "truth": s.truth, "iso230_names": dict(zip(mt.slot_names, mt.iso_names))}
    if s.fmt == "linuxcnc":
        info["diagnosis"] = s.diagnosis
        info["joints"] = {j: mt.axis_columns[k] for j, k in table.joints.items()}
        info["region"] = s.region or "calibrated volume"
        info["max_forward_minus_reverse_um"] = {j: 1e3 * v for j, v in table.max_reversal().items()}
        info["joint_units"] = dict(table.units)
        info["joint_turns_from_deg"] = dict(table.turns)
        info["linuxcnc"] = {"columns": "nominal forward reverse (the joint's unit: mm; deg for a rotary joint)",
                            "meaning": "forward/reverse: actual joint position when commanded to nominal moving +/-; "
                                       "the controller commands nominal + (nominal - actual), linear between lines",
                            "turns": "a joint in joint_turns_from_deg has a one-turn table; the controller folds its "
                                     "position into it (wrapped rotary joint)"}
    return info


def fitting_log_of(model, model_path) -> str:
    """The model's own fitting log (``fitted_on.log_path`` in drift_model.json, unchanged since: same
    sha256), or a UsageError in one line asking for ``--log``."""
    meta = model.meta or {}
    p, h = meta.get("log_path"), meta.get("log_sha256")
    if not p:
        raise UsageError(f"{model_path}: the drift model records no fitting log (written before logs were recorded): "
                         "give --log LOG.csv to check the controller on (or --sim for a simulated log)")
    if not Path(p).is_file():
        raise UsageError(f"{model_path}: the model's fitting log {p} is not found: give --log LOG.csv to check the "
                         "controller on")
    if h and sha256_file(p) != h:
        raise UsageError(f"{model_path}: the model's fitting log {p} has changed since the fit (sha256 differs): "
                         "give --log LOG.csv to check the controller on")
    return p


def drift_check_log(s: DriftSettings, progress=None, model=None):
    """The log the controller is re-simulated on, its description, and the noise-free displacement
    when it is simulated (``{channel: (n,)}``, else None); notes go to ``progress`` (stderr)."""
    from errormap.diagnosis.drift import DriftLog, load_drift_log
    progress = sys.stderr if progress is None else progress
    if s.log is None and s.sim is None and s.sim_seed is None and model is not None:
        path = fitting_log_of(model, s.model)
        print(f"check log: the model's own fitting log {path} (recorded in {s.model})", file=progress)
        s = DriftSettings(**{**s.__dict__, "log": path})
    if s.log is not None:
        if s.sim is not None or s.sim_seed is not None:
            raise UsageError("--sim and --sim-seed choose a simulated log: give them or --log, not both")
        log = load_drift_log(s.log, causal=True, require_displacement=False)
        for c, why in log.notes["dropped"].items():
            print(f"dropped input {c}: {why}", file=progress)
        return log, f"{s.log} (sha256 {sha256_file(s.log)})", None
    from errormap.diagnosis.drift_sim import SIMULATORS
    fam, seed = s.sim or "lumped", 0 if s.sim_seed is None else s.sim_seed
    cols = SIMULATORS[fam](seed, n_dropouts=0)
    truth = cols.pop("_truth")
    name = f"<simulated {fam} log, seed {seed}>"
    log = DriftLog(cols["time_s"], {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")},
                   {k[:-3]: v for k, v in cols.items() if k.endswith("_um")}, cols.get("speed_rpm"), name)
    return log, f"simulated: errormap.diagnosis.drift_sim {fam}, seed {seed}, no dropouts", truth["clean_um"]


def export_drift(s: DriftSettings, on_check=None, log=None) -> dict:
    """``--format drift``: coefficients at a fixed sample period, checked on a log before writing;
    returns the ``export.json`` document. ``on_check(check)`` is called before the tolerance
    decides; progress goes to ``log`` (stderr)."""
    from errormap.diagnosis.drift_models import DriftModel
    log = sys.stderr if log is None else log
    dt = s.sample_period_s
    from ...fields import require_kind, resolve_model
    src = require_kind(resolve_model(s.model), ("drift",), "--format drift exports")
    print(f"export: model {src.description}", file=sys.stderr)
    model = DriftModel.load(src.path)
    model_desc = f"{s.model} (drift model, sha256 {sha256_file(s.model)})"
    drift_log, log_desc, clean = drift_check_log(s, log, model)
    step = float(np.median(np.diff(drift_log.time_s)))
    if dt is None:
        dt = step
    print(f"re-simulating the controller at dt = {dt:g} s on {log_desc} (median sampling step {step:g} s) ...",
          file=log)
    with ex.staged_folder(s.out) as tmp:
        # force=True here: the check is printed first, then refused below (the staging folder is discarded)
        res = ex.export_drift_coefficients(model, tmp, dt, drift_log, model_desc, s.tolerance_um, clean, force=True)
        if on_check is not None:
            on_check(res["check"])
        worst, met = res["worst_model_residual_um"], res["tolerance_met"]
        if not met and not s.force:
            raise UsageError(f"tolerance not met: at a sample period of {dt:g} s the drift coefficients leave a model "
                             f"residual up to {worst:.4g} um > --tolerance-um {s.tolerance_um:g}; nothing written "
                             "(--force writes anyway, recorded in export.json)")
        coef = res["coefficients"]
        info = {"format": "volcomp-export/1", "table_format": "drift", "model": model_desc,
                "model_verdict": s.model_verdict,
                "sample_period_s": dt, "sample_period_given": s.sample_period_s is not None,
                "check_log_median_step_s": step, "tolerance_um": s.tolerance_um, "tolerance_met": met,
                "worst_model_residual_um": worst,
                "override": None if met else {"forced": True, "reason": f"worst model residual {worst:.6g} um "
                                                                        f"exceeds the tolerance {s.tolerance_um:g} um"},
                "check_log": log_desc, "check": res["check"],
                "residuals": {"model": "controller(coefficients) - DriftModel.predict (the fixed gains, without "
                                       "controller.distance_shrink) at each log time (um)",
                              "measured": "log displacement - prediction (um); before = the displacement itself",
                              "true": "noise-free simulated displacement - prediction (um)" if clean is not None
                                      else "no simulated log (--log given)"},
                "controller": {"ticks": f"every {dt:g} s from the log's first time; each tick reads the latest "
                                        f"logged value at or before it (within {ex.DRIFT_TICK_EPS_S:g} s)",
                               "output": "the prediction of the latest tick at or before each log time",
                               "update": "gains fixed between exports; `volcomp drift-predict MODEL LOG --update "
                                         "--save-model NEW.json` re-fits offsets and gains from on-machine "
                                         "measurements (Kalman filter on the parameters), then re-export NEW.json: "
                                         "only the gain_<ch> columns change",
                               "distance_shrink": ex.drift_distance_rule(model, coef)},
                "files": {ex.DRIFT_FILE: res["file"].stat().st_size},
                "table_values": coef.n_values()}
        ex.write_manifest(tmp, info)
    return info
