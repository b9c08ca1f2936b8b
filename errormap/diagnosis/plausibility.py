"""Plausibility gates on measured deviations, before any estimate (every chain's checks).

A check file's ``dx_um, dy_um, dz_um`` are judged against the model's prediction at the checks ((n, 3) μm) and
a stated instrument noise σ; the data decides, never the file's name. Another unit
(:func:`deviation_unit_mistake`: an RMS far below the prediction's, :data:`UNIT_RATIO`, or the noise's,
:data:`NOISE_UNIT_RATIO`; the likely factor 10³ or 10⁶ nearest the least-squares scale) and another axis
order (:func:`deviation_axis_mistake`, :data:`AXIS_FIT_RATIO`) raise :class:`~errormap.io.InputError` naming
file, columns and the likely mistake; ``--units as-written`` skips the unit gate, never the axis gate."""
from __future__ import annotations

import itertools

import numpy as np

from ..io import InputError

ERROR_COLUMNS = ("dx_um", "dy_um", "dz_um")
UNIT_RATIO = 50.0
"""A measured column whose RMS is this many times smaller than the model's prediction (which is at least
:data:`UNIT_MIN_PRED_UM`) is a unit mistake: a model identified from sweeps of the same machine predicts its
error to within a few tens of % (measured on the built-in machines: 5–12 % of the RMS), so the measured RMS
cannot be 50× below the prediction, while mm written as μm is 1000× below."""
UNIT_MIN_PRED_UM = 5.0
"""Below this predicted RMS (μm) the model says too little about the size of the error to judge the unit."""
NOISE_UNIT_RATIO = 10.0
"""A measured column whose RMS is this many times below the stated noise σ is a unit mistake: the noise alone
gives every column an RMS of about σ; with at least 10 checks the chance of an RMS below σ/10 is below
P(χ²₁₀ < 0.1) ≈ 1e-9."""
LIKELY_UNITS = (("mm", 1e3), ("m", 1e6))
"""(unit, μm per unit): what a column ~1000× or ~10⁶× too small was written in."""
AXIS_FIT_RATIO = 0.25
"""Another order of the columns is refused as the likely one when the model's squared residual with it is below
this fraction of the given order's. On correct data the best other order leaves 40× or more the given order's
(mill-xyz, seed 3, 600 checks: 43×; grinder: see tests); with ``dx_um``/``dy_um`` exchanged it leaves 0.009×.
A quarter is far from both: only data the model fits 4× better when reordered is refused."""


def _rms(a, axis=0):
    return np.sqrt(np.mean(np.asarray(a, float) ** 2, axis=axis))


def _likely_unit(scale: float) -> str:
    return min(LIKELY_UNITS, key=lambda u: abs(np.log(scale / u[1])))[0]


def deviation_unit_mistake(measured_um, predicted_um, noise_um: float | None = None,
                           columns=ERROR_COLUMNS) -> tuple[list[int], str] | None:
    """``(column indices, message)`` when deviation columns are in another unit than μm, or None.

    ``measured_um``, ``predicted_um`` (n, 3) μm; ``noise_um``: the stated noise σ per coordinate (μm) or None."""
    meas, pred = np.asarray(measured_um, float), np.asarray(predicted_um, float)
    rm, rp = _rms(meas), _rms(pred)
    bad, scales, by_noise_only = [], [], True
    for j in range(meas.shape[1]):
        by_model = rp[j] >= UNIT_MIN_PRED_UM and rm[j] * UNIT_RATIO < rp[j]
        by_noise = noise_um is not None and noise_um > 0 and rm[j] * NOISE_UNIT_RATIO < noise_um
        if not (by_model or by_noise):
            continue
        bad.append(j)
        by_noise_only &= not by_model
        dot = float(meas[:, j] @ meas[:, j])
        ls = float(meas[:, j] @ pred[:, j]) / dot if dot > 0 else 0.0
        scales.append(ls if by_model and ls > 0 else (rp[j] if by_model else noise_um) / max(rm[j], 1e-300))
    if not bad:
        return None
    unit = _likely_unit(float(np.median(scales)))
    names = ", ".join(f"'{columns[j]}'" for j in bad)
    shown = ", ".join(f"{rm[j]:.3g}" for j in bad)
    ref = (f"the stated noise σ is {noise_um:.3g} μm" if by_noise_only else
           "the model predicts " + ", ".join(f"{rp[j]:.3g}" for j in bad) + " μm")
    return bad, (f"column{'s' if len(bad) > 1 else ''} {names}: units do not fit: measured RMS {shown} μm where "
                 f"{ref}: {unit} rather than μm? (× {dict(LIKELY_UNITS)[unit]:g} to get μm)")


