"""Benchmark of the learned-residual stage in the CHAIN machines' closed loop (mill-xyz, five-axis-ac).

Per machine, seed and case, the user's path: the simulated machine writes its tracker sweeps (2 μm,
seeded unknown tracker pose) and 800 check measurements (1 μm) — both through the library functions
``volcomp sweeps`` / ``simulate --machine`` use (:func:`errormap.chain_sweeps.simulate_mt_sweeps`,
:meth:`errormap.chain_truth.MTTruth.check_measurements`), because the out-of-catalogue effects below are
not among ``simulate``'s ``--effect`` kinds — then ``volcomp identify --machine`` →
``volcomp diagnose --machine --noise-um 1`` (60/40 blocked split by seq; the learned stage on, its default
families) → ``volcomp compensate VOLUME.csv --machine --model DIR/model.json --method exact`` on
:data:`N_VOLUME` random points of the volume (linear axes :data:`EDGE_FRAC` inside their strokes, rotary
axes uniform over theirs, kept as programmed by the chain solver), scored by the TRUE residual on the
hidden truth (the truth machine driven with the compensated commands, minus the target; the truth is read
only here). The same ``model.json`` without its learned keys (``learned_residual``, …; the terms it
replaced restored) is the loop alone, compensated and scored the same way.

Cases (truth of the INDEPENDENT family, the one bench_mt_loop uses), designed generically over the
machine's axis list and fixed before any run:

* ``none`` — no effect (the same seed's machine without the effect: the reference of the two others);
* ``bump`` — a local bump of the FIRST linear axis's positioning error over a region of the first two
  linear axes: ``d<a1>_<w1> += A·exp(−½((u1 − 0.6)/0.15)² − ½((u2 − 0.4)/0.15)²)``, ``u`` the position as
  a fraction of the stroke, A = :data:`BUMP_UM`. Each chain element is a profile of ONE axis, so no
  element takes it up beyond its means along each axis; no effect kind is a local function of two axes;
* ``sq_grow`` — a squareness between the first two linear axes that grows along the third (the first
  when there are only two): the second axis's straightness toward the first
  ``d<a1>_<w2> += k·(q2 − mid2)·(q3 − lo3)/Δ3`` (k = :data:`SQ_GROW_URAD` μrad at the end of the third
  axis's stroke). A squareness is a constant slot and an element a one-axis profile; the one pair kind
  (interaction) is an axis's OWN-direction error bilinear in two positions, not a straightness. Measured
  after the first seed (and then computed from the chain, :func:`span_outside`): on both chains this
  linear growth lies IN the span of the element slots (an angular error of one axis through a lever arm
  that grows with another; outside fraction ~1e-15), so the element update absorbs it — it is reported as
  such, not as an out-of-catalogue case;
* ``sq_grow_sin`` — the same squareness growing as a half sine along the third axis,
  ``k·(q2 − mid2)·sin(π·u3)`` (k = :data:`SQ_GROW_URAD` μrad at mid-stroke of the third axis): a lever arm is
  affine in the positions, so no angular error takes up a sine of the third axis's position; decided by the
  span test (0.39 of its norm outside the slots' span on both chains, the bump 0.40–0.42), before any run
  of it.

Figures per row: TRUE RMS / max of the compensated volume with the hybrid (the kept stage) and with the
loop alone; held-out MEASURED RMS of the kept stage and of the loop's stage, beside the noise floor
√3·σ (σ = 1 μm, given); whether the learned stage was kept, its paired z, family, its band's held-out
coverage; the exact solver's MODEL residual max on the hybrid (as ``compensate`` reports it); on the
first seed with a kept stage per machine also ``batched-ga`` on :data:`N_GA` of the points.

Writes ``benchmarks/hybrid_chain_results.md`` and ``hybrid_chain_results.json`` (rows merged by machine,
seed, case). Run (one job, ``nice -n 10``): ``python benchmarks/bench_hybrid_chain.py --seeds 5``.
"""
from __future__ import annotations

import os

if __name__ == "__main__":
    for _k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_k, "1")

