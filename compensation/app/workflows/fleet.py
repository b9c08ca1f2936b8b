"""The fleet: identify → train → diagnose for every machine of a fleet file, one task per machine.

A fleet file (TOML, ``format = "volcomp-fleet/1"``, docs/reference/file-formats.md) lists machines (any
machine tool), each with its tracker sweeps and check measurements. Per machine (:func:`run_machine`), into
``DIR/<name>/``: identify (``elements.json``, ``elements.cov.npz``, ``identify_report.json``), train on the
identified set's feature points (``featurepoints.csv``, ``train/``, an MLflow run), diagnose the checks
(``diagnosis/``, the MEASURED residual), ``machine_summary.json`` last. Every input is validated on the driver
before any work (exit 2); with ``--cluster ray`` each machine is one Ray task, else they run one after
another; a machine that fails is reported and its folder removed. ``DIR/fleet_summary.json`` last. Several
machines training at once need a tracking server (``http(s)://``), never one SQLite file.
docs/how-to/scale-out.md ("The fleet").
"""
from __future__ import annotations

import re
import shutil
import sys
import time
import tomllib
from pathlib import Path

from errormap.io import InputError, read_document_bytes, write_json

FORMAT = "volcomp-fleet/1"
SUMMARY_NAME = "fleet_summary.json"
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
SERVER_SCHEMES = ("http://", "https://", "databricks")
MACHINE_KEYS = {"name", "machine", "sweeps", "checks", "noise_um"}


def _fail(path, key, msg):
    raise InputError(f"{path}: key '{key}': {msg}")


def read_fleet(path) -> list[dict]:
    """The machines of a fleet file: dicts with ``name``, ``machine`` (path or None),
    ``sweeps`` (list of paths), ``checks`` (path), ``noise_um`` (float or None); paths are
    resolved against the fleet file's folder and must exist."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such fleet file")
    try:
        doc = tomllib.loads(read_document_bytes(path, "a fleet file").decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: byte {exc.start}: not UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not TOML ({exc})") from None
    if doc.get("format") != FORMAT:
        _fail(path, "format", f"expected {FORMAT!r}, got {doc.get('format')!r}")
    extra = sorted(set(doc) - {"format", "machine"})
    if extra:
        _fail(path, extra[0], "unknown key (expected 'format' and [[machine]] tables)")
    machines = doc.get("machine")
    if not isinstance(machines, list) or not machines or not all(isinstance(m, dict) for m in machines):
        _fail(path, "machine", "expected one or more [[machine]] tables")
    base = path.parent
    out, seen = [], set()

    def file_(key, value):
        if not isinstance(value, str) or not value:
            _fail(path, key, f"expected a file path (string), got {value!r}")
        p = (base / value) if not Path(value).is_absolute() else Path(value)
        if not p.is_file():
            _fail(path, key, f"no such file: {p}")
        return p.resolve()

    def machine_(key, value):
        """A machine file, or a built-in machine's name (``mill-xyz``) as ``--machine`` takes it."""
        from errormap.machine import builtin_named
        builtin = builtin_named(value) if isinstance(value, str) and "/" not in value and "." not in value else None
        return builtin.resolve() if builtin is not None else file_(key, value)

    for i, m in enumerate(machines):
        k = f"machine[{i}]"
        bad = sorted(set(m) - MACHINE_KEYS)
        if bad:
            _fail(path, f"{k}.{bad[0]}", f"unknown key (expected {sorted(MACHINE_KEYS)})")
        name = m.get("name")
        if not isinstance(name, str) or not NAME_RE.match(name):
            _fail(path, f"{k}.name", f"expected a folder name of letters, digits, '.', '_', '-' "
                                     f"(at most 64, not starting with '.'), got {name!r}")
        if name in seen:
            _fail(path, f"{k}.name", f"{name!r} appears twice")
        seen.add(name)
        sweeps = m.get("sweeps")
        sweeps = [sweeps] if isinstance(sweeps, str) else sweeps
        if not isinstance(sweeps, list) or not sweeps:
            _fail(path, f"{k}.sweeps", f"expected a sweep file or a list of them, got {m.get('sweeps')!r}")
        noise = m.get("noise_um")
        if noise is not None and (isinstance(noise, bool) or not isinstance(noise, (int, float)) or not noise > 0):
            _fail(path, f"{k}.noise_um", f"expected a tracker noise σ > 0 in μm, got {noise!r}")
        out.append({"name": name, "machine": machine_(f"{k}.machine", m["machine"]) if "machine" in m else None,
                    "sweeps": [file_(f"{k}.sweeps[{j}]", s) for j, s in enumerate(sweeps)],
                    "checks": file_(f"{k}.checks", m.get("checks")),
                    "noise_um": None if noise is None else float(noise), "fleet_file": str(path), "key": k})
    return out


