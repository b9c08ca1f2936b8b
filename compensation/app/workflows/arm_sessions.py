"""What carries across measurement sessions, decided by blocked cross-validation over the sessions of one calibration
file (its ``session`` column; the poses already moved into one frame, :func:`errormap.arm_sessions.align_sessions`).

Each session in turn is held out: :func:`calibrate_arm` runs on the other sessions (its own decisions inside them),
and the held-out session is re-registered on its first N poses (:data:`TRANSFER_POSES`) the way ``volcomp register``
does — every candidate (the plain calibration, the kept geometric stage alone, the kept stage with its learned
residual, and, where the sessions were logged at different temperatures, the geometric stage with the expansion term
fitted across the other sessions) registered on the N poses and judged on the rest of the session (MEASURED residual,
mean position norm, mm), and register's own choice among them (:func:`errormap.arm_register.choose_candidate`).

A stage is CARRIED to other sessions only where, at :data:`TRANSFER_DECIDE_POSES` registration poses, its mean over
the held-out sessions is below that of the plainer model it adds to (the geometric stage: the plain calibration; the
learned stage and the temperature term: the geometric stage they are fitted on), on the same sessions. A stage that
helps inside one session only is reported as such (``carried`` false, ``why``) and ``register`` does not weigh it.
"""
from __future__ import annotations

import io

import numpy as np

from errormap.arm_register import MIN_POSES, choose_candidate, fit_frame, registered_point
from errormap.arm_sessions import expanded_params, fit_expansion, session_groups, session_temperatures

from .arm_calibration import calibrate_arm, stage_name
from .arm_register import PLAIN, candidates_of

TRANSFER_POSES = (6, 20, 50)
"""Registration poses of a held-out session (its first N by file order; the rest of it judges)."""
TRANSFER_DECIDE_POSES = 20
"""The N at which a stage's carrying is decided (or the largest N every held-out session allows, if smaller)."""
MIN_JUDGED_POSES = 10
"""Fewest poses of a held-out session left to judge on after its N registration poses."""
THERMAL_MIN_SPAN_C = 0.5
"""The sessions' mean logged temperatures must span at least this (°C) for the expansion term to be tried."""
TRANSFER_MAX_POSES = 2000
"""Each held-out session's calibration on the other sessions runs on at most this many of their poses (a seeded
subset; the final calibration uses all): the decision needs the stages' kind, not their last digit, and a file of
20,000 poses would otherwise cost one full calibration per session."""
ROLES = ("plain", "geometric", "learned", "temperature")
BASE_OF = {"geometric": "plain", "learned": "geometric", "temperature": "geometric"}
"""The plainer model each role adds to: what it must beat across sessions to be carried."""


def role_of(name: str, learner) -> str:
    return "plain" if name == PLAIN else ("temperature" if name.endswith(" + temperature") else
                                          "learned" if learner is not None else "geometric")


def thermal_reference(fit) -> float | None:
    """The calibration's reference temperature (°C, the mean of the sessions' means) where the sessions' mean logged
    temperatures span at least :data:`THERMAL_MIN_SPAN_C`, else None."""
    t = None if fit.temp_c is None else np.array([fit.temp_c[i].mean() for _, i in session_groups(fit)])
    return None if t is None or np.ptp(t) < THERMAL_MIN_SPAN_C else float(t.mean())


def thermal_candidate(chain, core, fit, t_ref_c, session_temp_c):
    """(name, chain, params, None, alpha_per_k) of the kept geometric stage expanded to ``session_temp_c``, α fitted on
    ``fit``'s residuals of that stage."""
    geo = core["geometric_model"]
    alpha = fit_expansion(geo.chain, geo.params, fit, fit.xyz_mm - geo.predict(fit.q), t_ref_c)
    name = (PLAIN if geo.method == "plain least squares" else stage_name(geo.model)) + " + temperature"
    return name, geo.chain, expanded_params(geo.chain, geo.params, alpha * (session_temp_c - t_ref_c)), None, alpha


def judge_session(cands, sess, n_reg) -> dict:
    """{n: {"meas": {name: mean mm}, "kept": register's choice}} of candidates (name, chain, params, learner)
    registered on ``sess``'s first n poses and judged on the rest."""
    out = {}
    for n in n_reg:
        fit, rest = sess.subset(np.arange(n)), sess.subset(np.arange(n, len(sess)))
        meas = {}
        for name, ch, params, lrn in cands:
            x, _, _, R, _, _ = fit_frame(ch, params, fit, lrn)
            meas[name] = float(np.linalg.norm(rest.xyz_mm - registered_point(ch, x, lrn, R, rest.q), axis=1).mean())
        kept = choose_candidate(cands, fit)["kept"]
        out[n] = {"meas": meas, "kept": kept, "shipped_mm": meas[kept]}
    return out


