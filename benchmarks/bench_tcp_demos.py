"""LinuxCNC's two 5-axis demo programs (the FeatureCAM "Hermle" ``boat-xyzac.ngc`` and the impeller program of
the ``xyzac-trt`` sim config: ``M428`` TCP kinematics, ``T1 M6`` with no ``G43``, ``G93`` inverse time) compensated
on ``five-axis-ac``: TRUE residual of the tool tip (μm) and of the tool axis (μrad) before / after, position-only
vs position + orientation (``--compensate-orientation``).

The programs are not stored here (GPL-2.0): ``program_corpus/TCP_DEMOS.csv`` names each (repository, path,
commit, the lines counted, the sha256 of the bytes counted) and the Z of the G54 offset used; put the files
in a folder under the ``file`` column's names and run

    python benchmarks/bench_tcp_demos.py --corpus DIR [--json OUT]

Truth: a seeded element set of ``five-axis-ac`` (seed 0, ±10 μm / μrad 1 σ); models: the truth itself (what the
method leaves) and the truth with seeded station noise 0.5 μm / μrad 1 σ (a model's own error, as
``python -m benchmarks.run tcp``). Work offset G54 = (0, 0, z) from the manifest (the boat's touch-off puts the table at program
Z -13.25: 13.25 puts it on the C table top; the impeller's lowest tip is at Z -0.54: 40 keeps its blank above the
table). Tool: no G43 in either program, so LinuxCNC's kinematics use a zero tool offset: the machine file's own
tool point (``[tcp] tool_length_under_g49``). Residual kind: true (simulated truth, the product's ``--truth``)."""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import re
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from benchmarks.suite.tcp import NOISE, inverse_time_minutes, noisy  # noqa: E402

import numpy as np  # noqa: E402

from compensation.app.cli import main  # noqa: E402
from errormap.chain_field import ChainField  # noqa: E402
from errormap.machine import load_machine  # noqa: E402
from errormap.chain_elements import ChainElementSet  # noqa: E402

MANIFEST = HERE / "program_corpus" / "TCP_DEMOS.csv"
MACHINE = "five-axis-ac"


def tcp_points(text):
    """Independent of the product: ``(points (n, 5) X Y Z A C, feed (n,) bool)`` of every TCP line of a LinuxCNC
    program (between M428 and M429; modal axis words carried; ``;`` and ``( )`` comments dropped; a point is a
    feed point when G1/G2/G3 is the active motion)."""
    pos = dict.fromkeys("XYZAC", np.nan)
    on, feed, pts, flags = False, False, [], []
    for line in text.splitlines():
        body = re.sub(r"\(.*?\)", "", line.split(";")[0]).upper()
        if re.search(r"M0*428(?![\d.])", body):
            on = True
        if re.search(r"M0*429(?![\d.])", body):
            on = False
        g = re.findall(r"G0*([0123])(?![\d.])", body)
        if g:
            feed = g[-1] != "0"
        words = dict(re.findall(r"([XYZAC])\s*([+-]?[\d.]+)", body))
        if words and on:
            pos.update({k: float(v) for k, v in words.items()})
            pts.append([pos[a] for a in "XYZAC"])
            flags.append(feed)
    return np.array(pts), np.array(flags)


def programmed_points_reached_um(src_text, out_text, truth_path, offset_z):
    """Every programmed TCP feed point of the source: the distance (μm) to the nearest TRUE tip among the written
    feed points, each driven as a TCP controller drives it (the nominal inverse at the machine file's own tool —
    no G43 in the demos — of the written tip + work offset at the written A C, then the truth's tool point there).
    The issue's check: every programmed point reproduced to <= 1 μm by the true machine after compensation."""
    mt = load_machine(MACHINE)
    off = np.array([0.0, 0.0, float(offset_z)])
    src, sf = tcp_points(src_text)
    out, of = tcp_points(out_text)
    src, out = src[sf & np.isfinite(src).all(axis=1)], out[of & np.isfinite(out).all(axis=1)]
    start = np.column_stack([np.full((len(out), 3), 0.0), out[:, 3:]])
    q, ok = mt.inverse(out[:, :3] + off, start, free=("X", "Y", "Z"), tol_mm=1e-10)
    assert ok.all()
    tips = mt.nominal(q) + 1e-3 * ChainField(mt, ChainElementSet.load(truth_path, mt)).predict(q) - off
    d = np.array([np.min(np.linalg.norm(tips - p, axis=1)) for p in src[:, :3]]) * 1e3
    return float(d.max()), len(src)


def _row(name, mname, orient, rc, e, src_text, out_text):
    o = e.get("tcp", {})
    row = {"program": name, "model": mname, "orientation": orient, "rc": rc, "points": e.get("points"),
           "true_before_um": e["true_uncompensated"]["max_um"], "true_after_um": e["true"]["max_um"],
           "true_after_rms_um": e["true"]["rms_um"],
           "orient_before_urad": o["true_orientation_uncompensated"]["max_urad"],
           "orient_after_urad": o["true_orientation"]["max_urad"],
           "orient_after_rms_urad": o["true_orientation"]["rms_urad"],
           "solved": o.get("orientation_solved_points"), "kept": o.get("orientation_kept_points"),
           "g93_minutes_in_out": (inverse_time_minutes(src_text), inverse_time_minutes(out_text))}
    if o.get("true_orientation_solved"):
        row["orient_solved_before_urad"] = o["true_orientation_solved_uncompensated"]["max_urad"]
        row["orient_solved_after_urad"] = o["true_orientation_solved"]["max_urad"]
    return row


def run(corpus: Path) -> list:
    rows = []
    mt = load_machine(MACHINE)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        truth = ChainElementSet.random(mt, 0, 10.0, 11)
        tp = truth.save(d / "truth.json")
        models = {"truth": tp, f"truth+{NOISE:g} noise": noisy(truth, 1).save(d / "est.json")}
        (d / "tt.csv").write_text("tool,length_mm,radius_mm\n1,0,5\n")  # the sim's tool table: T1 Z0
        for m in csv.DictReader(MANIFEST.open(encoding="utf-8")):
            p = corpus / m["file"]
            if not p.is_file() or hashlib.sha256(p.read_bytes()).hexdigest() != m["sha256"]:
                rows.append({"program": m["file"], "outcome": "missing or changed"})
                continue
            wo = d / f"wo-{m['file']}.csv"
            wo.write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{m['work_offset_z_mm']}\n")
            for mname, mpath in models.items():
                for orient in (False, True):
                    out = d / f"o-{len(rows)}"
                    argv = ["compensate", str(p), "--machine", MACHINE, "--model", str(mpath), "--method", "exact",
                            "--out", str(out), "--truth", str(tp), "--work-offsets", str(wo), "--tool-table",
                            str(d / "tt.csv"), "--dialect", "linuxcnc", "--force"]
                    rc = main(argv + (["--compensate-orientation"] if orient else []))
                    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
                    row = _row(m["file"], mname, orient, rc, e, p.read_text(), (out / p.name).read_text())
                    if mname == "truth":
                        row["programmed_points_max_um"], row["programmed_points"] = programmed_points_reached_um(
                            p.read_text(), (out / p.name).read_text(), tp, m["work_offset_z_mm"])
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--corpus", required=True, help="folder holding the manifest's files")
    ap.add_argument("--json", help="write the rows here")
    a = ap.parse_args()
    result = run(Path(a.corpus))
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1))
