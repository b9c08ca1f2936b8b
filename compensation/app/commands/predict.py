"""``volcomp predict``: evaluate any error field at axis points from a CSV."""
from __future__ import annotations

import sys

import numpy as np

from errormap.io import InputError, companion_path, read_table, write_csv
from errormap.field import machine_axes
from errormap.machine import load_machine
from errormap.units import check_units

from compensation.app.validate import UsageError, allowed_verdict

from ..families import family_of
from ..options import add_units_option
from ...fields import FAILED_VERDICT, check_verdict, resolve_model
from ...model_file import read_model


def register(sub):
    p = sub.add_parser("predict", help="evaluate an error field at axis points (CSV with the machine's axis columns, e.g. x_mm, z_mm, a_deg)")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name; default: the built-in "
                   "grinder; a machine-tool chain (mill-xyz, five-axis-ac ...) takes its own axis columns")
    p.add_argument("--model", required=True, help="element-set file (JSON), a diagnosed DIR/model.json (volcomp "
                   "diagnose: the kept stage, the hybrid's learned residual included), MLflow run id or runs:/ URI; "
                   "an arm (--machine ur5 ...): its DIR/model.json (volcomp calibrate)")
    p.add_argument("--tracking-uri", default=None)
    p.add_argument("points", help="CSV with x_mm, z_mm, a_deg (a chain machine: its axis columns, e.g. "
                   "x_mm, y_mm, z_mm; an arm: its joint columns q1_deg ..., output the calibrated tool point and "
                   "dx_mm, dy_mm, dz_mm against the nominal chain)")
    p.add_argument("--out", required=True, help="output CSV (input columns + dx_um, dy_um, dz_um)")
    p.add_argument("--allow", action="append", default=[], choices=("extrapolate", "volume", FAILED_VERDICT),
                   help="extrapolate (or volume, compensate's name for the same guard): predict also at points "
                        "outside the model's calibrated volume (refused by default: a model says nothing reliable "
                        "there; a diagnosed model with a learned residual: outside the checks' box); "
                        f"{FAILED_VERDICT}: use a model whose diagnosis verdict failed (refused by default); the "
                        "override is recorded in the output's header")
    p.add_argument("--band", choices=("1sigma", "95"), default=None,
                   help="also write the half-width of a per-component band (1-σ or 95 %%) from the element set's "
                        "covariance (NAME.cov.npz beside it, written by `volcomp identify`); a diagnosed model.json "
                        "writes its TOTAL band (learned residual's (+) the kept elements') always, 95 %% unless "
                        "--band 1sigma; an arm: the kept stage's band of a new measurement, dx_band95_mm ... (docs/explanation/serial-arms.md)")
    add_units_option(p, "points")
    p.set_defaults(func=run)


def _check_volume(args, table, axes, field, machine) -> int:
    """Refuse points outside the field's calibrated volume (unless ``--allow extrapolate``),
    naming the first one's row and column; a far-off value is most often a unit mistake. Returns the
    number of points outside that the override let through."""
    from ...guards import calibrated_volume, volume_violations
    names = machine_axes(machine)
    bad, reasons = volume_violations(axes, field, names=names)
    if not len(bad) or "extrapolate" in args.allow or "volume" in args.allow:
        return len(bad)
    lo, hi = calibrated_volume(field, names)
    i = int(bad[0])
    lin = np.array([n.endswith("_mm") for n in names])
    far = np.abs(axes[i, lin]) > 100 * np.maximum(np.abs(lo[lin]), np.abs(hi[lin]))
    hint = "; positions in μm rather than mm?" if far.any() else ""
    raise InputError(f"{table.path}: row {table.row_number(i)}: {reasons[0]} ({len(bad)} of {len(axes)} points "
                     f"outside the calibrated volume{hint}); pass --allow extrapolate to predict there anyway")


def _band_columns(sd, band) -> dict:
    """``{dx_band<tag>_um: …}`` from per-component standard deviations ``sd`` (n, 3) μm: 1-σ for
    ``--band 1sigma``, else the 95 % half-width."""
    from errormap.uncertainty import Z95
    k, tag = (1.0, "1sigma") if band == "1sigma" else (Z95, "95")
    return {f"{c}_band{tag}_um": k * sd[:, j] for j, c in enumerate(("dx", "dy", "dz"))}


def _point_conditions(t, needs, units, model: str = "model") -> dict:
    """Per-point conditions a model's effect terms need (``temp_c``, ``time_s``, ``dir_<w>``) from the
    points file's columns of those names (the check files' names and rules); a missing column is
    refused naming it."""
    out = {}
    for c in needs:
        if c not in t:
            hint = "°C" if c == "temp_c" else "+1 or -1, the approach direction" if c.startswith("dir_") else "s"
            raise InputError(f"{t.path}: the {model}'s effect terms need the condition '{c}' at every point: add a "
                             f"column '{c}' ({hint})")
        if c.startswith("dir_"):
            out[c] = t.int(c, allowed=(-1, 1)).astype(float)
        else:
            out[c] = t.float(c)
            if c == "temp_c":
                check_units(t.path, [t.row_number(k) for k in range(len(t))], temps={"temp_c": out[c]}, units=units,
                            option="--units")
    return out


