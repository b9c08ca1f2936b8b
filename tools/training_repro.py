"""One deterministic training run (iteration cap, no time limit), printed as one JSON row.

Used to check that a change of the code leaves the fit unchanged: run it in two checkouts and
compare the rows (``iterations``, ``train_*`` must agree to the last digit; ``val_*`` also
depends on how the validation points are drawn)::

    PYTHONPATH=CHECKOUT python tools/training_repro.py LABEL [MAX_ITER]

Data: ``volcomp simulate --seed 0`` (default grinder, 1,331 feature points); the trainer's
defaults (LM, raw A, Nguyen–Widrow init seed 0, 2 threads) with the paper's stop at 0.0267 μm max
on the feature points. Works with the settings-object API and with the earlier keyword API.
"""
import hashlib
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    from errormap.featurepoints import FeaturePoints
    try:
        from compensation.app.cli import main as cli
    except ImportError:  # a checkout before the application wing
        from compensation.app.cli import main as cli
    import training.trainers as trainers
    label = sys.argv[1] if len(sys.argv) > 1 else "run"
    max_iter = int(sys.argv[2]) if len(sys.argv) > 2 else 400
    out = Path(tempfile.gettempdir()) / f"volcomp-training-repro-{label}"
    if not (out / "featurepoints.csv").is_file():
        cli(["simulate", "--seed", "0", "--out", str(out), "--checks", "20"])
    fp = FeaturePoints.load(out / "featurepoints.csv")
    kw = dict(trainer="lm", a_encoding="raw", max_time_s=1e6, max_iter=max_iter, seed=0, threads=2,
              max_err_goal_um=0.0267, select_best=False)
    t0 = time.process_time()
    if hasattr(trainers, "TrainSettings"):
        r = trainers.fit_field(fp, trainers.TrainSettings(**kw), tracking=trainers.TrackSettings(track=False))
    else:
        r = trainers.fit_field(fp, track=False, **kw)
    m = r.metrics
    print(json.dumps({"label": label, "iterations": r.history.iterations, "stop": r.history.stop_reason,
                      "train_max_um": m["train_max_um"], "train_rms_um": m["train_rms_um"],
                      "val_max_um": m["val_max_um"], "val_rms_um": m["val_rms_um"],
                      "cpu_s": time.process_time() - t0,
                      "feature_errors_sha256": hashlib.sha256(np.ascontiguousarray(fp.errors_um).tobytes()).hexdigest()[:12]}))


if __name__ == "__main__":
    main()