def deviation_axis_mistake(measured_um, predicted_um, columns=ERROR_COLUMNS) -> tuple[list[int], str] | None:
    """``(column indices, message)`` when another order of the deviation columns fits the model much better
    (:data:`AXIS_FIT_RATIO`), or None. ``measured_um``, ``predicted_um`` (n, 3) μm."""
    meas, pred = np.asarray(measured_um, float), np.asarray(predicted_um, float)
    k = meas.shape[1]
    given = float(np.sum((meas - pred) ** 2))
    if not given > 0:
        return None
    best, best_rss = None, given
    for perm in itertools.permutations(range(k)):
        if perm == tuple(range(k)):
            continue
        rss = float(np.sum((meas[:, perm] - pred) ** 2))
        if rss < best_rss:
            best, best_rss = perm, rss
    if best is None or best_rss >= AXIS_FIT_RATIO * given:
        return None
    moved = [j for j in range(k) if best[j] != j]
    # the column written under header j holds the model's coordinate i where best[i] == j
    holds = ", ".join(f"'{columns[j]}' holds {columns[best.index(j)]}" for j in moved)
    given_rms, best_rms = np.sqrt(given / len(meas)), np.sqrt(best_rss / len(meas))
    return moved, (f"columns {', '.join(repr(columns[j]) for j in moved)}: the deviations fit another axis: "
                   f"{holds} (model residual RMS {best_rms:.3g} μm so, {given_rms:.3g} μm as written): "
                   "headers exchanged?")


def check_deviations(path, measured_um, predicted_um, *, rows=None, noise_um: float | None = None,
                     units: str = "check", option: str | None = "--units", columns=ERROR_COLUMNS) -> None:
    """Both gates (module doc) on the check file ``path``; raises :class:`InputError` naming it and (``rows``
    (n,), the file line of each check) the row of the largest value of the first column named. ``units``
    ``"as-written"`` skips the unit gate (``option`` named in the message as the way to say so)."""
    meas = np.asarray(measured_um, float)

    def where(cols):
        if rows is None or not np.any(rows):
            return ""
        return f"row {int(rows[int(np.argmax(np.abs(meas[:, cols[0]])))])}, "
    if units != "as-written":
        m = deviation_unit_mistake(meas, predicted_um, noise_um, columns)
        if m is not None:
            tail = f" (if they are μm, {option} as-written)" if option else ""
            raise InputError(f"{path}: {where(m[0])}{m[1]}{tail}")
    m = deviation_axis_mistake(meas, predicted_um, columns)
    if m is not None:
        raise InputError(f"{path}: {where(m[0])}{m[1]}")


def stated_noise(path, comments) -> float | None:
    """The noise σ (μm, > 0) a check file states in a ``# noise_um: σ`` header line, or None (none stated, or 0: a
    noise-free simulation states nothing a noise can be judged against); InputError naming the file when the
    line is there but its value is not a finite number ≥ 0."""
    for c in comments:
        key, sep, value = c.partition(":")
        if sep and key.strip() == "noise_um":
            try:
                v = float(value)
            except ValueError:
                v = float("nan")
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"{path}: header line 'noise_um': expected the instrument's noise σ in μm "
                                 f"(a number ≥ 0), got {value.strip()!r}")
            return v if v > 0 else None
    return None


# -- the verdict of a diagnosis ------------------------------------------------------------------------------
NOISE_EXCESS = 2.0
"""A noise σ estimated from the checks (with the model update) above this many times the instrument's stated σ
fails the verdict: σ̂ from a few hundred residual degrees of freedom is within ±10 % at 2 SE (on correct data
the chains' loop gives 0.95–1.05× the simulated σ), so 2× is not chance but data or a model that cannot be right
(headers exchanged gave 34–46×); such a run is never "at the floor", whatever its held-out / floor ratio."""
BASELINE_Z = 2.0
"""The kept stage of the loop loses to a plain baseline when the baseline lowers the held-out squared residual,
paired per point, by more than 2 standard errors (the loop's own rule for "better", ``FALLBACK_Z``); a kept
learned residual (whose per-point residual is not kept) loses when its held-out RMS is above the baseline's."""


