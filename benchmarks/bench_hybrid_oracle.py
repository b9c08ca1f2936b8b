"""How much of the learned stage's error is the checks' noise, and how much its form?

A diagnostic, judged against the hidden truth and used for no choice. Per case and seed (default family,
800 checks at 1 μm, the seeds and streams of :mod:`benchmarks.suite.hybrid`, so draw 0 of the results
table) the user's path runs (sweeps → simulate → identify → diagnose); then, over the 2,000 volume points
of the results table at the reference conditions, the MODEL error ``|truth − model|`` (μm RMS of the
vector; the compensated residual's first-order equal) of:

* ``loop``: the loop alone without its condition terms (its static part; the learned stage replaced the
  terms on these machines) — what the learned part must take up;
* ``shipped``: the diagnosed ``model.json`` (the family the blocked CV chose, refitted on all checks);
* ``gp measured``: the ``gp`` family (ARD squared exponential) fitted by :class:`training.residual.ResidualRegressor`
  on the static loop's MEASURED residual at all 800 checks (what the stage fits);
* ``gp noise-free``: the same fit on the TRUE static residual at the same checks (the measurement noise
  removed; an oracle, the truth used): what the learner's form can reach with these points and no noise;
* ``element GP``: a Gaussian process whose output is the machine's own error Jacobian times a field of
  element corrections, ``r(p) = Σ_k J_k(p)·g_k(p)``, every ``g_k`` a zero-mean squared-exponential field of
  the axes features (one set of length scales) with its own variance (automatic relevance over the 23
  elements), by maximum marginal likelihood on the measured residual (:func:`element_gp_fit`); a
  candidate form, not in the product (its fit costs minutes on 800 checks).

'no effect' is the same seed's machine without the effect through the same path (its shipped model).
Writes ``hybrid_oracle_results.json`` and ``hybrid_oracle_results.md``; ``--report-only`` rebuilds the
Markdown. Run: ``python benchmarks/bench_hybrid_oracle.py --cases none,bump,a_tilt,a_lobe_x --seeds 3``.
"""
from __future__ import annotations

import os

if __name__ == "__main__":
    for _k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_k, "1")

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import minimize

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
RESULTS_JSON = HERE / "hybrid_oracle_results.json"
RESULTS_MD = HERE / "hybrid_oracle_results.md"

ELEMENT_GP_MAXITER = 150
"""L-BFGS-B iterations of the element GP's marginal likelihood (it stopped before this on every run)."""


def _rms(r) -> float:
    return float(np.sqrt(np.mean(np.sum(np.asarray(r) ** 2, axis=1))))


def _sq_by_dim(X1, X2, ell):
    """(n1, n2, d) squared differences over ell² per input."""
    return ((X1[:, None, :] - X2[None, :, :]) / ell) ** 2


def _element_gp_nll(theta, X, J, y):
    """Negative log marginal likelihood and its gradient; θ = (log ℓ (d), log s_k² (E), log σ²)."""
    n, d = X.shape
    E = J.shape[2]
    ell, s2, sn2 = np.exp(theta[:d]), np.exp(theta[d:d + E]), np.exp(theta[-1])
    D = _sq_by_dim(X, X, ell)
    k = np.exp(-0.5 * D.sum(-1))
    A = (J * np.sqrt(s2)).reshape(3 * n, E)
    M = A @ A.T
    K3 = np.kron(k, np.ones((3, 3)))
    K = M * K3 + sn2 * np.eye(3 * n)
    try:
        c = cho_factor(K, lower=True)
    except np.linalg.LinAlgError:
        return 1e10, np.zeros_like(theta)
    yv = y.reshape(-1)
    al = cho_solve(c, yv)
    f = 0.5 * yv @ al + np.log(np.diag(c[0])).sum()
    W = cho_solve(c, np.eye(3 * n)) - np.outer(al, al)
    g = np.zeros_like(theta)
    Jr = J.reshape(3 * n, E)
    g[d:d + E] = 0.5 * np.einsum("ie,ij,je->e", Jr, W * K3, Jr) * s2
    WMK = W * M * K3
    for j in range(d):
        g[j] = 0.5 * np.sum(WMK * np.kron(D[:, :, j], np.ones((3, 3))))
    g[-1] = 0.5 * np.trace(W) * sn2
    return f, g


def element_gp_fit(F, J, y):
    """F (n, d) features, J (n, 3, E) error Jacobian (columns scaled to unit RMS), y (n, 3) μm → θ, the
    optimiser's result. Features standardised by the caller."""
    n, d = F.shape
    E = J.shape[2]
    v = float(np.mean(y ** 2))
    t0 = np.r_[np.zeros(d), np.full(E, np.log(v / E)), np.log(0.5 * v)]
    b = ([(np.log(0.05), np.log(5.0))] * d + [(np.log(1e-6 * v), np.log(10 * v))] * E
         + [(np.log(1e-4 * v), np.log(10 * v))])
    r = minimize(_element_gp_nll, t0, args=(F, J, y), jac=True, method="L-BFGS-B", bounds=b,
                 options={"maxiter": ELEMENT_GP_MAXITER})
    return r.x, r