import argparse
import contextlib
import dataclasses
import io
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS_JSON = HERE / "hybrid_chain_results.json"
RESULTS_MD = HERE / "hybrid_chain_results.md"
MACHINES = ("mill-xyz", "five-axis-ac")
CASES = ("none", "bump", "sq_grow_sin", "sq_grow")
FAMILY = "independent"
N_CHECKS = 800
CHECK_NOISE_UM = 1.0
SWEEP_NOISE_UM = 2.0
FLOOR_UM = float(np.sqrt(3.0) * CHECK_NOISE_UM)
N_VOLUME = 2000
EDGE_FRAC = 0.01
"""Volume points lie 1 % of each linear stroke inside it: a correction of up to ~0.1 mm keeps the
commands in the strokes and in the checks' box (800 uniform checks reach within ~0.1 % of each end)."""
BUMP_UM = 6.0
BUMP_CENTRE = (0.6, 0.4)
BUMP_WIDTH = 0.15
SQ_GROW_URAD = 25.0
N_GA = 50
LEARNED_KEYS = ("learned_residual", "base_stage", "learned_family", "base_terms_replaced", "loop_alone")


def ooc_truth(machine, seed: int, case: str):
    """The seeded truth of :data:`FAMILY` with the out-of-catalogue effect ``case`` (module doc) added to its
    element values (so the sweeps and the checks both see it)."""
    from errormap.chain_truth import MTTruth, make_mt_truth
    base = make_mt_truth(machine, seed, family=FAMILY)
    if case == "none":
        return base
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    j1, j2 = lin[0], lin[1]
    j3 = lin[2] if len(lin) > 2 else lin[0]
    a1, a2 = machine.axes[j1], machine.axes[j2]
    idx = {n: k for k, n in enumerate(machine.slot_names)}

    @dataclasses.dataclass
    class OOCTruth(MTTruth):
        def element_values(self, axes, **conditions):
            axes = np.atleast_2d(np.asarray(axes, dtype=float))
            v = super().element_values(axes, **conditions)
            lo, hi = machine.stroke_lo, machine.stroke_hi
            u = (axes - lo) / (hi - lo)
            if case == "bump":
                g = BUMP_UM * np.exp(-0.5 * ((u[:, j1] - BUMP_CENTRE[0]) / BUMP_WIDTH) ** 2
                                     - 0.5 * ((u[:, j2] - BUMP_CENTRE[1]) / BUMP_WIDTH) ** 2)
                v[:, idx[f"d{'xyz'[a1.along]}_{a1.word.lower()}"]] += g
            elif case in ("sq_grow", "sq_grow_sin"):
                mid2 = 0.5 * (lo[j2] + hi[j2])
                grow = u[:, j3] if case == "sq_grow" else np.sin(np.pi * u[:, j3])
                v[:, idx[f"d{'xyz'[a1.along]}_{a2.word.lower()}"]] += SQ_GROW_URAD * 1e-3 * (axes[:, j2] - mid2) * grow
            else:
                raise ValueError(f"unknown case {case!r}")
            return v

    return OOCTruth(machine, base.elements, dict(base.effects), seed, FAMILY)


def span_outside(machine_name: str, case: str, n: int = 1500, seed: int = 0) -> float:
    """The fraction of the case's error columns outside the span of the element slots' Jacobian at nominal
    elements over ``n`` uniform points (:class:`errormap.diagnosis.chain_loop.SlotSpan`, the loop's own
    representability test): ~0 — the element update absorbs the effect; ≥ 0.2 — out of the catalogue."""
    from errormap.diagnosis.chain_loop import SlotSpan
    from errormap.machine import load_machine
    from errormap.chain_elements import ChainElementSet
    m = load_machine(machine_name)
    el = ChainElementSet.zeros(m)
    q = m.stroke_lo + (m.stroke_hi - m.stroke_lo) * np.random.default_rng(seed).random((n, len(m.axes)))
    t = ooc_truth(m, 0, case)
    dv = t.element_values(q) - ooc_truth(m, 0, "none").element_values(q)   # (n, P): the effect on the elements
    C = np.einsum("nip,np->ni", m.error_jacobian(q), dv)[:, :, None]
    return float(SlotSpan.of(el, q).outside(C).max())


def _stats(r) -> dict:
    n = np.linalg.norm(r, axis=1)
    return {"rms_um": float(np.sqrt(np.mean(n ** 2))), "max_um": float(n.max())}


