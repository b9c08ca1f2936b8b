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
``bench_tcp.py``). Work offset G54 = (0, 0, z) from the manifest (the boat's touch-off puts the table at program
Z -13.25: 13.25 puts it on the C table top; the impeller's lowest tip is at Z -0.54: 40 keeps its blank above the
table). Tool: no G43 in either program, so LinuxCNC's kinematics use a zero tool offset: the machine file's own
tool point (``[tcp] tool_length_under_g49``). Residual kind: true (simulated truth, the product's ``--truth``)."""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from bench_tcp import NOISE, inverse_time_minutes, noisy  # noqa: E402

from compensation.app.cli import main  # noqa: E402
from errormap.machine import load_machine  # noqa: E402
from errormap.mt_elements import ChainElementSet  # noqa: E402

MANIFEST = HERE / "program_corpus" / "TCP_DEMOS.csv"
MACHINE = "five-axis-ac"


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