def _predict_diagnosed(args, t, axes, machine, model):
    """A diagnosed model.json: the kept stage's prediction (elements + effect terms + the learned
    residual when kept), its TOTAL band (learned ⊕ the elements' J Σ Jᵀ, the hybrid's
    :meth:`compensation.hybrid.HybridField.band_std`; 95 % unless ``--band 1sigma``) and, with a
    learned residual, a column ``learned_part``: ``fitted`` inside the checks' box, ``unknown``
    outside (the learned part is tapered to zero there and says nothing). Points outside the
    calibrated volume (the checks' box for a hybrid) are refused unless ``--allow volume``
    (or ``extrapolate``), recorded in the header by the caller. → (columns, header lines, points let through)."""
    from compensation.hybrid import total_band_std
    from errormap.chain_covariance import band_sd, covariance_path
    field = model.field.corrected
    n_out = _check_volume(args, t, axes, field, machine)
    cond = _point_conditions(t, field.needs, args.units, "diagnosed model")
    el_path = model.elements_path
    cov = None
    if model.covariance_path is not None:
        cov = _read_covariance(machine, model)
    elif args.band:   # the band asked for, half of it missing: refused, never a band without the elements' part
        raise UsageError(f"--band needs the kept elements' covariance {covariance_path(el_path)} (written beside "
                         f"them by volcomp diagnose); not found")
    print(f"predicting {len(axes)} points with the {model.description} ...", file=sys.stderr)
    e = field.predict(axes, **cond)
    learned = model.learned
    cols = {n: np.array(t.raw(n)) for n in t.names if n not in ("dx_um", "dy_um", "dz_um")}
    cols.update({"dx_um": e[:, 0], "dy_um": e[:, 1], "dz_um": e[:, 2]})
    if cov is not None:   # the TOTAL band: learned (when kept) ⊕ the elements' J Σ Jᵀ
        sd = total_band_std(learned, machine, axes, lambda p: band_sd(machine, model.elements, cov, p))
        cols.update(_band_columns(sd, args.band))
    meta = [f"machine: {machine.name}", f"stage: {model.stage}"]
    if learned is not None:
        meta += _learned_part(cols, learned, axes)
    if cov is not None:
        meta.append(f"band: total {'1-sigma' if args.band == '1sigma' else '95 %'} per component = "
                    + ("learned residual's band (cross-validation calibrated; outside the checks' box its prior) "
                       "(+) " if learned is not None else "")
                    + "the elements' J Sigma J^T"
                    + (" (effect terms' own uncertainty not included)" if model.terms else ""))
    else:
        meta.append(f"band: none (the kept elements' covariance {covariance_path(el_path).name} was not found)")
    return cols, meta, n_out


def _learned_part(cols, learned, axes) -> list:
    """A hybrid's ``learned_part`` column into ``cols`` — ``fitted`` inside the checks' box (every linear axis of
    the learned residual's ``box_axes`` within its range), ``unknown`` outside (the learned part is tapered to
    zero there and says nothing) — and its header line (the family and the box, axis by axis)."""
    inside = learned.inside(axes)
    cols["learned_part"] = np.where(inside, "fitted", "unknown")
    from training.residual import FAMILY_NAMES
    box = ", ".join(f"{n} {lo:.6g}..{hi:.6g}" for n, lo, hi in zip(learned.box_names, learned.lo, learned.hi))
    return [f"learned residual: {FAMILY_NAMES.get(learned.chosen, learned.chosen)}; checks' box {box} "
            f"(learned_part unknown outside it: {int((~inside).sum())} of {len(axes)} points)"]


def _read_covariance(machine, model):
    """The model's element-set covariance ``(slot names, stations, Σ)``, read and checked against its element set and
    ``machine`` (InputError naming the file and key)."""
    from errormap.chain_covariance import read_chain_covariance
    from ..workflows.measurement import check_chain_covariance
    cov = read_chain_covariance(model.covariance_path, model.elements)
    check_chain_covariance(machine, model.elements, cov, model.covariance_path)
    return cov


