"""Figures of docs/decisions/020-benchmark-notebook.md, "Verdicts everywhere, and huge tables read in bounded memory".

``arm``: the arm calibration's verdict on a simulated UR5 (seed 7: link errors and joint sag; 150 fit and 100
held-out poses, 20 μm tracker noise) with the true σ stated and with one 4x too small (``--no-learned --folds 3``),
and, where the shared data are present, the real UR5 grid (hold-out 0.2, seed 0, ``--no-learned``, no σ stated).
``grinder``: the loop's noise estimate on the grinder's chain (the update's) on 150 simulated checks of seeds 3-5
at 1 μm, and the verdict with 1 μm and 0.25 μm stated.
``table PATH``: write a 5,000,000-row point table to PATH (numpy seed 0); then measure with
``/usr/bin/time -v python -c "from errormap.io import read_table; read_table('PATH').float('x_mm')"``.

    python benchmarks/bench_verdicts_tables.py arm|grinder|table PATH
"""
from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

LO = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0])
HI = np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
REAL_UR5 = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "serial-arms" / "ur5_grid.csv"


def _calibrate(argv, out: Path) -> None:
    from compensation.app.cli import main
    t0 = time.process_time()
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        rc = main([str(a) for a in argv])
    v = json.loads((out / "model.json").read_text())["verdict"]
    h = v["held_out"]
    print(f"{out.name}: exit {rc}, {v['status']}, kept {h['kept_rms_mm']:.4f} mm, plain LSQ {h['plain_lsq_rms_mm']:.4f} "
          f"mm, paired z {h['paired_z_plain_over_kept']:.2f}, RMS(r/sigma) {h.get('noise_ratio')}, "
          f"{time.process_time() - t0:.0f} CPU s; {'; '.join(v['reasons'])}")


def arm() -> None:
    from errormap.arm_poses import write_arm_poses
    from errormap.arm_simulate import draw_truth, measure, random_joints
    from errormap.machine import load_machine
    ur5, d = load_machine("ur5"), Path(tempfile.mkdtemp())
    t = draw_truth(ur5, 7)
    write_arm_poses(d / "fit.csv", ur5, measure(ur5, t, random_joints(LO, HI, 150, [7, 0]), 0.02, [7, 1]))
    write_arm_poses(d / "check.csv", ur5, measure(ur5, t, random_joints(LO, HI, 100, [7, 5]), 0.02, [7, 6]))
    for name, noise_um in (("true_sigma", 20.0), ("understated", 5.0)):
        _calibrate(["calibrate", d / "fit.csv", "--check", d / "check.csv", "--machine", "ur5", "--out", d / name,
                    "--no-learned", "--folds", "3", "--noise-um", noise_um], d / name)
    if REAL_UR5.exists():
        _calibrate(["calibrate", REAL_UR5, "--machine", "ur5", "--out", d / "real_ur5", "--no-learned"], d / "real_ur5")


def grinder() -> None:
    import tempfile
    from pathlib import Path
    from errormap.chain_elements import ChainElementSet
    from errormap.diagnosis.chain_loop import MTChecks, closed_loop_chain, full_parameters
    from errormap.diagnosis.plausibility import diagnosis_verdict
    from errormap.machine import load_machine
    from errormap.simulator import random_truth
    g = load_machine(None)
    mt = g
    for seed in (3, 4, 5):
        t = random_truth(g, seed)
        with tempfile.TemporaryDirectory() as td:
            el = ChainElementSet.load(t.elements.save(Path(td) / "el.json"), mt)
        slots, stations = full_parameters(el)
        ck = MTChecks.from_columns(mt, t.check_measurements(150, 1.0, seed + 1))
        out = []
        for stated in (1.0, 0.25):
            ck.stated_noise_um = stated
            s = closed_loop_chain(mt, el, ck, cov=(slots, stations, 0.25 * np.eye(len(slots))))
            out.append(diagnosis_verdict(s)["status"])
        print(f"seed {seed}: the update's sigma {s['noise_sigma_estimated_um']:.3f} um; stated 1.0: {out[0]}, "
              f"stated 0.25: {out[1]}")


def table(path: str) -> None:
    import pyarrow as pa
    import pyarrow.csv as pacsv
    rng, n = np.random.default_rng(0), 5_000_000
    cols = {"x_mm": rng.uniform(0, 200, n), "z_mm": rng.uniform(-50, 0, n), "a_deg": rng.uniform(0, 360, n)}
    pacsv.write_csv(pa.table({k: np.round(v, 6) for k, v in cols.items()}), path,
                    pacsv.WriteOptions(quoting_style="none"))


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else ""
    if what == "table" and len(sys.argv) == 3:
        table(sys.argv[2])
    elif what in ("arm", "grinder"):
        globals()[what]()
    else:
        sys.exit(__doc__)
