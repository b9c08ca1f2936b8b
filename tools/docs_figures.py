"""The pictures of the explanation pages (docs/explanation/img/*.png), made from volcomp's own runs.

Every figure comes from the ``volcomp`` commands a user runs (called in-process through
``compensation.app.cli.main`` in a scratch folder, fixed seeds) and the files they write; the two diagrams
(the chain of a machine file, the layers of the code) are drawn from the machine file and the package list. Every
run is seeded (``--seed``), so the PNGs repeat byte for byte on one machine.

    python tools/docs_figures.py --thermal-log LOG.csv            # every figure (about 1 CPU minute)
    python tools/docs_figures.py --only closed-loop-stages        # one figure (the drift one needs --thermal-log)

``--thermal-log``: a drift log (``volcomp diagnose --drift`` schema) of a real machine; the drift figure is
drawn from it (it is not in the repository; the PNG is). ``FIGURES`` names every figure and the page that
shows it; ``tests/test_docs_figures.py`` checks that the pages reference exactly these images.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shlex
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMG = ROOT / "docs" / "explanation" / "img"
MAX_BYTES = 150_000
"""The largest PNG a page carries (the site stays light)."""
DPI = 90

FIGURES = {
    "chain-slots": "kinematics.md",
    "identified-element": "identification.md",
    "closed-loop-stages": "closed-loop.md",
    "learned-residual": "learned-stage.md",
    "drift-thermal-log": "drift.md",
    "solver-residuals": "solvers.md",
    "arm-held-out": "serial-arms.md",
    "hexapod-held-out": "parallel-kinematics.md",
    "layers": "architecture.md",
}
"""Figure name (``img/<name>.png``) → the explanation page that shows it."""


# -- running volcomp -------------------------------------------------------------------------------
def volcomp(line: str) -> str:
    """Run one ``volcomp ...`` line in-process; its printed text. A non-zero status stops the script (a failed
    verdict included: a figure is drawn only from a run that passed)."""
    from compensation.app.cli import main
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        status = main(shlex.split(line)[1:])
    if status not in (0, None):
        raise SystemExit(f"{line}: exit {status}\n{out.getvalue()[-2000:]}")
    return out.getvalue()


def mill_run(effect: str, folder: str) -> Path:
    """mill-xyz seed 3 with one undeclared effect: simulate, sweeps, identify, diagnose (σ 1 μm) → folder."""
    d = Path(folder)
    volcomp(f"volcomp simulate --machine mill-xyz --seed 3 --effect {effect} --out {d}/sim")
    volcomp(f"volcomp sweeps --machine mill-xyz --seed 3 --effect {effect} --out {d}/sweeps.csv")
    volcomp(f"volcomp identify {d}/sweeps.csv --machine mill-xyz --out {d}/E.json")
    volcomp(f"volcomp diagnose {d}/sim/checks.csv --model {d}/E.json --machine mill-xyz --noise-um 1 --out {d}/diag")
    return d


def _save(fig, name: str) -> Path:
    path = IMG / f"{name}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=DPI, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    os.replace(tmp, path)
    size = path.stat().st_size
    if size > MAX_BYTES:
        raise SystemExit(f"{path}: {size} bytes, more than {MAX_BYTES}")
    print(f"wrote {path.relative_to(ROOT)} ({size // 1000} kB)")
    return path


# -- the figures -----------------------------------------------------------------------------------
def chain_slots(work: Path, args) -> None:
    """mill-xyz's two chains as written, each transform a box, the error slots under each moving axis."""
    import matplotlib.pyplot as plt
    from errormap import load_machine
    from errormap.machine import builtin_machine_path
    m = load_machine(builtin_machine_path("mill-xyz"))
    fig, ax = plt.subplots(figsize=(9.5, 4.2))
    ax.set_axis_off()
    ax.set_xlim(-0.5, 5.5)
    ax.set_ylim(-3.6, 1.6)

    def label(e) -> str:
        what = m.axes[e.joint].word if e.joint is not None else f"{e.value:g}"
        return f"{'Trans' if e.kind == 't' else 'Rot'}{'xyz'[e.axis].upper()}({what})"

    for row, (side, ets) in enumerate((("work chain: base → workpiece", m.work_ets), ("tool chain: base → tool point", m.tool_ets))):
        y = 0.8 - 2.3 * row
        ax.text(-0.45, y + 0.55, side, fontsize=10, weight="bold")
        ax.text(-0.45, y, "base", fontsize=9, va="center")
        x = 0.35
        nominal = [e for e in ets if e.slot is None]
        for e in nominal:
            moving = e.joint is not None
            ax.annotate("", xy=(x - 0.05, y), xytext=(x - 0.3, y), arrowprops=dict(arrowstyle="->", color="0.4"))
            ax.text(x + 0.45, y, label(e), ha="center", va="center", fontsize=8.5,
                    bbox=dict(boxstyle="round", fc="#dbe9f6" if moving else "#eeeeee", ec="0.5"))
            if moving:
                word = m.axes[e.joint].word
                slots = m.slots_of(word)
                sq = [s.name for s in m.slots if not s.is_function and s.axis == word]
                ax.text(x + 0.45, y - 0.35, "E_" + word.lower() + ":\n" + "\n".join(
                    ", ".join(slots[i:i + 3]) for i in range(0, len(slots), 3)) + ("\n" + ", ".join(sq) if sq else ""),
                    ha="center", va="top", fontsize=7.5, color="#b03020")
            x += 1.15
        ax.text(x - 0.2, y, "workpiece" if row == 0 else "tool point", fontsize=9, va="center")
    ax.text(-0.45, -3.5, "blue: an axis' motion, followed by its error transform E = Trans(δ)·Rot(ε) (red: its slots, "
            "μm and μrad, functions of the axis; squareness constants)", fontsize=7.5, color="0.3")
    _save(fig, "chain-slots")