def paired_z(r_kept, r_other) -> float:
    """How much better ``r_other`` (m, 3) is than ``r_kept`` (m, 3) on the same points: the mean per-point drop of the
    squared residual norm over its standard error (0 when the drop does not vary)."""
    gain = np.sum(np.asarray(r_kept) ** 2, axis=1) - np.sum(np.asarray(r_other) ** 2, axis=1)
    sd = gain.std(ddof=1)
    return float(gain.mean() / (sd / np.sqrt(gain.size))) if sd > 0 else 0.0


def ols_linear_baseline(axes, residual_um, fit_idx) -> np.ndarray:
    """The plainest baseline: ``residual_um`` (n, 3) fitted by least squares on the fitting checks ``fit_idx`` as a
    linear function of the axis columns ``axes`` (n, k) plus a constant; → what it leaves at every check (n, 3)."""
    X = np.hstack([np.ones((len(axes), 1)), np.asarray(axes, float)])
    B = np.linalg.lstsq(X[fit_idx], np.asarray(residual_um)[fit_idx], rcond=None)[0]
    return residual_um - X @ B


NOISE_FLOOR_FACTOR = float(np.sqrt(3.0))
"""The held-out noise floor is ``√3·σ``: the vector norm of isotropic noise σ per axis."""


def noise_record(given_um, estimated_um, held_out_rms_um: float, stated_um=None) -> dict:
    """The noise keys of a closed loop's summary, the same on every machine: the floor ``√3·σ`` with σ given
    (``--noise-um``) or else estimated by the model update (``estimated_um``; None: no update ran), the held-out
    RMS over it, and the stated σ the verdict compares the estimate with (``stated_um``: the file's, else the
    given one)."""
    sig = given_um if given_um is not None else estimated_um
    floor = None if sig is None else NOISE_FLOOR_FACTOR * float(sig)
    return {"noise_sigma_source": "given" if given_um is not None else
            ("estimated by the update" if estimated_um is not None else None),
            "noise_sigma_estimated_um": estimated_um,
            "noise_sigma_stated_um": stated_um if stated_um is not None else given_um,
            "noise_floor_um": floor, "held_out_over_floor": None if floor is None else float(held_out_rms_um / floor)}


def diagnosis_verdict(summary: dict) -> dict:
    """``{"status": "passed" | "failed", "reasons": [...]}`` of a closed-loop summary (the one loop,
    :func:`errormap.diagnosis.chain_loop.closed_loop_chain`, the grinder's through its chain included,
    after the learned stage; its held-out RMS ``held_out_rms_um`` or ``rms_final_um``): failed when the noise
    estimated from the checks is far above the stated one (:data:`NOISE_EXCESS`) or the kept model loses to a
    plain baseline on the held-out checks (:data:`BASELINE_Z`)."""
    reasons = []
    stated, est = summary.get("noise_sigma_stated_um"), summary.get("noise_sigma_estimated_um")
    if stated and est is not None and est > NOISE_EXCESS * stated:
        how = summary.get("noise_sigma_estimated_how", "the check noise estimated with the update")
        reasons.append(f"{how} (σ = {est:.3g} μm) is {est / stated:.3g}× the "
                       f"stated σ = {stated:.3g} μm (more than {NOISE_EXCESS:g}×): the checks or the model cannot be "
                       "right; not at the floor")
    kept = summary["kept_stage"]
    held = summary["held_out_rms_um"] if "held_out_rms_um" in summary else summary["rms_final_um"]
    for name, b in (summary.get("baselines_vs_kept") or {}).items():
        lost = (b["held_out_rms_um"] < held if kept == "learned_residual"
                else b["paired_z_over_kept"] > BASELINE_Z)
        if lost:
            reasons.append(f"the kept model ({kept}, held-out RMS {held:.3g} μm) loses to the plain baseline {name} "
                           f"({b['held_out_rms_um']:.3g} μm" + ("" if kept == "learned_residual" else
                                                               f", paired z = {b['paired_z_over_kept']:.2f}") + ")")
    return {"status": "failed" if reasons else "passed", "reasons": reasons}


# -- tracker sweeps: mirrored ball coordinates ------------------------------------------------------------
BALL_COLUMNS = ("x_mm", "y_mm", "z_mm")
MIRROR_FIT_RATIO = 0.25
"""Ball coordinates are refused as mirrored (two of x_mm, y_mm, z_mm exchanged) when the best mirror-image fit
of the nominal ball positions leaves less than this fraction of the best rigid fit's squared residual. A
tracker pose is a rotation and a translation: it cannot mirror. On correct sweeps the rigid fit leaves the
machine's errors and the noise (μm) and the mirror fit metres of misfit (a 3-D spread of balls); with two
columns exchanged it is the other way round. Balls that lie in a plane fit both equally (ratio ~1): nothing is
decided then."""