def _volume(machine, rng):
    lo, hi = machine.stroke_lo.copy(), machine.stroke_hi.copy()
    for j, a in enumerate(machine.axes):
        if a.kind == "linear":
            e = EDGE_FRAC * (hi[j] - lo[j])
            lo[j], hi[j] = lo[j] + e, hi[j] - e
    return lo + (hi - lo) * rng.random((N_VOLUME, len(lo)))


def _condition_options(model: dict) -> list:
    """``--temp-c 20`` / ``--dir-<w> 1`` for the terms the model needs (the reference conditions)."""
    out = []
    for t in model.get("terms", []):
        if t["kind"] == "thermal" and "--temp-c" not in out:
            out += ["--temp-c", "20"]
        if t["kind"] == "reversal":
            opt = f"--dir-{t['axis'].lower()}"
            if opt not in out:
                out += [opt, "1"]
    return out


def _compensate(main, machine, d, model_path, label, truth_ref, P, method="exact", n=None):
    from compensation.app.workflows.compensate_report import true_residual_um
    from compensation.solvers.chain_exact import nominal_and_jacobian
    from errormap.io import read_table, write_csv
    n = len(P) if n is None else n
    pts = d / f"volume_{n}.csv"
    if not pts.is_file():
        write_csv(pts, dict(zip(machine.axis_columns, P[:n].T)), float_fmt="%.12g")
    od = d / f"comp_{label}"
    model = json.loads(Path(model_path).read_text())
    argv = ["compensate", str(pts), "--machine", machine.name, "--model", str(model_path), "--method", method,
            "--out", str(od), *_condition_options(model)]
    if method != "exact":
        argv += ["--seed", "0"]
    rc = main(argv)
    summ = json.loads((od / "compensate_summary.json").read_text())["files"][0] \
        if (od / "compensate_summary.json").is_file() else {}
    info = {k: summ.get(k) for k in ("model_max_um", "failures", "guard_violations")}
    if rc != 0:
        return dict(info, refused_exit=rc)
    t = read_table(od / pts.name)
    comp = np.stack([t.float(c) for c in machine.axis_columns], axis=1)
    targets, _ = nominal_and_jacobian(machine, P[:n])
    return dict(_stats(true_residual_um(truth_ref, machine, comp, targets)), **info)


class _AtReference:
    def __init__(self, truth):
        self.truth = truth

    def predict(self, axes):
        axes = np.atleast_2d(np.asarray(axes, float))
        return self.truth.spatial_error(axes, **self.truth.default_conditions(len(axes)))