def across_sessions(chain, fit, learned=True, k_folds=5, n_restarts=1, seed=0, say=None) -> dict:
    """Blocked CV over the sessions of ``fit`` (aligned poses with ``session`` labels): the held-out figures per
    session and N, the role means, and which roles are carried (module docstring)."""
    groups = session_groups(fit)
    n_min = min(len(i) for _, i in groups)
    n_reg = [n for n in TRANSFER_POSES if n >= MIN_POSES and n + MIN_JUDGED_POSES <= n_min]
    t_ref = thermal_reference(fit)
    rows = []
    if not n_reg:
        return {"sessions": [], "carried": {}, "why": {r: f"every session needs at least {MIN_POSES + MIN_JUDGED_POSES}"
                                                          " poses to be held out" for r in BASE_OF}}
    for lab, idx in groups:
        rest = np.setdiff1d(np.arange(len(fit)), idx)
        if len(rest) > TRANSFER_MAX_POSES:
            rest = np.sort(np.random.default_rng([seed, len(rows)]).choice(rest, TRANSFER_MAX_POSES, replace=False))
        train = fit.subset(rest)
        if say:
            say(f"sessions: session {lab!r} held out ({len(idx)} poses); calibrating on the other {len(train)}")
        core = calibrate_arm(chain, train, train.subset(np.arange(min(len(train), 20))), learned=learned,
                             k_folds=k_folds, n_restarts=n_restarts, seed=seed, log=io.StringIO(), band_blocked=False)
        cands = [(n, g.chain, g.params, lr) for n, g, lr in candidates_of(core["geometric_model"], core["kept_learner"],
                                                                          core["plain_model"], core["kept_stage"])]
        sess = fit.subset(idx)
        alpha = None
        if t_ref is not None:
            *th, alpha = thermal_candidate(chain, core, train, t_ref, float(sess.temp_c.mean()))
            cands.append(tuple(th))
        res = judge_session(cands, sess, n_reg)
        roles = {c[0]: role_of(c[0], c[3]) for c in cands}
        rows.append({"session": str(lab), "n": int(len(idx)), "kept_stage_without_it": core["kept_stage"],
                     "alpha_per_k": alpha, "roles": roles,
                     "by_poses": {str(n): r for n, r in res.items()}})
    return decide(rows, n_reg)


def role_mean(row, n, role) -> float | None:
    """A role's figure in one held-out session at n poses: the mean over its candidates (None: not a candidate)."""
    v = [m for name, m in row["by_poses"][str(n)]["meas"].items() if row["roles"][name] == role]
    return float(np.mean(v)) if v else None


def decide(rows, n_reg) -> dict:
    n_dec = max([n for n in n_reg if n <= TRANSFER_DECIDE_POSES] or [min(n_reg)])
    summary = {}
    for n in n_reg:
        summary[str(n)] = {r: _mean([role_mean(w, n, r) for w in rows]) for r in ROLES}
        summary[str(n)]["register ships"] = float(np.mean([w["by_poses"][str(n)]["shipped_mm"] for w in rows]))
    carried, why = {}, {}
    for role, base in BASE_OF.items():
        pairs = [(role_mean(w, n_dec, role), role_mean(w, n_dec, base) if role_mean(w, n_dec, base) is not None
                  else role_mean(w, n_dec, "plain")) for w in rows]
        pairs = [(a, b) for a, b in pairs if a is not None]
        if not pairs:
            carried[role], why[role] = None, "not a candidate in any held-out session"
            continue
        a, b = np.mean(pairs, axis=0)
        wins = sum(x < y for x, y in pairs)
        carried[role] = bool(a < b)
        why[role] = (f"held-out sessions re-registered on {n_dec} poses: {role} {a:.4f} vs {base} {b:.4f} mm mean over "
                     f"{len(pairs)} session(s), lower in {wins}: " + ("carried to other sessions" if a < b else
                                                                     "it helps inside its sessions only: not carried"))
    return {"sessions": rows, "summary_by_poses": summary, "decide_poses": n_dec, "carried": carried, "why": why,
            "residual_kind": "measured residual (measured − model) on each held-out session's poses after its first "
                             "N, the frame registered on those N; mean position norm, mm"}


def _mean(v):
    v = [x for x in v if x is not None]
    return float(np.mean(v)) if v else None


def session_document(chain, fit, core, rows, settings, say) -> dict:
    """``model.json`` key ``across_sessions`` of a calibration on poses from several sessions: the sessions'
    frames (``rows`` of :func:`errormap.arm_sessions.align_sessions`), the blocked CV over them
    (:func:`across_sessions`) and the temperature term fitted on every fit pose (where the sessions' temperatures
    span :data:`THERMAL_MIN_SPAN_C`)."""
    out = across_sessions(chain, fit, learned=settings.learned, k_folds=settings.k_folds,
                          n_restarts=settings.n_restarts, seed=settings.seed, say=say)
    out["frames"] = rows
    temps = session_temperatures(fit)
    for r in rows:
        sel = fit.session == r["session"] if temps is not None else None
        r["temp_c"] = None if sel is None or not sel.any() else float(temps[sel][0])
    t_ref = thermal_reference(fit)
    out["temperature_term"] = None
    if t_ref is not None:
        geo = core["geometric_model"]
        alpha = fit_expansion(geo.chain, geo.params, fit, fit.xyz_mm - geo.predict(fit.q), t_ref)
        out["temperature_term"] = {"alpha_per_k": alpha, "t_ref_c": t_ref, "on": "every translation of the chain "
                                   "after its base (links, tool) scaled by 1 + alpha (T_session − t_ref)"}
    return out
