"""The lathe's identification on the user's path.

Per seed, through the command line: ``simulate --machine M --seed S`` → ``sweeps --machine M --seed S
--seed-noise S`` (2 μm tracker noise; the noise seed varied with the truth seed: with one noise seed the
identification error is the same on every truth, it is noise, not the truth) → ``identify`` →
``compensate --method exact --truth`` of a turning program (G18 arc, C moves). TRUE residual (the hidden
truth driven with the compensated axes) beside the uncompensated program. The mill's identified model gives
the same volume-grid figure beside it.

Also, per slot of the shipped lathe file, the identified minus the noise-free identification (the truth in
the identification's gauge) in units of the identification's standard error (z-score RMS) and the
volume-grid field error of the identified model.

    python -m benchmarks.run lathe
"""
from __future__ import annotations

import contextlib
import io
import json
import tempfile
from pathlib import Path


PROGRAM = ("%\nO1000 (LATHE X Z C)\nG18 G90 G21\nT1 M6\nG0 X80. Z350. C0.\n"
           "G1 X60. Z320. C0. F200.\nG1 Z260. C90.\nG2 X80. Z240. I20. K0.\nG1 X120. C180.\n"
           "(FINISH)\nG1 Z180. C270.\nM30\n%\n")


def user_path(machine: str, seed: int, d: Path) -> dict:
    from compensation.app.cli import main
    base = ["--machine", machine, "--seed", str(seed)]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["simulate", *base, "--out", str(d / "sim")]) == 0
        assert main(["sweeps", *base, "--seed-noise", str(seed), "--out", str(d / "sw.csv")]) == 0
        assert main(["identify", str(d / "sw.csv"), "--machine", machine, "--out", str(d / "E.json")]) == 0
        (d / "p.nc").write_text(PROGRAM)
        assert main(["compensate", str(d / "p.nc"), "--machine", machine, "--model", str(d / "E.json"), "--method",
                     "exact", "--truth", str(d / "sim" / "truth.json"), "--out", str(d / "o"),
                     "--work-offsets", "machine"]) == 0  # PROGRAM is in machine coordinates
    e = json.loads((d / "o" / "compensate_summary.json").read_text())["files"][0]
    return {"true_max": e["true"]["max_um"], "true_rms": e["true"]["rms_um"],
            "unc_max": e["true_uncompensated"]["max_um"], "unc_rms": e["true_uncompensated"]["rms_um"],
            "model_max": e["model_max_um"], "failures": e["failures"]}


def grid_figure(machine_name, seeds):
    """Identified-model field error over the volume grid (4,000 points), max / RMS μm, and the z-scores."""
    from errormap.machine import load_machine
    from errormap.identifiability import identifiability
    m = load_machine(machine_name)
    out = []
    for s in seeds:
        rep = identifiability(m, seed=s, noise_um=2.0, seed_noise=s)
        out.append(rep)
    return out


TITLE = "Lathe (`lathe-xzc`): identification from sweeps and a turning program compensated"
DATA = ("simulated `lathe-xzc` (`volcomp simulate --seed S`), sweeps at 2 μm, a G18 turning program with C moves; "
        "seeds 0–2 (quick: seed 0, no volume-grid figure)")


def run(quick: bool, seed: int) -> dict:
    import numpy as np
    seeds = [seed] if quick else [seed, seed + 1, seed + 2]
    rows = []
    for s in seeds:
        with tempfile.TemporaryDirectory() as td:
            rows.append(user_path("lathe-xzc", s, Path(td)))
    med = lambda k: float(np.median([r[k] for r in rows]))  # noqa: E731
    figs = [{"what": "turning program, max (median over seeds)", "value": med("true_max"), "unit": "μm",
             "residual": "true", "anchor": "uncompensated", "anchor_value": med("unc_max")},
            {"what": "turning program, RMS", "value": med("true_rms"), "unit": "μm", "residual": "true",
             "anchor": "uncompensated", "anchor_value": med("unc_rms")}]
    if not quick:
        g = grid_figure("lathe-xzc", seeds)
        figs.append({"what": "identified model over the volume grid, RMS (median)",
                     "value": float(np.median([x.grid_rms_um for x in g])), "unit": "μm", "residual": "true",
                     "anchor": "mill-xyz's identified model, the same figure",
                     "anchor_value": float(np.median([x.grid_rms_um for x in grid_figure("mill-xyz", seeds)]))})
    return {"figures": figs, "notes": []}