def validate_inputs(machines) -> None:
    """Read every machine file, sweep set and check file (raises InputError / MachineFileError
    naming file, row and column) — before any work starts."""
    from errormap.sweeps import read_sweeps
    from errormap.diagnosis.chain_checks import load_chain_checks
    from errormap.machine import load_machine
    from ..families import family_of
    for m in machines:
        machine = load_machine(m["machine"])
        family_of(machine).target("fleet")   # every machine tool; an arm or a parallel machine refused
        read_sweeps(m["sweeps"], machine)   # one tracker set-up: one file, or several naming the same set-up
        load_chain_checks(m["checks"], machine)   # the reader the loop itself uses (diagnose_chain)


def check_tracking_uri(uri: str, n_machines: int, on_cluster: bool) -> None:
    """Refuse a file-based MLflow store when several machines would write to it at once."""
    from ..validate import UsageError
    if on_cluster and n_machines > 1 and not uri.startswith(SERVER_SCHEMES):
        raise UsageError(f"--cluster ray: {n_machines} machines would write to the MLflow store {uri} at once, "
                         "and a SQLite file (or a local file store) is not for many writers (nor seen by other "
                         "nodes); start a tracking server (mlflow server --backend-store-uri ...) and pass "
                         "--tracking-uri http://HOST:PORT")


def _log_to_run(uri: str, run_id: str, metrics: dict, files, tags: dict) -> None:
    from mlflow.tracking import MlflowClient
    client = MlflowClient(tracking_uri=uri)
    for k, v in metrics.items():
        client.log_metric(run_id, k, float(v))
    for k, v in tags.items():
        client.set_tag(run_id, k, str(v))
    for f in files:
        client.log_artifact(run_id, str(f), artifact_path="diagnosis")


STATUS_OK, STATUS_VERDICT_FAILED, STATUS_FAILED = "ok", "verdict-failed", "failed"
"""A machine's ``status`` in the fleet summary: it ran and its diagnosis verdict passed; it ran and the verdict
failed (its files are written, with the verdict in them; never counted as a pass); it did not run (``error``)."""


def machine_status(verdict: dict) -> str:
    """``status`` of a machine that ran, from its diagnosis verdict (:data:`STATUS_OK` only when it passed)."""
    return STATUS_VERDICT_FAILED if verdict.get("status") == "failed" else STATUS_OK


def fleet_counts(results) -> dict:
    """``{"passed": [names], "verdict_failed": [names], "failed": [names]}`` of the machines' summaries."""
    by = {STATUS_OK: "passed", STATUS_VERDICT_FAILED: "verdict_failed"}
    out = {"passed": [], "verdict_failed": [], "failed": []}
    for r in results:
        out[by.get(r.get("status"), "failed")].append(r.get("name"))
    return out


def run_machine(m: dict, out_dir: str, settings: dict) -> dict:
    """Identify → train → diagnose one machine into ``out_dir/<name>``; returns its summary
    (``status`` ``"ok"``, ``"verdict-failed"`` (:func:`machine_status`) or ``"failed"`` with a one-line
    ``error``; a failed machine's folder is removed). ``settings``: ``tracking_uri``, ``train_iter``, ``hidden``, ``bootstrap``,
    ``seed``, ``grid``, ``learned`` (the diagnosis's learned-residual stage; default on), ``threads`` (torch threads, 1 on
    a cluster), ``fleet``."""
    from ..validate import one_line
    t0 = time.perf_counter()
    folder = Path(out_dir) / m["name"]
    if folder.exists():  # a retried task starts clean
        shutil.rmtree(folder)
    try:
        summary = _run_machine(m, folder, settings)
    except Exception as exc:  # reported per machine; the other machines go on
        shutil.rmtree(folder, ignore_errors=True)
        return {"name": m["name"], "status": "failed", "error": one_line(f"{type(exc).__name__}: {exc}"),
                "seconds": time.perf_counter() - t0}
    summary["seconds"] = time.perf_counter() - t0
    write_json(folder / "machine_summary.json", summary)
    return summary


def _identify(machine, m: dict, folder: Path, s: dict) -> tuple:
    """``(elements file, tracker σ μm)`` of ``m``'s sweeps, identified as ``volcomp identify`` identifies every machine
    tool (:func:`.identification.identify_chain_files`), with its covariance and ``identify_report.json``."""
    from errormap.uncertainty import noise_um
    from .identification import identify_chain_files
    sweeps = [str(p) for p in m["sweeps"]]
    el_path, report = folder / "elements.json", folder / "identify_report.json"
    res = identify_chain_files(machine, sweeps, el_path, report=report, noise_um=m["noise_um"],
                               n_boot=s["bootstrap"], seed=s["seed"])[0]
    return el_path, noise_um(res)


