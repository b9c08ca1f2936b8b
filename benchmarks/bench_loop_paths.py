"""Benchmark: the grinder's closed loop (``volcomp diagnose`` today) beside the chain loop run on the
grinder's chain, on the SAME files.

Per case (truth family, seed, effect of :data:`loop_cases.EXPECTED`), :func:`loop_cases.run_case` runs the
user's CLI path (sweeps 2 μm, 21 stations → simulate 800 checks at 1 μm → identify → diagnose, 60/40 by seq);
then, on the same ``sim/checks.csv`` and identified ``el.json``, the chain loop
(:func:`compensation.app.workflows.measurement.diagnose_chain`, parametric stages only: the grinder's learned
stage declines on these cases) on :func:`errormap.grinder_file.machine_tool_of` of the built-in grinder.
The chain loop reads a chain covariance file: the grinder's identified covariance re-keyed (same element
names and stations; the smoother's ``prior_extra`` added on the diagonal with ``--prior-extra``, as the
grinder's update adds it). The truth is used only to score:

* held-out MEASURED RMS (vector norm, last 40 % of the checks) of the identified and the kept stage, and its
  ratio to the noise floor each loop reports (√3·σ̂, σ̂ estimated from the checks by each loop);
* the effects named (kind and axis);
* TRUE RMS ‖Δe‖ of the updated geometry (``updated_elements.json``) over 5,000 random points (loop_cases'
  probe points), beside the identified geometry's (the plain baseline: no update); for the chain loop also
  its kept stage re-estimated on ALL checks (the loop's ``refit``; the grinder's loop ships that re-estimate,
  the chain's ``diagnose_chain`` ships the fit-part estimate unless its learned stage is kept).

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_loop_paths.py --seeds 0 1 --effect none pitch thermal``
(about 2 CPU min a case on a loaded 2-core machine); prints one JSON row per case and a Markdown table.
"""
from __future__ import annotations

import os

if __name__ == "__main__":
    for _k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_k, "1")

import argparse
import contextlib
import io
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))


def chain_covariance(el_path: Path, out_path: Path, prior_extra: bool) -> None:
    """Write the grinder's identified covariance (beside ``el_path``) as a chain covariance file: the
    same parameters, keyed by (slot, station) as :func:`errormap.identification.load_covariance` reads."""
    from errormap.elements import ElementSet
    from errormap.identification import COV_FORMAT
    from errormap.uncertainty import ElementCovariance, covariance_path, theta_layout
    el = ElementSet.load(el_path)
    gc = ElementCovariance.load(covariance_path(el_path), el)
    lay = theta_layout(el)
    with open(out_path, "wb") as fh:
        np.savez(fh, format=np.array(COV_FORMAT), slot=np.array([k for k, _ in lay]),
                 station=np.array([i for _, i in lay]), cov=gc.prior_cov() if prior_extra else gc.cov)


def refit_all_checks(el_path: Path, checks_path: Path, mt, P, truth_e) -> float:
    """TRUE RMS ‖Δe‖ (μm) at ``P`` (n, 3) of the chain loop's kept stage re-estimated on ALL checks (fit and
    held-out; the loop's own ``refit``, as the grinder's loop ships its model), against ``truth_e`` (n, 3) μm."""
    from compensation.app.workflows.measurement import load_chain_model
    from errormap.diagnosis.chain_loop import closed_loop_chain, load_mt_checks
    from errormap.chain_field import ChainField
    el, cov, _ = load_chain_model(el_path, mt)
    checks = load_mt_checks(checks_path, mt)
    s = closed_loop_chain(mt, el, checks, cov=cov)
    refit = s["_models"]["refit"]
    if refit is None:   # the identified stage kept: nothing re-estimated
        return float("nan")
    terms = s["_models"]["terms"] if s["kept_stage"].endswith("plus_effects") else []
    el_all, _, _ = refit(terms, np.zeros_like(checks.measured_um), np.arange(len(checks)))
    e = ChainField(mt, el_all).predict(P) - truth_e
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def chain_loop(prior_extra: bool):
    """The ``also`` scorer of :func:`loop_cases.run_case`: the chain loop on the case's files."""
    def score(td: Path, m, truth, probe_ss) -> dict:
        import shutil
        from compensation.app.workflows.measurement import diagnose_chain
        from errormap.grinder_file import machine_tool_of
        from errormap.htm import HTMField
        from errormap.chain_elements import ChainElementSet
        from errormap.chain_field import ChainField
        from errormap.simulator import random_axes
        from loop_cases import N_PROBE
        mt = machine_tool_of(m)
        (td / "ch").mkdir()
        shutil.copy(td / "el.json", td / "ch" / "el.json")
        chain_covariance(td / "el.json", td / "ch" / "el.cov.npz", prior_extra)
        t0 = time.process_time()
        with contextlib.redirect_stderr(io.StringIO()):
            s, _ = diagnose_chain(td / "sim" / "checks.csv", mt, td / "ch" / "el.json", td / "cdiag", learn=False)
        cpu = time.process_time() - t0
        P = random_axes(m, N_PROBE, np.random.default_rng(probe_ss))
        truth_e = HTMField(m, truth.elements).predict(P)
        e_up = ChainField(mt, ChainElementSet.load(td / "cdiag" / "updated_elements.json", mt)).predict(P) - truth_e
        all_rms = refit_all_checks(td / "ch" / "el.json", td / "sim" / "checks.csv", mt, P, truth_e)
        st = s["stages"]
        return {"updated_geometry_all_checks_rms_um": all_rms,
                "held_identified_um": st["identified"]["held_out"]["rms_um"], "held_final_um": s["held_out_rms_um"],
                "over_floor": s.get("held_out_over_floor"), "kept_stage": s["kept_stage"],
                "effects": [f"{e['kind']} {e['axis']}" for e in s["effects"]],
                "updated_geometry_rms_um": float(np.sqrt(np.mean(np.sum(e_up**2, axis=1)))),
                "verdict": s["verdict"]["status"], "cpu_s": cpu}
    return score


def table(rows: list) -> list[str]:
    """Markdown lines: one row per case, grinder loop → chain loop."""
    out = ["| case | identified geometry TRUE RMS (μm) | updated geometry TRUE RMS grinder / chain (μm) "
           "| chain re-estimated on all checks (μm) | held-out identified (μm) | held-out final grinder / chain (μm) | final / floor grinder / chain "
           "| effects grinder / chain |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        c = r["also"]
        out.append(f"| {r['family']} s{r['seed']} {r['effect']} | {r['sweeps_rms_um']:.2f} "
                   f"| {r['updated_geometry_rms_um']:.2f} / {c['updated_geometry_rms_um']:.2f} "
                   f"| {c['updated_geometry_all_checks_rms_um']:.2f} | {r['held_identified_um']:.2f} | {r['held_final_um']:.2f} / {c['held_final_um']:.2f} "
                   f"| {r['held_final_over_floor']:.2f} / {c['over_floor']:.2f} "
                   f"| {', '.join(r['effects']) or 'none'} / {', '.join(c['effects']) or 'none'} |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--family", default="independent")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--effect", nargs="+", default=["none", "pitch", "thermal"])
    ap.add_argument("--prior-extra", action="store_true", help="add the smoother's prior_extra to the chain covariance")
    a = ap.parse_args(argv)
    from loop_cases import run_case
    rows = []
    for seed in a.seeds:
        for eff in a.effect:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                r = run_case(a.family, seed, eff, also=chain_loop(a.prior_extra))
            rows.append(r)
            print(json.dumps(r, default=str), flush=True)
    print("\n".join(table(rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