def run_case(machine_name: str, seed: int, case: str, ga: bool = False) -> dict:
    from compensation.app.cli import main
    from errormap.io import write_csv
    from errormap.machine import load_machine
    from errormap.chain_sweeps import simulate_mt_sweeps, write_sweeps
    from errormap.seeds import spawn_seeds
    m = load_machine(machine_name)
    t_cpu = time.process_time()
    truth = ooc_truth(m, seed, case)
    check_ss = spawn_seeds(seed, 1)[0]   # simulate --machine's check seed; the sweeps' noise seed as bench_mt_loop's
    row = {"machine": machine_name, "seed": seed, "case": case}
    with tempfile.TemporaryDirectory() as td, contextlib.redirect_stdout(io.StringIO()), \
            contextlib.redirect_stderr(io.StringIO()):
        d = Path(td)
        write_sweeps(d / "sweeps.csv", simulate_mt_sweeps(truth, noise_um=SWEEP_NOISE_UM, seed=1000 + seed),
                     comments=["setup: setup-1", f"machine: {m.name}", f"machine_sha256: {m.sha256}",
                               f"noise_um: {SWEEP_NOISE_UM}", "tracker pose: seeded, unknown to the identification"])
        write_csv(d / "checks.csv", truth.check_measurements(n=N_CHECKS, noise_um=CHECK_NOISE_UM, seed=check_ss),
                  header_comments=["format: volcomp-checks/1", f"machine: {m.name}", f"machine_sha256: {m.sha256}",
                                   f"noise_um: {CHECK_NOISE_UM}"])
        assert main(["identify", str(d / "sweeps.csv"), "--machine", m.name, "--out", str(d / "E.json")]) == 0
        t0 = time.process_time()
        assert main(["diagnose", str(d / "checks.csv"), "--machine", m.name, "--model", str(d / "E.json"),
                     "--noise-um", str(CHECK_NOISE_UM), "--out", str(d / "diag")]) == 0
        row["cpu_diagnose_s"] = time.process_time() - t0
        s = json.loads((d / "diag" / "diagnosis.json").read_text())
        model = json.loads((d / "diag" / "model.json").read_text())
        alone = {k: v for k, v in model.items() if k not in LEARNED_KEYS}
        alone["kept_stage"] = model.get("base_stage", model["kept_stage"])
        own = model.get("loop_alone") or {}   # a backfitted hybrid's base is not the loop's (round 12)
        alone["elements"] = own.get("elements", model["elements"])
        alone["terms"] = own.get("terms", model["terms"]) + model.get("base_terms_replaced", [])
        (d / "diag" / "model_loop.json").write_text(json.dumps(alone))
        P = _volume(m, np.random.default_rng([seed, 2024]))
        ref = _AtReference(truth)
        row["uncompensated"] = _stats(ref.predict(P))
        row["hybrid"] = _compensate(main, m, d, d / "diag" / "model.json", "hybrid", ref, P)
        row["loop"] = _compensate(main, m, d, d / "diag" / "model_loop.json", "loop", ref, P)
        if case != "none":
            e_without = _AtReference(ooc_truth(m, seed, "none")).predict(P)
            row["effect_rms_um"] = _stats(ref.predict(P) - e_without)["rms_um"]
        if ga and "learned_residual" in model:
            row["hybrid_batched_ga"] = _compensate(main, m, d, d / "diag" / "model.json", "ga", ref, P,
                                                   method="batched-ga", n=N_GA)
    lr = s.get("learned_residual") or {}
    from compensation.hybrid import LEARNED_FAMILIES
    row.update({"learned_families": list(LEARNED_FAMILIES), "kept_stage": s["kept_stage"], "base_stage": s.get("base_stage", s["kept_stage"]),
                "learned_kept": bool(lr.get("kept")), "learned_family": lr.get("family"),
                "learned_output_frame": lr.get("output_frame", "work"),
                "output_frames_compared": lr.get("output_frames_compared", ["work"]),
                "code_round": 12, "learned_backfit_steps_um": (lr.get("backfit") or {}).get("step_rms_um"),
                "learned_z": lr.get("held_out_gain_z"), "held_band95_cover": lr.get("held_out_band95_cover"),
                "replaced_terms": [f"{e['kind']} {e['axis']}" for e in s.get("effects_replaced_by_learned", [])],
                "held_final_um": s["held_out_rms_um"], "held_loop_um": s.get("held_out_rms_base_um", s["held_out_rms_um"]),
                "noise_floor_um": s["noise_floor_um"], "effects": [f"{e['kind']} {e['axis']}" for e in s["effects"]],
                "cpu_s": time.process_time() - t_cpu})
    return row


def _load() -> list:
    return json.loads(RESULTS_JSON.read_text())["rows"] if RESULTS_JSON.is_file() else []


def _med(v):
    v = [x for x in v if x is not None]
    return float(np.median(v)) if v else None


def _fmt(v, d=2):
    return "—" if v is None else f"{v:.{d}f}"