def _train(machine, el_path: Path, folder: Path, s: dict, name: str) -> tuple:
    """``(feature points file, run id, iterations, metrics)``: the network trained on the identified set's feature
    points over the machine's axes, tracked as an MLflow run (the feature points say which network: a chain's name
    their axis columns, as ``volcomp train`` reads them)."""
    import numpy as np

    from errormap.featurepoints import make_feature_points
    from errormap.io import sha256_file
    from training import DEFAULT_PHYSICS
    from training.trainers import TrackSettings, TrainSettings, fit_field

    from ...model_file import read_model
    fp = make_feature_points(machine, read_model(str(el_path), machine).field, n=s["grid"],
                             meta={"elements_file": str(el_path), "elements_sha256": sha256_file(el_path)})
    fp_path = fp.save(folder / "featurepoints.csv")
    tags = {"fleet": s["fleet"], "fleet_machine": name, "featurepoints_file": str(fp_path)}
    settings = TrainSettings(max_iter=s["train_iter"], max_time_s=np.inf, seed=s["seed"], hidden=tuple(s["hidden"]),
                             physics=DEFAULT_PHYSICS)   # as `volcomp train` trains by default
    res = fit_field(fp, settings, machine=machine, tracking=TrackSettings(tracking_uri=s["tracking_uri"],
                    run_name=f"fleet {name}", tags=tags), out_dir=folder / "train", quiet=True)
    return fp_path, res.run_id, int(res.history.iterations), res.metrics


def _run_machine(m, folder: Path, s: dict) -> dict:
    from errormap.machine import load_machine
    from errormap.threads import limit_threads

    from .measurement import diagnose_chain
    from ..reports.chain_diagnosis import write_chain_diagnosis_page

    machine = load_machine(m["machine"])   # checked by the fleet's up-front read
    name = m["name"]
    folder.mkdir(parents=True, exist_ok=True)
    with limit_threads(s.get("threads")):
        el_path, noise_um = _identify(machine, m, folder, s)   # 1. identify
        fp_path, run_id, iterations, train_metrics = _train(machine, el_path, folder, s, name)   # 2. train
        # 3. diagnose: the closed loop on the identified set and its covariance (measured residual)
        summary, paths = diagnose_chain(m["checks"], machine, el_path, folder / "diagnosis",
                                        learn=s.get("learned", True))
        paths.append(write_chain_diagnosis_page(folder / "diagnosis", machine))
    st = summary["stages"]
    metrics = {"diagnose_heldout_rms_identified_um": st["identified"]["held_out"]["rms_um"],
               "diagnose_heldout_rms_updated_um": st["updated"]["held_out"]["rms_um"],
               "diagnose_heldout_rms_final_um": summary["held_out_rms_um"],
               "identify_noise_um": noise_um}
    if run_id:
        _log_to_run(s["tracking_uri"], run_id, metrics,
                    [p for p in paths if Path(p).suffix in (".json", ".html")],
                    {"diagnosis_effects": ",".join(f"{e['kind']}:{e['axis']}" for e in summary["effects"]) or "none",
                     "diagnosis_verdict": (summary.get("verdict") or {}).get("status", "passed")})
    verdict = summary.get("verdict") or {"status": "passed", "reasons": []}
    return {"name": name, "status": machine_status(verdict), "verdict": verdict, "machine_file": machine.path,
            "run_id": run_id,
            "tracking_uri": s["tracking_uri"], "train_iterations": iterations,
            "train": {k: float(train_metrics[k]) for k in ("train_max_um", "train_rms_um", "val_max_um", "val_rms_um")
                      if k in train_metrics},
            "residual": "measured (check measurement − model prediction), held-out checks",
            "diagnosis": metrics, "effects": [f"{e['kind']} {e['axis']} {e['element']}" for e in summary["effects"]],
            "files": {"elements": str(el_path), "featurepoints": str(fp_path), "train": str(folder / "train"),
                      "diagnosis": str(folder / "diagnosis")}}


def run_fleet(machines, out_dir, settings: dict, executor=None) -> list[dict]:
    """Every machine's summary, in fleet order: with ``executor`` (a started
    :class:`~.cluster.RayExecutor`) one Ray task per machine, else one after another here."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if executor is None:
        results = []
        for m in machines:
            print(f"fleet: {m['name']}: identify -> train -> diagnose ...", file=sys.stderr)
            results.append(run_machine(m, str(out_dir), settings))
        return results
    def done(name, r):
        status = r.get("status") if isinstance(r, dict) else "lost"
        print(f"fleet: {name}: {status}", file=sys.stderr)

    results = executor.map_function(run_machine, [(m, str(out_dir), dict(settings, threads=1)) for m in machines],
                                    labels=[m["name"] for m in machines], on_done=done)
    return [r if isinstance(r, dict) else {"name": m["name"], "status": "failed", "error": str(r)}
            for m, r in zip(machines, results)]
