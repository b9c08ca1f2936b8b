"""5-axis programs in tool-centre-point mode on ``five-axis-ac``: TRUE residual of the tool tip (μm) and of the
tool axis (μrad) before / after compensation, position-only vs position + orientation, for a LinuxCNC program
(M428 switchable kinematics, G43 H1, G93 inverse time) and the same path posted for Fanuc (G43.4 H1) and in
joint mode (axis words).

The program is the benchmark's own (written here): a 5-axis helical contour, the tool tip on a circle of
40 mm radius rising from Z 5 to Z 25 mm over 720° of C, the tool tilted by A from -15° to -45°. Truth: a
seeded element set (±10 μm / μrad, 1 σ); models: the truth itself (what the method leaves) and the truth with
seeded station noise of 0.5 μm / μrad (1 σ; a model's own error). Tool length 120 mm, work offset
(10, -5, 20) mm. Run: ``python -m benchmarks.run tcp`` (about a minute; ``--quick``: the LinuxCNC program
only)."""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from compensation.app.cli import main  # noqa: E402
from compensation.gcode import split_lines, tokenize  # noqa: E402
from errormap.machine import load_machine  # noqa: E402
from errormap.chain_elements import ChainElementSet  # noqa: E402

OFFSET = np.array([10.0, -5.0, 20.0])
LENGTH_MM = 120.0
STEPS = 144
NOISE = 0.5


def path_points():
    """Tip (n, 3) mm in the workpiece frame (program coordinates) and A, C (n, 2) deg."""
    t = np.linspace(0.0, 1.0, STEPS + 1)
    c = 720.0 * t
    a = -15.0 - 30.0 * 0.5 * (1 - np.cos(2 * np.pi * t))
    tip = np.column_stack([40.0 * np.cos(np.radians(3 * c)), 40.0 * np.sin(np.radians(3 * c)), 5.0 + 20.0 * t])
    return tip, np.column_stack([a, c])


def programs(mt):
    tip, rot = path_points()
    body = [f"X{x:.4f} Y{y:.4f} Z{z:.4f} A{a:.4f} C{c:.4f}" for (x, y, z), (a, c) in zip(tip, rot)]
    lcnc = ["(5-axis helical contour, TCP kinematics, inverse time)", "G21 G90 G17", "G54", "T1 M6", "G43 H1", "M428",
            f"G0 {body[0]}", "G93"] + [f"G1 {b} F{STEPS / 0.5:.1f}" if k == 0 else f"{b} F{STEPS / 0.5:.1f}"
                                       for k, b in enumerate(body[1:])] + ["G94", "M429", "G49", "M2"]
    fanuc = ["%", "O4711 (5-AXIS HELIX)", "G21 G90 G17", "T1 M6", "G54", f"G43.4 H1 G0 {body[0]}"] + \
            [f"G1 {body[1]} F600." ] + body[2:] + ["G49", "M30", "%"]
    # joint mode: the controller's nominal inverse done by the post (axis words), tool length by G43 H1
    from compensation.nc_state import machine_with_tool
    m = machine_with_tool(mt, LENGTH_MM)
    start = np.column_stack([np.full((len(tip), 3), -200.0), rot])
    q, ok = m.inverse(tip + OFFSET, start)
    assert ok.all()
    zprog = q[:, 2] - OFFSET[2] - LENGTH_MM  # machine Z = program Z + offset + tool length
    jb = [f"X{x - OFFSET[0]:.4f} Y{y - OFFSET[1]:.4f} Z{z:.4f} A{a:.4f} C{c:.4f}"
          for (x, y, _), z, (a, c) in zip(q[:, :3], zprog, rot)]
    joint = ["(the same contour posted in joint mode)", "G21 G90 G17", "G54", "T1 M6", "G43 H1", f"G0 {jb[0]}",
             f"G1 {jb[1]} F600"] + jb[2:] + ["G49", "M2"]
    return {"lcnc.ngc": ("linuxcnc", lcnc), "fanuc.nc": ("fanuc", fanuc), "joint.ngc": ("linuxcnc", joint)}


def noisy(truth, seed):
    rng = np.random.default_rng(seed)
    f = {}
    for k, v in truth.functions.items():
        e = rng.normal(0.0, NOISE, v.shape)
        if k.endswith("_c"):  # C is a full turn: its profiles stay closed
            e = e - (e[-1] - e[0]) * np.linspace(0, 1, len(e))
        f[k] = v + e
    return ChainElementSet(truth.machine, truth.stations, f,
                           {k: v + rng.normal(0.0, NOISE) for k, v in truth.constants.items()})


