"""Ray scale-out (docs/how-to/scale-out.md): a local 2-CPU Ray instance started by the tests.

* ``compensate --cluster ray`` on several files and one large path writes the same bytes as the
  local run, for every method (the chunk plan is shared);
* a worker killed mid-batch: the batch completes (Ray restarts the actor, the chunk is solved
  again) with the same bytes, or — killed on every try — fails with one line and writes nothing;
* ``fleet --cluster ray`` on two machines, tracked on a local MLflow tracking server.

Skipped only when Ray is not importable (``pip install -e '.[test,cluster]'``).
"""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from compensation.app.cli import main  # noqa: E402
from compensation.app.workflows.cluster import FAULT_ENV, RayExecutor  # noqa: E402
from compensation.batch import LocalExecutor, solve_batch  # noqa: E402
from compensation.pathio import write_axes_gcode  # noqa: E402
from path_files import write_targets_csv  # noqa: E402
from compensation.toolpath import flute_path  # noqa: E402
from errormap.chain_field import ChainField  # noqa: E402
from errormap.io import write_csv  # noqa: E402
from errormap.chain_truth import make_chain_truth, random_axes  # noqa: E402
from tests.test_batch import small_learned_field  # noqa: E402

pytestmark = pytest.mark.slow

BIG_POINTS = 4_000         # the "large path": four chunks of CHUNK_POINTS (what is asserted is the chunk plan, the
CHUNK_POINTS = 1_000       # bytes, the retried and the failing chunk, the same at any size: the fault hook kills a worker
# as its chunk starts (FAULT_ENV); the throughput at 200k+ points is the benchmark suite's (benchmarks/suite/cluster.py))
EDGE_MM = (1.0, 0.5)       # random points kept this far inside the X / Z strokes (the guards' ball)
# identification of a 23-element set is least squares on the same sweeps; a Ray worker runs its
# BLAS on one thread, this process perhaps on two: the sums may differ in the last bits only
IDENTIFY_TOL = 1e-9
TRAIN_ITER = 3             # the fleet test checks the plumbing, not the fit
FLEET_OPTIONS = ["--train-iter", str(TRAIN_ITER), "--bootstrap", "4", "--grid", "5", "--hidden", "6,6", "--no-learned"]
"""The fleet test's options: it checks the plumbing (options reach the Ray tasks, runs and artifacts reach the
server, the task's identification is the in-process one), not the fit; --no-learned leaves out the diagnosis's
learned-residual stage (GP fits, ~1/3 of a machine's CPU time), whose figures the test does not assert (the stage
itself is tests/test_hybrid_chain.py's and tests/test_hybrid.py's)."""


@pytest.fixture(scope="module")
def batch(tmp_path_factory, grinder):
    """Three small files, one BIG_POINTS path in four chunks, an element set, and the local run's outputs."""
    d = tmp_path_factory.mktemp("cluster")
    el = make_chain_truth(grinder, 7).elements.save(d / "elements.json")
    f = flute_path(turns=1, points_per_turn=60)
    files = [write_axes_gcode(d / "in" / "flute.nc", f.axes(grinder)),
             write_axes_gcode(d / "in" / "sparse.nc", f.axes(grinder)[::4]),
             write_targets_csv(d / "in" / "targets.csv", f.targets_mm)]
    ax = random_axes(grinder, BIG_POINTS, np.random.default_rng(1))
    ax[:, 0] = np.clip(ax[:, 0], EDGE_MM[0], grinder.stroke_hi[0] - EDGE_MM[0])
    ax[:, 1] = np.clip(ax[:, 1], EDGE_MM[1], grinder.stroke_hi[1] - EDGE_MM[1])
    files.append(write_csv(d / "in" / "big.csv", dict(zip(("x_mm", "z_mm", "a_deg"), ax.T))))
    base = ["compensate", *map(str, files), "--model", str(el), "--method", "exact",
            "--chunk-points", str(CHUNK_POINTS), "--work-offsets", "machine"]  # the .nc files: machine coordinates
    assert main(base + ["--out", str(d / "local"), "--workers", "1"]) == 0
    return SimpleNamespace(d=d, files=files, base=base, local=d / "local")