def _element_cov(F1, J1, F2, J2, ell, s2):
    """(3·n1, 3·n2) covariance of the element GP's outputs: ``Σ_k s_k² J_k(a) J_k(b)ᵀ k(a, b)`` per pair of points."""
    A1 = (J1 * np.sqrt(s2)).reshape(3 * len(F1), -1)
    A2 = (J2 * np.sqrt(s2)).reshape(3 * len(F2), -1)
    return (A1 @ A2.T) * np.kron(np.exp(-0.5 * _sq_by_dim(F1, F2, ell).sum(-1)), np.ones((3, 3)))


def element_gp_predict(theta, F, J, y, Fs, Js):
    """The posterior mean (m, 3) at ``Fs`` (m, d), ``Js`` (m, 3, E) of the element GP fitted on (F, J, y)."""
    n, d = F.shape
    E = J.shape[2]
    ell, s2, sn2 = np.exp(theta[:d]), np.exp(theta[d:d + E]), np.exp(theta[-1])
    K = _element_cov(F, J, F, J, ell, s2) + sn2 * np.eye(3 * n)
    al = cho_solve(cho_factor(K, lower=True), y.reshape(-1))
    return (_element_cov(Fs, Js, F, J, ell, s2) @ al).reshape(-1, 3)


def run_case(case: str, seed: int, element_gp: bool = True, family: str = "default") -> dict:
    from benchmarks.suite.hybrid import EDGE_MM, N_VOLUME, user_path
    from compensation.app.cli import main
    from compensation.model_file import load_diagnosed_model, loop_alone_model
    from compensation.hybrid import CV_BLOCKS, axis_features, input_set_groups
    from errormap.chain_kernel import error_jacobian
    from errormap.elements import ELEMENT_NAMES
    from errormap.io import read_table
    from errormap.machine import load_machine
    from errormap.seeds import spawn_seeds
    from errormap.simulator import random_axes
    from errormap.truth_families import make_truth
    from training.residual import ResidualRegressor
    t_cpu = time.process_time()
    eff = [] if case == "none" else [case]
    m = load_machine()
    noise_ss, probe_ss = spawn_seeds(seed, 2)   # the streams of benchmarks.suite.hybrid.run_case
    truth = make_truth(m, seed, effects=eff, family=family)
    row = {"family": family, "case": case, "seed": seed}
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        user_path(main, td, family, seed, eff, noise_ss)
        model = json.loads((td / "diag" / "model.json").read_text())
        static = loop_alone_model(model)   # the loop alone (its own base where backfitted), static terms only
        static["terms"] = [e for e in static["terms"] if not e.get("needs")]
        static["needs"] = []
        (td / "diag" / "static.json").write_text(json.dumps(static))
        f_static = load_diagnosed_model(td / "diag" / "static.json", m)
        f_ship = load_diagnosed_model(td / "diag" / "model.json", m)
        t = read_table(td / "sim" / "checks.csv")
        lr = json.loads((td / "diag" / "diagnosis.json").read_text()).get("learned_residual", {})
    A = np.stack([t.float(k) for k in ("x_mm", "z_mm", "a_deg")], axis=1)
    cond = {k: t.float(k) for k in ("temp_c", "dir_x", "dir_z", "dir_a")}
    meas = np.stack([t.float(k) for k in ("dx_um", "dy_um", "dz_um")], axis=1)
    p_chk = f_static.predict(A, **cond, time_s=t.float("time_s"))
    y_meas, y_true = meas - p_chk, truth.spatial_error(A, **cond) - p_chk
    P = random_axes(m, N_VOLUME, np.random.default_rng(probe_ss))
    for k, name in ((0, "x_mm"), (1, "z_mm")):
        lo, hi = m.strokes[name]
        P[:, k] = lo + EDGE_MM + (P[:, k] - lo) * (hi - lo - 2 * EDGE_MM) / (hi - lo)
    rc = truth.default_conditions(N_VOLUME)
    prc = dict(rc, time_s=np.zeros(N_VOLUME))
    e_vol = truth.spatial_error(P, **rc)
    left = e_vol - f_static.predict(P, **prc)
    row.update({"loop_static_um": _rms(left), "shipped_um": _rms(e_vol - f_ship.predict(P, **prc)),
                "shipped_family": lr.get("family") if lr.get("kept") else "none",
                "noise_at_checks_um": _rms(meas - truth.spatial_error(A, **cond))})
    n = len(A)
    Fc, Fv = axis_features(A)[0], axis_features(P)[0]
    groups = np.repeat(np.arange(CV_BLOCKS), int(np.ceil(n / CV_BLOCKS)))[:n]

    def gp(F, y, g):
        """The gp family fitted on (F, y) with blocked folds ``g``; the form's reach, declined or not: where the CV
        declines it, the family refitted on every row."""
        reg = ResidualRegressor(families=("gp",), seed=seed, input_groups=input_set_groups("axes")).fit(F, y, groups=g)
        return reg if reg.chosen_ != "none" else reg.refit(F, y, family="gp")

    fits = {"gp_measured": gp(Fc, y_meas, groups), "gp_noise_free": gp(Fc, y_true, groups)}
    for label, reg in fits.items():
        row[f"{label}_um"] = _rms(left - reg.predict(Fv))
    # the out-of-fold gain: would scaling the gp's prediction help? Per output component, the least-squares
    # gain of the measured residual on the gp's blocked out-of-fold prediction (hyper-parameters re-estimated
    # per fold), and the TRUE model error with the prediction so scaled (fitted on all checks as above)
    oof = np.zeros_like(y_meas)
    for b in range(CV_BLOCKS):
        tr, te = groups != b, groups == b
        oof[te] = gp(Fc[tr], y_meas[tr], groups[tr]).predict(Fc[te])
    den = np.sum(oof * oof, axis=0)
    gain = np.where(den > 0, np.sum(oof * y_meas, axis=0) / np.where(den > 0, den, 1.0), 0.0)
    gcomp = np.sqrt(np.mean(y_meas ** 2, axis=0))   # the components' size, to name the one that carries the residual
    row.update({"oof_gain": gain.tolist(), "residual_rms_by_component_um": gcomp.tolist(),
                "gp_measured_gained_um": _rms(left - fits["gp_measured"].predict(Fv) * gain)})
    if case != "none" and element_gp:
        mu, sd = Fc.mean(0), Fc.std(0)
        J, Jv = error_jacobian(m, A), error_jacobian(m, P)
        scale = np.sqrt(np.mean(np.sum(J ** 2, axis=1), axis=0))
        scale[scale == 0] = 1.0
        t0 = time.process_time()
        th, res = element_gp_fit((Fc - mu) / sd, J / scale, y_meas)
        pv = element_gp_predict(th, (Fc - mu) / sd, J / scale, y_meas, (Fv - mu) / sd, Jv / scale)
        s = np.sqrt(np.exp(th[Fc.shape[1]:Fc.shape[1] + J.shape[2]]))   # θ = (log ℓ (d), log s_k² (E), log σ²)
        top = np.argsort(-s)[:3]
        row.update({"element_gp_um": _rms(left - pv), "element_gp_cpu_s": time.process_time() - t0,
                    "element_gp_iterations": int(res.nit),
                    "element_gp_top": [[ELEMENT_NAMES[i], float(s[i] / s.max())] for i in top]})
    row["cpu_s"] = time.process_time() - t_cpu
    return row