def identified_element(work: Path, args) -> None:
    """Two identified elements of mill-xyz (seed 3) with their 95 % band, beside the simulated truth."""
    import matplotlib.pyplot as plt
    import numpy as np
    d = mill_run("periodic:Y", str(work / "mill-periodic"))
    # the truth in the identification's frame (gauge): its noise-free sweeps identified the same way, unsmoothed
    volcomp(f"volcomp sweeps --machine mill-xyz --seed 3 --effect periodic:Y --noise-um 0 --out {d}/clean.csv")
    volcomp(f"volcomp identify {d}/clean.csv --machine mill-xyz --raw --out {d}/T.json")
    ident = json.loads((d / "E.json").read_text())
    truth = json.loads((d / "T.json").read_text())
    cov = np.load(d / "E.cov.npz")
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for ax, name in zip(axes, ("dz_x", "ez_x")):
        col = f"{name.split('_')[1]}_mm"
        s = np.asarray(ident["stations"][col])
        v = np.asarray(ident["functions"][name])
        idx = np.flatnonzero(cov["slot"] == name)
        sd = np.zeros_like(v)
        sd[cov["station"][idx]] = np.sqrt(np.diag(cov["cov"])[idx])
        t = np.asarray(truth["functions"][name])
        ts = np.asarray(truth["stations"][col])
        ax.fill_between(s, v - 1.96 * sd, v + 1.96 * sd, color="#9ecae1", label="identified ± 95 % band")
        ax.plot(s, v, "o-", color="#08519c", ms=3, label="identified")
        ax.plot(ts, t, "--", color="#b03020", label="simulated truth (noise-free sweeps, same frame)")
        unit = ident["units"][name].replace("um", "μm").replace("urad", "μrad")
        ax.set(title=f"{name} of mill-xyz", xlabel=col.replace("_mm", " (mm)"), ylabel=f"{name} ({unit})")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    _save(fig, "identified-element")


def closed_loop_stages(work: Path, args) -> None:
    """The loop's stages on mill-xyz with a pitch error on Y: held-out MEASURED RMS vs the noise floor."""
    import matplotlib.pyplot as plt
    d = work / "mill-periodic"
    if not (d / "diag" / "diagnosis.json").exists():
        mill_run("periodic:Y", str(d))
    _stage_bars(json.loads((d / "diag" / "diagnosis.json").read_text()),
                ("identified", "baseline_ols_linear", "updated", "updated_plus_effects"),
                ("identified\n(sweeps)", "plain OLS\nof the residual", "updated\nelements", "updated\n+ effects"),
                "mill-xyz, a pitch error on Y the elements lack (seed 3, 400 checks, σ 1 μm)", plt)
    _save(plt.gcf(), "closed-loop-stages")