def _same_outputs(a: Path, b: Path, files) -> None:
    for f in files:
        assert (a / f.name).read_bytes() == (b / f.name).read_bytes(), f.name


def test_ray_batch_writes_the_local_runs_bytes(ray_session, batch, grinder, capsys):
    out = batch.d / "ray"
    assert main(batch.base + ["--out", str(out), "--cluster", "ray"]) == 0
    _same_outputs(batch.local, out, batch.files)
    summary = json.loads((out / "compensate_summary.json").read_text())
    assert summary["solved_on"].startswith("Ray") and summary["chunk_points"] == CHUNK_POINTS
    assert [e["chunks"] for e in summary["files"]] == [1, 1, 1, BIG_POINTS // CHUNK_POINTS]
    # every method: the same arrays from Ray actors as from local threads (GA: per-chunk seeds)
    field = ChainField(grinder, make_chain_truth(grinder, 7).elements)
    fl = flute_path(turns=1, points_per_turn=40)
    paths = [SimpleNamespace(targets_mm=fl.targets_mm, axes=fl.axes(grinder)),
             SimpleNamespace(targets_mm=fl.targets_mm[3:9], axes=fl.axes(grinder)[3:9])]
    opts = {"traditional": {}, "exact": {}, "batched-ga": {"generations": 10},
            "ga": {"generations": 2, "population": 10}}
    learned = small_learned_field(grinder)  # torch in the workers: one thread, as locally
    runs = [(field, m, o) for m, o in opts.items()] + [(learned, m, opts[m]) for m in ("exact", "batched-ga")]
    with RayExecutor() as ex:  # the session above: joined, left running
        for f, method, o in runs:
            local = solve_batch(method, f, grinder, paths, seed=11, options=o, chunk_points=16,
                                executor=LocalExecutor(1))
            remote = solve_batch(method, f, grinder, paths, seed=11, options=o, chunk_points=16, executor=ex)
            for a, b in zip(local, remote):
                assert np.array_equal(a.axes, b.axes) and np.array_equal(a.residual_um, b.residual_um), method
    assert ray.is_initialized()


def test_worker_killed_mid_batch(ray_session, batch, monkeypatch, capsys):
    # killed once, on the third chunk of the large path: the actor restarts, the chunk is solved again
    marker = batch.d / "killed-once"
    monkeypatch.setenv(FAULT_ENV, f"exit-once:3:2:{marker}")
    out = batch.d / "ray_fault_once"
    assert main(batch.base + ["--out", str(out), "--cluster", "ray"]) == 0
    assert marker.exists()  # the worker did die
    _same_outputs(batch.local, out, batch.files)
    capsys.readouterr()
    # killed on every try: one error line, exit 4, nothing written (not even the summary). On one
    # worker chunk 3 is always queued behind chunk 2 and dies with it: the line names chunk 2
    monkeypatch.setenv(FAULT_ENV, "exit:3:2")
    out = batch.d / "ray_fault_always"
    assert main(batch.base + ["--out", str(out), "--cluster", "ray", "--workers", "1"]) == 4
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("volcomp compensate")]
    assert len(err) == 1 and f"chunk 2 (points {2 * CHUNK_POINTS}-{3 * CHUNK_POINTS - 1}) of " in err[0]
    assert "big.csv failed on the Ray cluster after 2 retries" in err[0] and "nothing was written" in err[0]
    assert not out.exists() or not any(out.iterdir())