def inverse_time_minutes(text):
    t, g93 = 0.0, False
    for ln in split_lines(text):
        _, words, _ = tokenize(ln.rstrip("\n"))
        codes = {w.code for w in words if w.letter == "G"}
        g93 = (g93 or "G93" in codes) and "G94" not in codes
        f = [w.value for w in words if w.letter == "F"]
        if g93 and f and any(w.letter in "XYZAC" for w in words):
            t += 1.0 / f[0]
    return t


def compensate_rows(names=None):
    mt = load_machine("five-axis-ac")
    rows = []
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        truth = ChainElementSet.random(mt, 0, 10.0, 11)
        tp = truth.save(d / "truth.json")
        models = {"truth": tp, f"truth+{NOISE:g} noise": noisy(truth, 1).save(d / "est.json")}
        (d / "wo.csv").write_text("system,x_mm,y_mm,z_mm\nG54,%g,%g,%g\n" % tuple(OFFSET))
        (d / "tt.csv").write_text(f"tool,length_mm\n1,{LENGTH_MM}\n")
        for name, (dialect, lines) in programs(mt).items():
            if names is not None and name not in names:
                continue
            (d / name).write_text("\n".join(lines) + "\n")
            for mname, mpath in models.items():
                for orient in (False, True):
                    out = d / f"o_{name}_{mname}_{orient}".replace(" ", "_").replace("+", "p")
                    argv = ["compensate", str(d / name), "--machine", "five-axis-ac", "--model", str(mpath), "--method",
                            "exact", "--out", str(out), "--truth", str(tp), "--work-offsets", str(d / "wo.csv"),
                            "--tool-table", str(d / "tt.csv"), "--dialect", dialect, "--force"]
                    rc = main(argv + (["--compensate-orientation"] if orient else []))
                    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
                    o = e["tcp"]
                    row = {"program": name, "model": mname, "orientation": orient, "rc": rc, "points": e["points"],
                           "true_before_um": e["true_uncompensated"]["max_um"], "true_after_um": e["true"]["max_um"],
                           "true_after_rms_um": e["true"]["rms_um"],
                           "orient_before_urad": o["true_orientation_uncompensated"]["max_urad"],
                           "orient_after_urad": o["true_orientation"]["max_urad"],
                           "orient_after_rms_urad": o["true_orientation"]["rms_urad"],
                           "solved": o.get("orientation_solved_points"), "kept": o.get("orientation_kept_points")}
                    if orient and o.get("orientation_solved_points"):
                        row["orient_after_solved_urad"] = o["true_orientation_solved"]["max_urad"]
                    if name == "lcnc.ngc":
                        row["g93_minutes_in_out"] = (inverse_time_minutes((d / name).read_text()),
                                                     inverse_time_minutes((out / name).read_text()))
                    rows.append(row)
    return rows

TITLE = "Five-axis programs in TCP mode (`five-axis-ac`): tool tip and tool axis, before / after"
DATA = ("the benchmark's 5-axis helical contour (145 points, A −15…−45°, C 0…720°) as LinuxCNC TCP (M428, G43 H1, "
        "G93), Fanuc G43.4 and joint-mode posts; seeded truth ±10 μm / μrad; model = truth + 0.5 μm / μrad noise")


def run(quick: bool, seed: int) -> dict:
    rows = [r for r in compensate_rows(["lcnc.ngc"] if quick else None) if r["model"] != "truth"]
    figs = []
    for r in rows:
        if not r["orientation"]:
            figs.append({"what": f"{r['program']}: tool tip, max (position compensated)", "value": r["true_after_um"],
                         "unit": "μm", "residual": "true", "anchor": "uncompensated", "anchor_value": r["true_before_um"]})
        else:
            figs.append({"what": f"{r['program']}: tool axis, max (`--compensate-orientation`)",
                         "value": r["orient_after_urad"], "unit": "μrad", "residual": "true",
                         "anchor": "uncompensated", "anchor_value": r["orient_before_urad"]})
    g93 = next(r["g93_minutes_in_out"] for r in rows if "g93_minutes_in_out" in r)
    notes = [f"G93 inverse-time program: {g93[0]:.4f} min in, {g93[1]:.4f} min out (feed time kept)."]
    return {"figures": figs, "notes": notes}