def _stage_bars(diag: dict, stages, labels, title, plt) -> None:
    rms = [diag["stages"][s]["held_out"]["rms_um"] for s in stages]
    fig, ax = plt.subplots(figsize=(7.5, 3.4))
    colours = ["#999999" if "baseline" in s else "#3182bd" for s in stages]
    bars = ax.bar(labels, rms, color=colours)
    for b, r in zip(bars, rms):
        ax.text(b.get_x() + b.get_width() / 2, r, f"{r:.2f}", ha="center", va="bottom", fontsize=8)
    floor = diag["noise_floor_um"]
    ax.axhline(floor, color="#b03020", ls="--", label=f"noise floor √3·σ = {floor:.2f} μm")
    ax.set(ylabel="held-out MEASURED RMS (μm)", title=title)
    ax.title.set_fontsize(9)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)


def learned_residual(work: Path, args) -> None:
    """mill-xyz with a bump of X·Y no effect kind represents: the held-out residual per axis before/after."""
    import matplotlib.pyplot as plt
    import numpy as np
    d = mill_run("bump:X*Y", str(work / "mill-bump"))
    diag = json.loads((d / "diag" / "diagnosis.json").read_text())
    before, after = diag["stages"]["updated_plus_effects"]["held_out"], diag["stages"]["learned_residual"]["held_out"]
    plain = diag["stages"]["baseline_ols_linear"]["held_out"]
    cols = ("dx_um", "dy_um", "dz_um")
    x = np.arange(3)
    fig, ax = plt.subplots(figsize=(7, 3.4))
    for k, (stage, lab, c) in enumerate(((plain, "plain OLS of the residual", "#999999"),
                                         (before, "physics (updated + effects)", "#3182bd"),
                                         (after, "+ learned residual", "#31a354"))):
        ax.bar(x + (k - 1) * 0.27, [stage[c_]["rms_um"] for c_ in cols], 0.27, label=lab, color=c)
    ax.axhline(1.0, color="#b03020", ls="--", label="noise σ = 1 μm per axis")
    ax.set_xticks(x, [c.replace("_um", "") for c in cols])
    ax.set(ylabel="held-out MEASURED RMS (μm)",
           title=f"mill-xyz with a bump of X·Y (seed 3): learned family {diag['learned_residual']['family']}")
    ax.title.set_fontsize(9)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    _save(fig, "learned-residual")


def drift_thermal_log(work: Path, args) -> None:
    """A real machine's thermal log: measured displacement vs the chosen model and plain OLS over time."""
    import matplotlib.pyplot as plt
    import numpy as np
    if not args.thermal_log:
        raise SystemExit("drift-thermal-log needs --thermal-log LOG.csv (a real machine's drift log)")
    out = work / "drift"
    volcomp(f"volcomp diagnose --drift {args.thermal_log} --out {out}")
    diag = json.loads((out / "diagnosis.json").read_text())
    log = np.genfromtxt(args.thermal_log, delimiter=",", names=True)
    pred = np.genfromtxt(out / "drift_compensation.csv", delimiter=",", names=True)
    t_h = log["time_s"] / 3600
    n_fit = int(round(diag["settings"].get("fit_fraction", 0.6) * len(t_h))) if "settings" in diag else int(0.6 * len(t_h))
    temps = [n for n in log.dtype.names if n.startswith("temp_")] + [n for n in log.dtype.names if n == "speed_rpm"]
    X = np.column_stack([np.ones(len(t_h))] + [log[n] for n in temps])
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.4), sharex=True)
    for ax, ch in zip(axes, ("ch4", "ch1")):
        y = log[f"{ch}_um"]
        beta = np.linalg.lstsq(X[:n_fit], y[:n_fit], rcond=None)[0]
        c = diag["channels"][ch]
        ax.plot(t_h, y, color="0.2", lw=0.8, label="measured")
        ax.fill_between(t_h, pred[f"{ch}_lo_um"], pred[f"{ch}_hi_um"], color="#9ecae1", alpha=0.5, label="95 % band")
        ax.plot(t_h, pred[f"{ch}_pred_um"], color="#08519c", lw=1, label=f"volcomp ({c['model']})")
        ax.plot(t_h, X @ beta, color="#e6550d", lw=0.8, ls="--", label="plain OLS (all sensors)")
        ax.axvline(t_h[n_fit], color="0.5", ls=":")
        ax.set(ylabel=f"{ch} (μm)", ylim=(np.min(y) - 25, np.max(y) + 25))
        ax.set_title(f"{ch}: held-out RMS {c['rms_before_um']:.1f} μm uncompensated → {c['rms_after_um']:.1f} μm "
                     f"(OLS {c['rms_ols_um']:.1f}, constant offset {c['rms_constant_um']:.1f})", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7.5, ncol=4, loc="upper left")
    axes[1].set_xlabel("time (h); fitted left of the dotted line, held out right of it")
    _save(fig, "drift-thermal-log")