def _fleet_inputs(d: Path, grinder) -> Path:
    from errormap.chain_truth import ChainTruth
    from errormap.chain_sweeps import simulated_sweeps
    from errormap.sweeps import write_sweeps
    for seed in (1, 2):
        truth = make_chain_truth(grinder, seed)
        write_sweeps(d / f"m{seed}" / "sweeps.csv", simulated_sweeps(ChainTruth(grinder, truth.elements, {}),
                                                                     seed=seed), comments=["setup: s1"])
        write_csv(d / f"m{seed}" / "checks.csv", truth.check_measurements(n=150, seed=seed + 10),
                  header_comments=["format: volcomp-checks/1"])
    fleet = d / "fleet.toml"
    fleet.write_text('format = "volcomp-fleet/1"\n\n'
                     '[[machine]]\nname = "g1"\nsweeps = "m1/sweeps.csv"\nchecks = "m1/checks.csv"\n\n'
                     f'[[machine]]\nname = "g2"\nmachine = "{grinder.path}"\nsweeps = ["m2/sweeps.csv"]\n'
                     'checks = "m2/checks.csv"\n')
    return fleet


def test_fleet_refuses_a_file_store_for_several_writers(tmp_path, grinder, capsys, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    fleet = _fleet_inputs(tmp_path, grinder)
    rc = main(["fleet", str(fleet), "--out", str(tmp_path / "out"), "--cluster", "ray",
               "--tracking-uri", f"sqlite:///{tmp_path / 'm.db'}"])
    assert rc == 2 and "tracking server" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() and not (tmp_path / "m.db").exists()   # refused before the store is opened


def test_fleet_on_ray_tracked_on_a_server(ray_session, mlflow_server, grinder, capsys):
    from mlflow.tracking import MlflowClient

    from errormap.chain_elements import ChainElementSet
    from errormap.sweeps import read_sweeps
    from errormap.estimators import Identification
    url, tmp = mlflow_server
    fleet = _fleet_inputs(tmp, grinder)
    out = tmp / "fleet_out"
    rc = main(["fleet", str(fleet), "--out", str(out), "--cluster", "ray", "--tracking-uri", url, *FLEET_OPTIONS])
    assert rc == 0, capsys.readouterr().err
    summary = json.loads((out / "fleet_summary.json").read_text())
    assert [m["status"] for m in summary["machines"]] == ["ok", "ok"] and summary["ran_on"].startswith("Ray")
    assert summary["settings"]["learned"] is False
    client = MlflowClient(tracking_uri=url)
    for m in summary["machines"]:
        run = client.get_run(m["run_id"])
        assert run.data.tags["fleet_machine"] == m["name"]
        assert run.data.params["max_iter"] == str(TRAIN_ITER)
        diag = json.loads((out / m["name"] / "diagnosis" / "diagnosis.json").read_text())
        assert "learned_residual" not in diag   # --no-learned reached the Ray task's diagnosis
        # the figures logged to the server are the machine's own diagnosis (measured residual)
        assert run.data.metrics["diagnose_heldout_rms_final_um"] == diag["held_out_rms_um"]   # the kept stage's
        assert run.data.metrics["diagnose_heldout_rms_identified_um"] == diag["stages"]["identified"]["held_out"][
            "rms_um"]
    # the artifacts went through the server into its artifact folder (model and diagnosis, per machine's run)
    for m in summary["machines"]:
        for name in ("weights.npy", "diagnosis.json"):
            assert len([p for p in (tmp / "art").rglob(name) if m["run_id"] in p.parts]) == 1, (m["name"], name)
    # the Ray task identified what an in-process identification of the same sweeps gives
    ref = Identification(grinder, n_boot=4, seed=0).fit(read_sweeps([str(tmp / "m1" / "sweeps.csv")], grinder)).elements_
    got = ChainElementSet.load(out / "g1" / "elements.json", grinder)
    pts = random_axes(grinder, 200, np.random.default_rng(0))
    assert np.abs(got.values(pts) - ref.values(pts)).max() < IDENTIFY_TOL