def write_results(rows, argv) -> None:
    from errormap.io import write_json
    rows = sorted(rows, key=lambda r: (r["machine"], r["case"], r["seed"]))
    cmd = "python benchmarks/bench_hybrid_chain.py " + " ".join(argv)
    prev = json.loads(RESULTS_JSON.read_text()) if RESULTS_JSON.is_file() else {}
    commands = list(prev.get("commands", [prev["command"]] if "command" in prev else []))
    if cmd not in commands:
        commands.append(cmd)
    write_json(RESULTS_JSON, {"commands": commands, "rows": rows})
    lines = ["# The learned-residual stage in the chain machines' closed loop (mill-xyz, five-axis-ac)", "",
             f"{'; '.join(f'`{c}`' for c in commands)} on {platform.machine()} (Python "
             f"{platform.python_version()}), {time.strftime('%Y-%m-%d')}, one job, under nice. User's path only "
             "(module doc of the script): sweeps (2 μm) and 800 checks (1 μm) of a truth of the independent family "
             "with the case's effect → `volcomp identify --machine` → `volcomp diagnose --machine --noise-um 1` "
             "(60/40 blocked split by seq, the learned stage on) → `volcomp compensate --machine --model "
             "DIR/model.json --method exact` on 2,000 random volume points (linear axes 1 % inside their strokes; "
             "rotary axes kept as programmed). *TRUE* = the truth machine driven with the compensated commands minus "
             "the target (hidden truth, reference conditions); *loop alone* = the same model.json without its learned "
             "residual; *held-out* = MEASURED residual (vector norm) on the last 40 % of the checks; noise floor "
             f"√3·σ = {FLOOR_UM:.2f} μm (σ = 1 μm, given). *no effect* = the same seed's machine without the effect "
             "(its hybrid's TRUE RMS).", "",
             "Cases (designed before any run, over the machine's axis list): `bump` — a local bump "
             f"(A = {BUMP_UM:g} μm, centre {BUMP_CENTRE} of the strokes, width {BUMP_WIDTH:g}) of the first linear "
             "axis's positioning error over the first two linear axes; `sq_grow` — a squareness between the first "
             f"two linear axes that grows linearly along the third ({SQ_GROW_URAD:g} μrad at the end of its stroke), "
             "as the second axis's straightness toward the first (designed before any run; after the first seed it "
             "showed to lie in the span of the element slots — an angular error through a lever arm — so the element "
             "update absorbs it: a catalogue case, kept as such); `sq_grow_sin` — the same squareness growing as a "
             f"half sine along the third axis ({SQ_GROW_URAD:g} μrad at its mid-stroke; added after the first seed, "
             "chosen by the span test below, not by any TRUE figure); `none` — no effect. Judged per case: the "
             "hybrid's TRUE RMS against the loop alone and against the same seed's machine without the effect.", "",
             "Output frame (round 11, `compensation.hybrid.LEARNED_FRAMES`): rows that record it compared the work and "
             "the machine frame; rows before round 11 the work frame alone. On `mill-xyz`, whose work frame turns with "
             "no axis, round 11 compares the work frame alone, so its rows are what round 11 gives; on `five-axis-ac` "
             "only the rows that name their frame were measured with round 11. Round 12 (`compensation.hybrid.BACKFIT_ROUNDS`): "
             "the learned part backfitted with the element update; rows measured with it say so ('backfitted', or "
             "'round 12' where no family was chosen); the others are earlier rounds' (the learned part fitted after "
             "the update). *loop alone* reads the loop's own elements and terms (`model.json` `loop_alone`) where the "
             "hybrid's base was backfitted.", ""]
    by = {}
    for r in rows:
        by.setdefault((r["machine"], r["case"]), []).append(r)
    none_true = {(r["machine"], r["seed"]): (r.get("hybrid") or {}).get("rms_um") for r in rows if r["case"] == "none"}
    for mname in MACHINES:
        sel = [c for c in CASES if (mname, c) in by]
        if not sel:
            continue
        lines += [f"## {mname}", "",
                  "| case | seeds | effect RMS (μm) | TRUE RMS hybrid (median; per seed) | TRUE RMS loop alone (median) | "
                  "hybrid / loop (median) | TRUE RMS no effect (median) | hybrid / no effect (median, max) | "
                  "learned kept | held-out hybrid / loop (μm, median) | held-out / floor (median, max) | "
                  "band95 held-out coverage (median) | exact model residual max (μm) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c in sel:
            rs = by[(mname, c)]
            h = [(r.get("hybrid") or {}).get("rms_um") for r in rs]
            lo = [(r.get("loop") or {}).get("rms_um") for r in rs]
            ne = [none_true.get((mname, r["seed"])) for r in rs]
            ratio_l = [a / b for a, b in zip(h, lo) if a is not None and b]
            ratio_n = [a / b for a, b in zip(h, ne) if a is not None and b]
            of = [r["held_final_um"] / r["noise_floor_um"] for r in rs]
            mm = [(r.get("hybrid") or {}).get("model_max_um") for r in rs]
            refused = sum("refused_exit" in (r.get("hybrid") or {}) for r in rs)
            lines.append(
                f"| {c} | {len(rs)} | {_fmt(_med([r.get('effect_rms_um') for r in rs]))} | {_fmt(_med(h))}; "
                f"{', '.join(_fmt(x) for x in h)} | {_fmt(_med(lo))} | {_fmt(_med(ratio_l))} | {_fmt(_med(ne))} | "
                f"{_fmt(_med(ratio_n))}, {_fmt(max(ratio_n) if ratio_n else None)} | "
                f"{sum(r['learned_kept'] for r in rs)}/{len(rs)}"
                f"{f' (refused {refused})' if refused else ''} | {_fmt(_med([r['held_final_um'] for r in rs]))} / "
                f"{_fmt(_med([r['held_loop_um'] for r in rs]))} | {_fmt(_med(of))}, {_fmt(max(of))} | "
                f"{_fmt(_med([r.get('held_band95_cover') for r in rs]), 3)} | "
                f"{'—' if not [x for x in mm if x is not None] else f'{max(x for x in mm if x is not None):.1e}'} |")
        lines.append("")
        lines += ["Span test (the loop's representability test, `span_outside`: the fraction of the effect's "
                  "error columns outside the span of the element slots; ~0 = the element update absorbs it): "
                  + ", ".join(f"`{c}` {span_outside(mname, c):.2g}" for c in sel if c != "none"), ""]
        det = [r for c in sel for r in by[(mname, c)]]
        lines += ["Per run: seed, case, learned family (z), kept stage, effects the loop named, TRUE RMS hybrid / loop "
                  "(μm), CPU s:", ""]
        for r in det:
            lines.append(f"- {r['seed']} {r['case']}: {r['learned_family']} (z {_fmt(r['learned_z'])}), "
                         f"{r['kept_stage']}, effects [{', '.join(r['effects'])}]"
                         f"{', replaced ' + ', '.join(r['replaced_terms']) if r['replaced_terms'] else ''}, "
                         f"{_fmt((r.get('hybrid') or {}).get('rms_um'))} / {_fmt((r.get('loop') or {}).get('rms_um'))}, "
                         f"{r['cpu_s']:.0f} s, families compared: "
                         + ("+".join(r["learned_families"]) if r.get("learned_families") else "not recorded (the four of the time)")
                         + (f", output frame {r['learned_output_frame']} of {'+'.join(r['output_frames_compared'])}"
                            if "output_frames_compared" in r else ", output frame: work (before round 11)")
                         + ("" if r.get("code_round", 0) < 12 else
                            ", backfitted with the update (round 12)" if r.get("learned_backfit_steps_um") else
                            ", round 12 (not backfitted: no family chosen)"))
        ga = [r for r in det if "hybrid_batched_ga" in r]
        for r in ga:
            g = r["hybrid_batched_ga"]
            lines.append(f"- batched-ga on the hybrid, seed {r['seed']} {r['case']}, {N_GA} points: model residual max "
                         f"{_fmt(g.get('model_max_um'), 4)} μm, failures {g.get('failures')}, TRUE RMS "
                         f"{_fmt(g.get('rms_um'))} μm")
        lines.append("")
    from errormap.io import atomic_write
    with atomic_write(RESULTS_MD, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def main(argv=None) -> int:
    import sys
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--machine", action="append", choices=MACHINES, default=None)
    p.add_argument("--case", action="append", choices=CASES, default=None)
    a = p.parse_args(argv)
    rows = {(r["machine"], r["seed"], r["case"]): r for r in _load()}
    ga_done = set()
    for mname in a.machine or MACHINES:
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            for case in a.case or CASES:
                ga = case != "none" and mname not in ga_done
                r = run_case(mname, seed, case, ga=ga)
                if "hybrid_batched_ga" in r:
                    ga_done.add(mname)
                rows[(mname, seed, case)] = r
                print(f"{mname} seed {seed} {case}: hybrid {r['hybrid'].get('rms_um')} loop {r['loop'].get('rms_um')} "
                      f"kept {r['learned_kept']} z {r['learned_z']} cpu {r['cpu_s']:.0f}s", flush=True)
                write_results(list(rows.values()), argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
