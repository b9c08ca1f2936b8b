"""MLflow tracking: every fit is a run; trained fields load back by run id or URI.

Store: ``MLFLOW_TRACKING_URI`` or an explicit ``tracking_uri``; otherwise an embedded SQLite store at
``runs/mlflow.db`` with artifacts under ``runs/artifacts`` in the working folder (for any
``sqlite:///…/name.db`` store, ``artifacts/`` beside the database file): docs/reference/file-formats.md
("The MLflow store"). A run holds parameters (architecture, trainer, stopping rules, seed, data and machine
SHA-256, ...), metrics (``loss`` per iteration, ``train_*``/``val_*`` max and RMS in μm), artifacts
(``model/``, an MLflow pyfunc model, :mod:`training.pyfunc`; the fit plots; ``metrics.json``) and tags."""
from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from pathlib import Path

from errormap.io import InputError, read_document_text

RUN_ID_RE = re.compile(r"^[0-9a-f]{32}$")
MODEL_ARTIFACT = "model"


def default_tracking_uri() -> str:
    """``MLFLOW_TRACKING_URI`` if set, else ``sqlite:///<working folder>/runs/mlflow.db`` (absolute)."""
    env = os.environ.get("MLFLOW_TRACKING_URI")
    if env:
        return env
    return f"sqlite:///{Path.cwd().resolve() / 'runs' / 'mlflow.db'}"


def _artifact_root(uri: str) -> str | None:
    """Where a new experiment's artifacts go for a SQLite store: ``artifacts/`` beside the db."""
    if uri.startswith("sqlite:///"):
        db = Path(uri[len("sqlite:///"):])
        return (db.parent / "artifacts").resolve().as_uri()
    return None