def solver_residuals(work: Path, args) -> None:
    """The grinder's flute compensated by the traditional and the exact solver: TRUE residual along the path."""
    import matplotlib.pyplot as plt
    import numpy as np
    g = work / "grinder"
    volcomp(f"volcomp simulate --seed 0 --out {g}/sim")
    volcomp(f"volcomp sweeps --seed 0 --out {g}/sweeps.csv")
    volcomp(f"volcomp identify {g}/sweeps.csv --out {g}/E.json")
    volcomp(f"volcomp report --flute --model {g}/E.json --truth {g}/sim --methods traditional,exact --out {g}/rep")
    r = np.genfromtxt(g / "rep" / "residuals.csv", delimiter=",", names=True)
    fig, ax = plt.subplots(figsize=(8, 3.4))
    for col, lab, c in (("uncompensated_true_um", "uncompensated", "0.5"), ("traditional_true_um", "traditional", "#e6550d"),
                        ("exact_true_um", "exact", "#08519c")):
        ax.plot(r["point"], r[col], color=c, lw=0.9, label=f"{lab} (max {np.max(r[col]):.1f} μm)")
    ax.set(yscale="log", xlabel="point along the flute path", ylabel="TRUE residual (μm)",
           title="the grinder's flute (seed 0), compensated with the identified elements")
    ax.title.set_fontsize(9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    _save(fig, "solver-residuals")


def _held_out_bars(rows, title, unit, name) -> None:
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 3.4))
    labels = [r[0] for r in rows]
    rms = [r[1] for r in rows]
    mx = [r[2] for r in rows]
    colours = [r[3] for r in rows]
    bars = ax.bar(labels, rms, color=colours, label="RMS")
    ax.scatter(labels, mx, marker="_", s=400, color="k", label="max", zorder=3)
    for b, v in zip(bars, rms):
        ax.text(b.get_x() + b.get_width() / 2, v, f"{v:.3g}", ha="center", va="bottom", fontsize=8)
    ax.set(yscale="log", ylabel=f"held-out error ({unit})", title=title)
    ax.title.set_fontsize(9)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3, which="both")
    _save(fig, name)


def arm_held_out(work: Path, args) -> None:
    """A simulated UR5: held-out position error of the nominal arm, the plain baselines and volcomp."""
    a = work / "ur5"
    volcomp(f"volcomp simulate --machine ur5 --seed 0 --poses 60 --checks 40 --out {a}/sim")
    volcomp(f"volcomp calibrate {a}/sim/poses.csv --machine ur5 --check {a}/sim/checks.csv --no-learned --out {a}/cal")
    cal = json.loads((a / "cal" / "model.json").read_text())["calibration"]
    rows = {s["name"]: s for s in cal["stages"] + cal["baselines"]}
    kept = rows[cal["kept_stage"]]
    pick = [("nominal", "nominal\nchain", "0.6"), ("nominal + base/tool", "nominal +\nbase/tool", "#999999"),
            ("plain geometric LSQ", "plain LSQ\n(every slot)", "#999999")]
    out = [(lab, rows[k]["rms_mm"], rows[k]["max_mm"], c) for k, lab, c in pick]
    out.append((f"volcomp\n({cal['kept_stage']})", kept["rms_mm"], kept["max_mm"], "#3182bd"))
    _held_out_bars(out, "UR5 (seed 0): 60 fitting poses, 40 held-out poses, tracker σ 20 μm", "mm", "arm-held-out")