def _chain_covariance(args, model, machine):
    """``--band`` on a machine tool, checked before any work: the identification covariance of the model's element
    set (``E.cov.npz`` of ``identify --machine`` beside it, or the file its model.json names); refused naming the
    file for a model that holds more than elements (their band alone would understate it) or no covariance."""
    if not model.elements_only:
        raise UsageError(f"--band needs an element set with its covariance (E.cov.npz of volcomp identify); "
                         f"{args.model} holds {', '.join(model.holds()) or 'no elements'}")
    if model.covariance_path is None:
        raise InputError(f"{model.source.path}: --band needs the identification's covariance beside the element set "
                         f"({companion_path(model.elements_path, '.cov.npz').name}, written by volcomp identify; "
                         "or key 'covariance' of a model.json); none found")
    return _read_covariance(machine, model)


def run(args) -> int:
    machine = load_machine(args.machine)
    family = family_of(machine)
    family.refuse_unsupported("predict", args)
    return RUNNERS[family.target("predict")](machine, args)


def _run_arm(machine, args) -> int:
    """An arm: its model.json at joint configurations."""
    from ..workflows.arm_predict import arm_predict_settings_of, run_arm_predict
    return run_arm_predict(machine, args.points, arm_predict_settings_of(args.model, args.out, args.band, args.allow))


def _run_parallel(machine, args) -> int:
    """A parallel machine: its model.json at commanded poses."""
    from ..workflows.pkm_predict import run_pkm_predict
    return run_pkm_predict(machine, args.points, args.model, args.out)


def _run_machine_tool(machine, args) -> int:
    """Every machine tool (the built-in grinder among them): any error field at its axis columns, one output form."""
    names = machine_axes(machine)   # the machine's own axis columns (the grinder's x_mm, z_mm, a_deg)
    t = read_table(args.points, "points")
    t.require(*names)
    if len(t) == 0:   # a header alone: nothing to predict (an empty output would look like a result)
        raise InputError(f"{t.path}: no data rows under the header (columns {', '.join(names)})")
    axes = np.stack([t.float(c) for c in names], axis=1)
    check_units(t.path, [t.row_number(k) for k in range(len(t))], machine=machine, axes=axes, axes_columns=names,
                coverage="path", units=args.units, option="--units")
    src = resolve_model(args.model)  # by content: the file's format key, a model folder, an MLflow reference
    verdict = check_verdict(src.path, FAILED_VERDICT in args.allow)  # a failed diagnosis: refused unless allowed
    allowed = [f"allowed: {allowed_verdict(verdict)}"] if allowed_verdict(verdict) else []
    model = read_model(args.model, machine, args.tracking_uri, source=src)
    tail = [f"model: {src.description}", f"model_kind: {src.kind}", f"model_holds: {', '.join(model.holds())}",
            f"units: {args.units}"]
    if model.per_point:  # the grinder's old closed-loop (and hybrid) model: its own band and conditions
        cols, meta, n_out = _predict_diagnosed(args, t, axes, machine, model)
    else:
        cols, meta, n_out = _predict_chain(args, t, axes, machine, model, src)
    if n_out:   # the override recorded in the output itself, on every machine
        meta.append(f"allowed: volume ({n_out} of {len(axes)} points outside the calibrated volume, "
                    f"--allow {'volume' if 'volume' in args.allow else 'extrapolate'})")
    path = write_csv(args.out, cols, header_comments=meta + allowed + tail)
    print(f"wrote {len(axes)} predictions to {path}")
    return 0


def _predict_chain(args, t, axes, machine, model, src):
    """Any other model: its field at the points (per-point conditions from their columns), ``--band`` the element
    set's J Σ Jᵀ per point through the chain's parameter Jacobian. → (columns, header lines, points let in)."""
    cov = _chain_covariance(args, model, machine) if args.band else None
    field = model.field
    cond = _point_conditions(t, model.needs, args.units) if model.needs else None  # per point, from columns
    n_out = _check_volume(args, t, axes, field, machine)
    print(f"predicting {len(axes)} points with the {src.description} ...", file=sys.stderr)
    from ..validate import predict_batched
    e = predict_batched(field, axes, cond)
    cols = {n: np.array(t.raw(n)) for n in t.names if n not in ("dx_um", "dy_um", "dz_um")}
    cols.update({"dx_um": e[:, 0], "dy_um": e[:, 1], "dz_um": e[:, 2]})
    meta = [f"machine: {machine.name}"]
    if model.learned is not None:   # a loop's model.json with its kept learned residual
        meta += [f"stage: {model.stage} on {model.doc.get('base_stage')}"] + _learned_part(cols, model.learned, axes)
    if args.band:
        from errormap.chain_covariance import band_sd
        print(f"band: covariance {model.covariance_path} ({len(cov[0])} parameters)", file=sys.stderr)
        cols.update(_band_columns(band_sd(machine, model.elements, cov, axes), args.band))
    return cols, meta, n_out


RUNNERS = {"chain": _run_machine_tool, "arm": _run_arm, "parallel": _run_parallel}
"""The runner of each target of ``predict`` (:meth:`compensation.app.families.Family.target`)."""