def _client(tracking_uri: str | None):
    """``(MlflowClient, uri)`` of the store; a store MLflow refuses to open (an unknown scheme, the retired
    ``file:`` store) is an :class:`InputError` naming ``--tracking-uri`` (or ``MLFLOW_TRACKING_URI``)."""
    from mlflow.tracking import MlflowClient
    uri = tracking_uri or default_tracking_uri()
    if uri.startswith("sqlite:///"):
        Path(uri[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
    try:
        return MlflowClient(tracking_uri=uri), uri
    except Exception as exc:   # MlflowException, UnsupportedModelRegistryStoreURIException: the store, not a defect
        where = "--tracking-uri" if tracking_uri else "MLFLOW_TRACKING_URI"
        why = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:90].rstrip()
        raise InputError(f"{where} {uri}: MLflow cannot open this store ({why}); use sqlite:///PATH/mlflow.db or a "
                         "tracking server's http(s):// address") from None


def check_tracking_uri(tracking_uri: str | None) -> None:
    """Open the store named by ``tracking_uri`` before a command's work (its refusal then comes first, not
    after a training); None: nothing to check (the default store is opened when it is used)."""
    if tracking_uri:
        _client(tracking_uri)


def _experiment_id(client, uri: str, name: str) -> str:
    exp = client.get_experiment_by_name(name)
    if exp is not None:
        return exp.experiment_id
    try:
        return client.create_experiment(name, artifact_location=_artifact_root(uri))
    except Exception:  # created concurrently by another process
        exp = client.get_experiment_by_name(name)
        if exp is None:
            raise
        return exp.experiment_id


def log_fit(params: dict, metrics: dict, history, model_dir, artifacts, *, tracking_uri=None,
            run_name=None, parent_run_id=None, tags=None, experiment: str = "volcomp-field",
            machine_file=None) -> str:
    """Record one fit as an MLflow run; returns its run id.

    ``history`` has ``loss`` and ``elapsed_s`` per iteration (logged as metric ``loss``
    with ``step`` = iteration); ``model_dir`` goes to artifact path ``model/`` (as a pyfunc model of the
    network, :mod:`training.pyfunc`);
    ``artifacts`` (files) go to the run's root.
    """
    from mlflow.entities import Metric, Param
    client, uri = _client(tracking_uri)
    exp_id = _experiment_id(client, uri, experiment)
    run_tags = {k: str(v) for k, v in (tags or {}).items() if v is not None}
    if parent_run_id:
        run_tags["mlflow.parentRunId"] = parent_run_id
    run = client.create_run(exp_id, run_name=run_name, tags=run_tags)
    rid = run.info.run_id
    status = "FAILED"
    try:
        ps = [Param(k, str(v)[:6000]) for k, v in params.items()]
        for i in range(0, len(ps), 100):
            client.log_batch(rid, params=ps[i:i + 100])
        now = int(time.time() * 1000)
        ms = [Metric("loss", float(l), now, i + 1) for i, l in enumerate(history.loss)]
        ms += [Metric(k, float(v), now, 0) for k, v in metrics.items()]
        for i in range(0, len(ms), 1000):
            client.log_batch(rid, metrics=ms[i:i + 1000])
        with tempfile.TemporaryDirectory(prefix="volcomp-pyfunc-") as tmp:
            from .pyfunc import save_pyfunc
            client.log_artifacts(rid, str(save_pyfunc(model_dir, Path(tmp) / MODEL_ARTIFACT, machine_file)),
                                 MODEL_ARTIFACT)
        for a in artifacts:
            client.log_artifact(rid, str(a))
        status = "FINISHED"
    finally:
        client.set_terminated(rid, status)
    return rid


LEARNED_RESIDUAL_EXPERIMENT = "volcomp-learned-residual"
LEARNED_RESIDUAL_FILE = "learned_residual.json"


def _numeric_leaves(prefix: str, doc) -> dict:
    """``{prefix.key.sub: float}`` for every finite number in a nested dict (MLflow metric names)."""
    out = {}
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.update(_numeric_leaves(f"{prefix}.{k}" if prefix else str(k), v))
    elif isinstance(doc, (int, float)) and not isinstance(doc, bool):
        import math
        if math.isfinite(float(doc)):
            out[re.sub(r"[^0-9A-Za-z_.\-/ ]", "_", prefix)] = float(doc)
    return out


def log_learned_residual(stage: dict, learned_doc: dict, *, model_doc: dict | None = None, tracking_uri=None,
                         run_name=None, tags=None, experiment: str = LEARNED_RESIDUAL_EXPERIMENT) -> str:
    """Record the closed loop's kept learned residual as an MLflow run; returns its run id.

    ``stage``: the stage's summary (``diagnosis.json`` ``stages.learned_residual``: ``learned`` with
    the chosen family, the blocked-CV table, the held-out gate; ``held_out`` / ``fitting`` statistics);
    ``learned_doc``: the learned residual's JSON (what ``model.json`` holds under ``learned_residual``);
    ``model_doc``: the whole ``model.json`` (logged beside it when given).
    Params: family, inputs, output frame, CV scheme, base stage, kept; metrics: every number of the held-out and
    fitting statistics and of the gate (``held_out.rms_um``, ``learned.held_out_gain_z``, ...) and
    the CV table (``cv_table.<family>.<column>``); artifacts: ``learned_residual.json``,
    ``stage.json`` (the summary with its CV table), ``model.json``. Tag ``kind = learned_residual``.
    """
    import json

    from mlflow.entities import Metric, Param
    client, uri = _client(tracking_uri)
    exp_id = _experiment_id(client, uri, experiment)
    learned = stage.get("learned", {})
    run_tags = {"kind": "learned_residual", **{k: str(v) for k, v in (tags or {}).items() if v is not None}}
    run = client.create_run(exp_id, run_name=run_name or f"learned residual ({learned.get('family', '?')})",
                            tags=run_tags)
    rid = run.info.run_id
    status = "FAILED"
    try:
        params = {"family": learned.get("family", ""), "inputs": ",".join(learned.get("inputs", [])),
                  "output_frame": learned.get("output_frame", "work"),
                  "cv": learned.get("cv", ""), "kept": learned.get("kept", ""), "why": learned.get("why", ""),
                  "base_stage": stage.get("base_stage", "")}
        client.log_batch(rid, params=[Param(k, str(v)[:6000]) for k, v in params.items()])
        now = int(time.time() * 1000)
        figures = {**_numeric_leaves("held_out", stage.get("held_out", {})),
                   **_numeric_leaves("fitting", stage.get("fitting", {})),
                   **_numeric_leaves("cv_table", learned.get("cv_table", {})),
                   **{f"learned.{k}": v for k, v in _numeric_leaves("", {k: learned.get(k) for k in (
                       "held_out_gain_um2", "held_out_gain_se_um2", "held_out_gain_z", "held_out_band95_cover")}).items()}}
        ms = [Metric(k, v, now, 0) for k, v in figures.items()]
        for i in range(0, len(ms), 1000):
            client.log_batch(rid, metrics=ms[i:i + 1000])
        with tempfile.TemporaryDirectory(prefix="volcomp-learned-") as tmp:
            files = {LEARNED_RESIDUAL_FILE: learned_doc, "stage.json": stage}
            if model_doc is not None:
                files["model.json"] = model_doc
            for name, doc in files.items():
                (Path(tmp) / name).write_text(json.dumps(doc, indent=1, default=str), encoding="utf-8")
                client.log_artifact(rid, str(Path(tmp) / name))
        status = "FINISHED"
    finally:
        client.set_terminated(rid, status)
    return rid


PROGRESS_BAR_ENV = "MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR"
"""MLflow's switch for its artifact download bar: off for volcomp's downloads unless the user set it (a model of a
few kB downloads at once; its bar wrote 13 lines of ``Downloading artifacts`` into a compensate's log)."""


def _download(artifact_uri: str, dst_path: str, tracking_uri: str) -> Path:
    """``mlflow.artifacts.download_artifacts`` without MLflow's progress bar (:data:`PROGRESS_BAR_ENV`; a value the
    user set is kept), the environment as it was after."""
    from mlflow.artifacts import download_artifacts
    user_set = PROGRESS_BAR_ENV in os.environ
    if not user_set:
        os.environ[PROGRESS_BAR_ENV] = "false"
    try:
        return Path(download_artifacts(artifact_uri=artifact_uri, dst_path=dst_path, tracking_uri=tracking_uri))
    finally:
        if not user_set:
            os.environ.pop(PROGRESS_BAR_ENV, None)


def load_learned_residual_doc(run_id: str, tracking_uri: str | None = None) -> dict:
    """The ``learned_residual.json`` a :func:`log_learned_residual` run holds (a dict)."""
    import json

    uri_store = tracking_uri or default_tracking_uri()
    with tempfile.TemporaryDirectory(prefix="volcomp-learned-") as tmp:
        try:
            p = _download(f"runs:/{run_id}/{LEARNED_RESIDUAL_FILE}", tmp, uri_store)
        except Exception as exc:
            raise InputError(f"{run_id}: no learned residual in MLflow store {uri_store}: "
                             f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
        return json.loads(read_document_text(p, "a JSON record"))


def register_model(run_id: str, name: str, tracking_uri: str | None = None) -> str:
    """Register a run's ``model/`` artifact as a new version of ``name``; returns ``models:/name/version``."""
    from mlflow.tracking import MlflowClient
    _, uri = _client(tracking_uri)
    client = MlflowClient(tracking_uri=uri, registry_uri=uri)
    try:
        client.create_registered_model(name)
    except Exception:  # already exists
        pass
    src = client.get_run(run_id).info.artifact_uri.rstrip("/") + f"/{MODEL_ARTIFACT}"
    mv = client.create_model_version(name, src, run_id=run_id)
    return f"models:/{name}/{mv.version}"


def _model_version_source(uri: str, store: str) -> str:
    """``models:/name/version``, ``models:/name/latest`` or ``models:/name@alias`` -> artifact URI,
    resolved in the registry of the same store (MLflow would otherwise use its global registry URI)."""
    from mlflow.tracking import MlflowClient
    c = MlflowClient(tracking_uri=store, registry_uri=store)
    body = uri[len("models:/"):].strip("/")
    if "@" in body:
        name, alias = body.split("@", 1)
        version = c.get_model_version_by_alias(name, alias).version
    else:
        name, _, version = body.partition("/")
        if version in ("", "latest"):
            versions = c.search_model_versions(f"name='{name}'")
            if not versions:
                raise InputError(f"{uri}: registered model {name!r} has no versions")
            version = str(max(int(v.version) for v in versions))
    return c.get_model_version_download_uri(name, version)


def load_field(spec: str, tracking_uri: str | None = None, loader=None):
    """A trained network from a run id, ``runs:/<id>[/path]``, ``models:/<name>/<version>`` or a local model
    directory, as its ``config.json`` names it (:meth:`training.model.MLPField.load`); ``loader(folder)``
    another loader."""
    from .model import MLPField
    load = loader or MLPField.load
    spec = str(spec).strip()
    p = Path(spec)
    if p.is_dir():
        return load(p / MODEL_ARTIFACT if (p / MODEL_ARTIFACT / "config.json").is_file() else p)
    if RUN_ID_RE.match(spec):
        uri = f"runs:/{spec}/{MODEL_ARTIFACT}"
    elif spec.startswith("runs:/"):
        parts = spec[len("runs:/"):].strip("/").split("/", 1)
        uri = spec if len(parts) == 2 and parts[1] else f"runs:/{parts[0]}/{MODEL_ARTIFACT}"
    elif spec.startswith("models:/"):
        uri = spec
    else:
        raise InputError(f"{spec}: not a model directory, MLflow run id (32 hex digits), runs:/ or models:/ URI")
    uri_store = tracking_uri or default_tracking_uri()
    tmp = tempfile.mkdtemp(prefix="volcomp-model-")
    try:
        try:
            if uri.startswith("models:/"):
                uri = _model_version_source(uri, uri_store)
            local = _download(uri, tmp, uri_store)
        except Exception as exc:  # MlflowException, OSError: report in one line
            raise InputError(f"{spec}: cannot load a trained model from MLflow store {uri_store}: "
                             f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
        if (local / MODEL_ARTIFACT / "config.json").is_file():
            local = local / MODEL_ARTIFACT
        return load(local)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
