"""``volcomp identify``: the 23 error elements from laser-tracker sweep files (grinder paper §2.1)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from errormap.elements import A_ELEMENTS, ElementSet, X_ELEMENTS, Z_ELEMENTS, element_unit
from errormap.identification import GAUGES
from errormap.io import atomic_write, write_json
from errormap.iso230 import ISO_NAME, label as iso_label
from errormap.machine import load_machine
from errormap.sweeps import read_sweeps

AXIS_GROUPS = {"X": (X_ELEMENTS, "x_mm", "x (mm)"), "Z": (Z_ELEMENTS, "z_mm", "z (mm)"),
               "A": (A_ELEMENTS, "a_deg", "a (deg)")}


def register(sub):
    p = sub.add_parser("identify", help="identify the 23 error elements from laser-tracker sweeps",
                       description="The grinder paper's method (section 2.1): reference lines/circles, the 9x6 "
                                   "least-squares system per station, squareness from the X and Z lines, the A-axis "
                                   "line from the rotary body's initial state, B-spline elements. See "
                                   "docs/identification.md.")
    p.add_argument("sweeps", nargs="+", help="sweep file(s) (CSV) of one tracker set-up")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    p.add_argument("--out", required=True, help="output element-set file (JSON)")
    p.add_argument("--report", default=None,
                   help="identification report (JSON: conditioning, residuals per station); default OUT.report.json")
    p.add_argument("--plot", default=None, metavar="PREFIX",
                   help="write one figure per axis: PREFIX_X.png, PREFIX_Z.png, PREFIX_A.png")
    p.add_argument("--truth", default=None, metavar="ELEMENTS", help="truth element set to overlay on the plots")
    p.add_argument("--gauge", choices=GAUGES, default="first-station",
                   help="machine-frame gauge (default first-station: elements zero at each axis' first station)")
    p.add_argument("--raw", action="store_true",
                   help="interpolating splines through the noisy stations (the paper's method, no smoothing); "
                        "the covariance is still written")
    p.add_argument("--noise-um", type=float, default=None,
                   help="known tracker noise σ per coordinate (μm); default: estimated from the ball residuals")
    p.add_argument("--bootstrap", type=int, default=100, help="bootstrap draws for the covariance (default 100)")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    p.set_defaults(func=run)


def plot_elements(elements: ElementSet, prefix, truth: ElementSet | None = None) -> list[Path]:
    """One figure per axis (six elements each, the constants in the title), truth dashed when given.

    Written atomically as ``PREFIX_X.png``, ``PREFIX_Z.png``, ``PREFIX_A.png``; returns the paths.
    The truth is shown after its squareness is moved to the identified value (the one split the
    sweeps cannot observe), so like is compared with like.
    """
    from matplotlib.figure import Figure  # Agg canvas, no pyplot state
    c = elements.constants
    out = []
    for ax, (names, key, label) in AXIS_GROUPS.items():
        fig = Figure(figsize=(11, 6.5), layout="constrained")
        axs = fig.subplots(2, 3)
        st = elements.stations[key]
        grid = np.linspace(st[0], st[-1], 400)
        pts = np.zeros((grid.size, 3))
        pts[:, ["x_mm", "z_mm", "a_deg"].index(key)] = grid
        v = elements.values(pts)
        vt = truth.values(pts) if truth is not None else None
        from errormap.elements import ELEMENT_NAMES
        for a, name in zip(axs.ravel(), names):
            j = ELEMENT_NAMES.index(name)
            a.plot(grid, v[:, j], "C0-", label="identified")
            a.plot(st, elements.functions[name], "C0o", ms=3)
            if vt is not None:
                a.plot(grid, vt[:, j], "k--", lw=1, label="truth")
            a.set_title(f"{iso_label(name)} ({'μm' if element_unit(name) == 'um' else 'μrad'})")
            a.set_xlabel(label)
            a.grid(alpha=0.3)
        axs[0, 0].legend(fontsize=8)
        if ax == "A":
            extra = (f"dy_oa {c['dy_oa']:.3f} μm, dz_oa {c['dz_oa']:.3f} μm, "
                     f"ey_oa {c['ey_oa']:.3f} μrad, ez_oa {c['ez_oa']:.3f} μrad")
        else:
            extra = f"s_xz {c['s_xz']:.3f} μrad"
        fig.suptitle(f"identified {ax}-axis elements ({extra})")
        path = Path(f"{prefix}_{ax}.png")
        with atomic_write(path, "wb") as fh:
            fig.savefig(fh, format="png", dpi=110)
        out.append(path)
    return out


def iso_summary_lines(elements: ElementSet) -> list[str]:
    """The 23 elements with their ISO 230-1 names (docs/export.md) and their largest magnitude.

    The ISO names hold in the project's frames: Z's lateral pairs and A's radial/tilt pairs
    are turned (θ1, a) before they equal the ISO components (``errormap.iso230.to_iso``).
    """
    from errormap.elements import CONSTANT_ELEMENTS, FUNCTION_ELEMENTS
    lines = ["element (ISO 230-1)    max |value|"]
    for k in FUNCTION_ELEMENTS:
        lines.append(f"  {iso_label(k):<20} {np.abs(elements.functions[k]).max():9.3f} {element_unit(k)}")
    for k in CONSTANT_ELEMENTS:
        lines.append(f"  {iso_label(k):<20} {elements.constants[k]:9.3f} {element_unit(k)} (constant)")
    return lines


def run(args) -> int:
    machine = load_machine(args.machine, expect_kind="grinder")
    truth = ElementSet.load(args.truth) if args.truth else None
    sweeps = read_sweeps(args.sweeps)
    print(f"identifying from {', '.join(args.sweeps)} ...", file=sys.stderr)
    from errormap.uncertainty import covariance_path, smooth_identify
    from ..cli import UsageError
    if args.bootstrap < 2:
        raise UsageError(f"--bootstrap must be >= 2, got {args.bootstrap}")
    sm = smooth_identify(sweeps, machine, noise_um=args.noise_um, n_boot=args.bootstrap, seed=args.seed,
                         smooth=not args.raw, gauge=args.gauge)
    res = sm.raw
    res.elements_ = sm.elements_
    for line in res.summary_lines() + sm.summary_lines():
        print(line)
    for line in iso_summary_lines(res.elements_):
        print(line)
    report = Path(args.report) if args.report else Path(args.out).with_suffix(".report.json")
    info = res.to_dict()
    info["iso230_names"] = dict(ISO_NAME)
    cov_path = covariance_path(args.out)
    info.update({"sweeps": [str(s) for s in args.sweeps], "machine_file": machine.path,
                 "machine_sha256": machine.sha256, "elements_file": str(args.out),
                 "uncertainty": sm.report_dict(), "covariance_file": str(cov_path)})
    sm.covariance_.save(cov_path)
    write_json(report, info)
    el_path = res.elements_.save(args.out)
    print(f"wrote elements: {el_path}")
    print(f"wrote covariance: {cov_path}")
    print(f"wrote report: {report}")
    if args.plot:
        if truth is not None:
            from errormap.identification import move_squareness
            truth = move_squareness(truth, res.elements_.constants["s_xz"], machine)
        for p in plot_elements(res.elements_, args.plot, truth):
            print(f"wrote plot: {p}")
    return 0