def _rigid_rss(P, Q, proper: bool) -> float:
    """Least-squares residual (sum of squares) of Q (n, 3) ≈ R P + t with det R = +1 (``proper``) or −1."""
    p, q = P - P.mean(0), Q - Q.mean(0)
    U, _, Vt = np.linalg.svd(p.T @ q)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) * (1.0 if proper else -1.0)
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return float(np.sum((q - p @ R.T) ** 2))


def mirrored_ball_columns(nominal_mm, measured_mm, columns=BALL_COLUMNS) -> str | None:
    """A message when the measured ball centres (n, 3) fit the nominal ones (n, 3) far better as a mirror image
    (:data:`MIRROR_FIT_RATIO`), or None. Which two columns were exchanged (or which one negated) cannot be told:
    with the tracker pose unknown every mirror is every other one times a rotation."""
    P, Q = np.asarray(nominal_mm, float), np.asarray(measured_mm, float)
    proper, mirror = _rigid_rss(P, Q, True), _rigid_rss(P, Q, False)
    if not mirror < MIRROR_FIT_RATIO * proper:
        return None
    n = len(P)
    return (f"columns {', '.join(repr(c) for c in columns)}: the ball coordinates are a mirror image of the machine "
            f"(a tracker pose leaves RMS {np.sqrt(proper / n):.3g} mm, a mirror {np.sqrt(mirror / n) * 1e3:.3g} μm): "
            "two columns exchanged, or one negated?")


# -- the verdict of an arm calibration ----------------------------------------------------------------------
ARM_NOISE_EXCESS = NOISE_EXCESS
"""An arm's kept model whose held-out residual, per coordinate and in units of the stated tracker σ (RMS of
r/σ), is above this fails the verdict: noise alone gives 1 (±5 % at 2 SE with 100 held-out poses), so 2× is
model error or data that contradict the stated noise, as for the machine tools' :data:`NOISE_EXCESS`."""


def arm_verdict(kept: str, r_kept_mm, r_plain_mm, sigma_mm=None) -> dict:
    """``{"status", "reasons", "held_out"}`` of an arm calibration, judged on its held-out poses: failed when the kept
    model (``kept``, residual vectors ``r_kept_mm`` (m, 3), measured − model) loses to the plain least-squares
    calibration (``r_plain_mm`` (m, 3)) by more than :data:`BASELINE_Z` paired standard errors, or leaves a residual
    above :data:`ARM_NOISE_EXCESS` times the stated tracker σ per coordinate (``sigma_mm``: scalar or (m,) per pose,
    None: not stated, not judged)."""
    rk, rp = np.asarray(r_kept_mm, float), np.asarray(r_plain_mm, float)
    rms_k, rms_p = float(np.sqrt(np.mean(np.sum(rk ** 2, 1)))), float(np.sqrt(np.mean(np.sum(rp ** 2, 1))))
    z = paired_z(rk, rp)
    held = {"poses": int(len(rk)), "kept_rms_mm": rms_k, "plain_lsq_rms_mm": rms_p, "paired_z_plain_over_kept": z,
            "residual": "measured residual (measured − model) on the held-out poses, 3-D norm RMS"}
    reasons = []
    if z > BASELINE_Z:
        reasons.append(f"the kept model ({kept}, held-out RMS {rms_k:.4g} mm) loses to the plain least-squares "
                       f"calibration ({rms_p:.4g} mm, paired z = {z:.2f})")
    if sigma_mm is not None:
        sig = np.broadcast_to(np.asarray(sigma_mm, float).reshape(-1, 1), rk.shape)
        ratio = float(np.sqrt(np.mean((rk / sig) ** 2)))
        held.update(noise_ratio=ratio, sigma_stated_mm=float(np.sqrt(np.mean(sig ** 2))))
        if ratio > ARM_NOISE_EXCESS:
            reasons.append(f"the held-out residual per coordinate is {ratio:.3g}× the stated tracker σ "
                           f"({held['sigma_stated_mm']:.3g} mm; more than {ARM_NOISE_EXCESS:g}×): the stated noise "
                           "or the model cannot be right")
    return {"status": "failed" if reasons else "passed", "reasons": reasons, "held_out": held}