def _load() -> tuple:
    """(rows, commands) of the results file (empty where there is none)."""
    doc = json.loads(RESULTS_JSON.read_text()) if RESULTS_JSON.is_file() else {}
    return doc.get("rows", []), doc.get("commands", [])


GAIN_SHOWN_MAX = 10.0
"""An out-of-fold gain beyond ±10 is shown as '≈0': the gp's out-of-fold prediction of that component is nearly
zero (the gain divides by its square), so the gain says nothing there."""


def _gain_text(g: float) -> str:
    return "≈0" if abs(g) > GAIN_SHOWN_MAX else f"{g:.2f}"


def write_report(rows, commands) -> None:
    fam = (lambda r: r.get("family", "default"))
    key = (lambda r: (fam(r), r["seed"]))
    none = {key(r): r["shipped_um"] for r in rows if r["case"] == "none"}
    none_nf = {key(r): r["gp_noise_free_um"] for r in rows if r["case"] == "none"}
    lines = ["# What limits the learned stage: the checks' noise or its form?", "",
             "Generated by " + "; ".join(f"`python benchmarks/bench_hybrid_oracle.py {c}`" for c in commands)
             + " (module doc: the method; a row's element-GP figures come from the last run without "
             "`--no-element-gp`). "
             "Default truth family unless the row says otherwise, 800 checks at 1 μm, the results table's seeds and streams (draw 0). MODEL error over "
             "the 2,000 volume points against the hidden TRUTH, μm RMS of the vector (a diagnostic: the truth "
             "is used, for no choice). '/ n' = divided by the same seed's no-effect machine's shipped model "
             "(its floor). 'noise-free' fits the same family to the TRUE residual at the same checks (an oracle); "
             "'nf / nf n' divides it by the same oracle on the no-effect machine (where it also learns part of the "
             "floor, which the measured fit cannot). 'out-of-fold gain': per component, the least-squares gain of the "
             "measured residual on the gp's blocked out-of-fold prediction ('≈0': that prediction is nearly zero); "
             "'× gain': the gp's TRUE model error with its prediction so scaled.",
             "", f"Machine: {platform.machine()}, Python {platform.python_version()}.", "",
             "| truth family | case | seed | loop alone (static) | shipped (family) | gp on measured | gp noise-free (oracle) | element GP on measured (top elements, relative s) | shipped / n | gp measured / n | gp noise-free / n | gp nf / nf n | element GP / n | out-of-fold gain per component (dx, dy, dz) | gp measured × gain | CPU s of the last run (the element GP fit) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (fam(r), r["case"] != "none", r["case"], r["seed"])):
        n = none.get(key(r))
        q = (lambda v: "—" if (v is None or n is None) else f"{v / n:.2f}")
        eg = r.get("element_gp_um")
        top = ", ".join(f"{a} {b:.2f}" for a, b in r.get("element_gp_top", []))
        lines.append(f"| {fam(r)} | {r['case']} | {r['seed']} | {r['loop_static_um']:.3f} | {r['shipped_um']:.3f} ({r['shipped_family']}) | "
                     f"{r['gp_measured_um']:.3f} | {r['gp_noise_free_um']:.3f} | "
                     + ("—" if eg is None else f"{eg:.3f} ({top})")
                     + f" | {q(r['shipped_um'])} | {q(r['gp_measured_um'])} | {q(r['gp_noise_free_um'])} | "
                     + ("—" if key(r) not in none_nf else f"{r['gp_noise_free_um'] / none_nf[key(r)]:.2f}")
                     + f" | {q(eg)} | "
                     + (", ".join(_gain_text(g) for g in r["oof_gain"]) if "oof_gain" in r else "—") + " | "
                     + (f"{r['gp_measured_gained_um']:.3f}" if "gp_measured_gained_um" in r else "—") + " | "
                     + f"{r['cpu_s']:.0f} ({r.get('element_gp_cpu_s', 0):.0f}) |")
    cases = sorted({(fam(r), r["case"]) for r in rows if r["case"] != "none"})
    lines += ["", "Medians over the seeds of the ratios to the no-effect floor:", "",
              "| truth family | case | seeds | shipped / n | gp measured / n | gp noise-free / n | gp nf / nf n | element GP / n |",
              "|---|---|---|---|---|---|---|---|"]
    for f, c in cases:
        rs = [r for r in rows if (fam(r), r["case"]) == (f, c) and key(r) in none]
        med = (lambda k: f"{np.median([r[k] / none[key(r)] for r in rs]):.2f}" if rs and all(k in r for r in rs) else "—")
        nf = f"{np.median([r['gp_noise_free_um'] / none_nf[key(r)] for r in rs]):.2f}" if rs else "—"
        lines.append(f"| {f} | {c} | {len(rs)} | {med('shipped_um')} | {med('gp_measured_um')} | {med('gp_noise_free_um')} | "
                     f"{nf} | {med('element_gp_um')} |")
    tmp = RESULTS_MD.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(RESULTS_MD)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="none,bump,a_tilt,a_lobe_x")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seed-start", type=int, default=0)
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--family", default="default", choices=("default", "independent"), help="the truth family")
    ap.add_argument("--no-element-gp", action="store_true",
                    help="skip the element GP (minutes per run); a row's earlier element-GP figures are kept")
    args = ap.parse_args(argv)
    argv = sys.argv[1:] if argv is None else list(argv)
    rows, commands = _load()
    if not args.report_only and " ".join(argv) not in commands:
        commands.append(" ".join(argv))
    if not args.report_only:
        for case in args.cases.split(","):
            for seed in range(args.seed_start, args.seed_start + args.seeds):
                row = run_case(case, seed, element_gp=not args.no_element_gp, family=args.family)
                same = (lambda r: (r.get("family", "default"), r["case"], r["seed"]) == (args.family, case, seed))
                old = [r for r in rows if same(r)]
                if args.no_element_gp and old:
                    row = {**{k: v for k, v in old[0].items() if k.startswith("element_gp")}, **row}
                rows = [r for r in rows if not same(r)] + [row]
                tmp = RESULTS_JSON.with_suffix(".json.tmp")
                tmp.write_text(json.dumps({"commands": commands, "rows": rows}, indent=1))
                tmp.replace(RESULTS_JSON)
                print(f"{case} seed {seed}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()
                                                           if isinstance(v, float)), flush=True)
    write_report(rows, commands)


if __name__ == "__main__":
    main()