def hexapod_held_out(work: Path, args) -> None:
    """A simulated hexapod: held-out pose error before, with the plain baseline and with volcomp."""
    h = work / "hexapod"
    volcomp(f"volcomp simulate --machine hexapod --seed 0 --out {h}/sim")
    volcomp(f"volcomp calibrate {h}/sim/poses.csv --machine hexapod --check {h}/sim/checks.csv --out {h}/cal")
    cal = json.loads((h / "cal" / "model.json").read_text())["calibration"]
    rows = [("nominal\ngeometry", cal["rms_before_um"], cal["max_before_um"], "0.6"),
            ("plain\nleast squares", cal["baseline"]["rms_um"], cal["baseline"]["max_um"], "#999999"),
            (f"volcomp\n({cal['lambda_rule']} λ)", cal["rms_after_um"], cal["max_after_um"], "#3182bd")]
    _held_out_bars(rows, f"hexapod (seed 0): {cal['n_fit_poses']} fitting poses, {cal['n_check_poses']} held-out poses",
                   "μm", "hexapod-held-out")


def layers(work: Path, args) -> None:
    """The code's layers and the one direction of imports."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.set_axis_off()
    ax.set_xlim(0, 10)
    ax.set_ylim(0, 10)
    boxes = {"app": (0.5, 7.6, 9, 1.9, "compensation/app/   the volcomp program\ncli → commands → workflows → reports", "#fdd0a2"),
             "comp": (0.5, 5.0, 9, 1.9, "compensation/   solvers, tool paths, G-code, guards,\nTRUE residual, export, learned stage", "#c6dbef"),
             "train": (0.5, 2.6, 4.0, 1.7, "training/\nthe learned field", "#c7e9c0"),
             "err": (0.5, 0.2, 9, 1.7, "errormap/   machines, kinematics, error slots, fields,\nsimulator, identification, "
                     "diagnosis, drift, arms, PKM, I/O", "#dadaeb")}
    for x, y, w, h, text, c in boxes.values():
        ax.add_patch(plt.Rectangle((x, y), w, h, fc=c, ec="0.3"))
        ax.text(x + w / 2, y + h / 2, text, ha="center", va="center", fontsize=9)
    arrow = dict(arrowstyle="->", color="0.2", lw=1.2)
    for (x0, y0), (x1, y1) in (((5, 7.6), (5, 6.9)), ((2.5, 5.0), (2.5, 4.3)), ((2.5, 2.6), (2.5, 1.9)), ((7.5, 5.0), (7.5, 1.9))):
        ax.annotate("", xy=(x1, y1), xytext=(x0, y0), arrowprops=arrow)
    ax.text(7.7, 3.4, "imports go downwards only\n(tests/test_architecture.py)", fontsize=8, color="0.3")
    _save(fig, "layers")


MAKERS = {"chain-slots": chain_slots, "identified-element": identified_element, "closed-loop-stages": closed_loop_stages,
          "learned-residual": learned_residual, "drift-thermal-log": drift_thermal_log, "solver-residuals": solver_residuals,
          "arm-held-out": arm_held_out, "hexapod-held-out": hexapod_held_out, "layers": layers}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    p.add_argument("--only", action="append", choices=sorted(FIGURES), help="make only this figure (repeatable)")
    p.add_argument("--thermal-log", help="a real machine's drift log (the drift figure)")
    args = p.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import matplotlib
    matplotlib.use("Agg")
    if args.thermal_log:
        args.thermal_log = str(Path(args.thermal_log).resolve())
    with tempfile.TemporaryDirectory(prefix="volcomp-docs-figures-") as tmp:
        for name in args.only or FIGURES:
            MAKERS[name](Path(tmp), args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
