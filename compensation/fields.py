"""Recognising what the user names as ``--model``, and the diagnosis verdict that governs it.

``--model`` accepts a ``model.json`` (``volcomp-model/1``), any older model file (an element set, a closed
loop's ``model.json``), a trained model folder or an MLflow run id / ``runs:/<id>/...`` / ``models:/...`` URI of
a trained network; :func:`compensation.model_file.read_model` reads each (the one reader).

A file is recognised by its content, never by its name: :func:`resolve_model` reads the JSON's
``format`` key (``schema`` for a drift model), a folder by the ``config.json`` of a trained model
inside it (or in its ``model/`` sub-folder, a training run folder). Only a name that is neither a
file nor a folder is taken for an MLflow reference, and then only in the forms MLflow knows.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

from errormap.io import InputError, read_document_text
from errormap.pkm.calibration_file import CALIBRATION_FORMAT as PKM_FORMAT   # a parallel machine's calibration

MODEL_FORMAT = "volcomp-model/1"         # model.json (errormap/diagnosis/loop_model.py writes it)
ELEMENTS_FORMAT = "volcomp-elements/1"
DIAGNOSED_FORMAT = "volcomp-diagnosed-model/1"
CHAIN_MODEL_FORMAT = "volcomp-chain-model/1"  # model.json of diagnose on a machine-tool chain (errormap/diagnosis/loop_model.py)
NETWORK_FORMAT = "volcomp-mlpfield/1"      # config.json of a trained model folder (training/model.py)
CHAIN_NETWORK_FORMAT = "volcomp-chain-mlpfield/1"  # the same over a machine-tool chain (training/model.py)
ARM_FORMAT = "volcomp-arm-calibration/4"  # an arm model.json's calibration section (compensation/calibration_models.py)
ARM_READ_FORMATS = (ARM_FORMAT, "volcomp-arm-calibration/3", "volcomp-arm-calibration/2")
"""Arm calibrations read, bare (an older ``calibration.json``) or as a model.json's section (/2: before the stacked
stage; /3: before the base frame was kept apart from the link parameters; their stages are all readable as /4's)."""
FAMILY_KINDS = {"arm": "arm-model", "parallel": "pkm-model"}
"""A model.json's key ``family`` (absent: a machine tool's) → its kind."""
DRIFT_SCHEMA = "volcomp.drift_model"       # the drift model's key 'schema' (errormap/diagnosis/drift_models.py)
_RUN_ID = re.compile(r"^[0-9a-f]{32}$")    # an MLflow run id (training/tracking.py RUN_ID_RE)

KIND_NAMES = {"model": f"model ({MODEL_FORMAT})",
              "elements": f"element set ({ELEMENTS_FORMAT})",
              "diagnosed": f"diagnosed model ({DIAGNOSED_FORMAT})",
              "chain-model": f"diagnosed chain model ({CHAIN_MODEL_FORMAT})",
              "arm-model": f"arm calibration model ({MODEL_FORMAT})",
              "pkm-model": f"parallel machine calibration model ({MODEL_FORMAT})",
              "arm-calibration": "arm calibration (volcomp-arm-calibration/2 to /4)",
              "pkm-calibration": f"parallel machine calibration ({PKM_FORMAT})",
              "drift": f"drift model ({DRIFT_SCHEMA})",
              "network": f"trained model folder ({NETWORK_FORMAT})",
              "chain-network": f"trained chain model folder ({CHAIN_NETWORK_FORMAT})",
              "mlflow": "trained model in MLflow"}
"""Each model kind as a person reads it (printed and recorded by every command that loads one)."""


@dataclass(frozen=True)
class ModelSource:
    """What ``--model`` names, recognised by content: ``kind`` (a key of :data:`KIND_NAMES`),
    ``spec`` as given, ``path`` the file or folder that holds it (None for an MLflow reference)."""

    kind: str
    spec: str
    path: Path | None

    @property
    def description(self) -> str:
        return f"{KIND_NAMES[self.kind]}: {self.path if self.path is not None else self.spec}"

    def to_dict(self) -> dict:
        """The record a command writes into its output (summary JSON)."""
        return {"kind": self.kind, "kind_name": KIND_NAMES[self.kind], "spec": self.spec,
                "path": str(self.path) if self.path is not None else None}


def _json_format(path: Path) -> str | None:
    """The kind of the JSON model file ``path`` from its ``format`` / ``schema`` key (InputError when
    the file is not JSON or names no model format volcomp reads)."""
    try:
        d = json.loads(read_document_text(path, "a model file"))
    except (json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not a model file (not JSON: {exc}); expected {_EXPECTED}") from None
    if not isinstance(d, dict):
        raise InputError(f"{path}: not a model file (JSON {type(d).__name__}, no key 'format'); expected {_EXPECTED}")
    fmt = d.get("format")
    if fmt == MODEL_FORMAT:
        if d.get("family") is not None and d.get("family") not in FAMILY_KINDS:
            raise InputError(f"{path}: key 'family': {d.get('family')!r}; expected one of "
                             f"{', '.join(FAMILY_KINDS)} (absent: a machine tool's model)")
        return FAMILY_KINDS.get(d.get("family"), "model")
    if fmt in ARM_READ_FORMATS:
        return "arm-calibration"
    if fmt == PKM_FORMAT or (fmt is None and "identified_machine" in d and "kind" in d):
        return "pkm-calibration"
    if fmt == ELEMENTS_FORMAT:
        return "elements"
    if fmt == DIAGNOSED_FORMAT:
        return "diagnosed"
    if fmt == CHAIN_MODEL_FORMAT:
        return "chain-model"
    if fmt == NETWORK_FORMAT:
        return "network"
    if fmt == CHAIN_NETWORK_FORMAT:
        return "chain-network"
    if d.get("schema") == DRIFT_SCHEMA:
        return "drift"
    got = repr(str(fmt)) if fmt is not None else "missing"
    raise InputError(f"{path}: key 'format': {got}; not a model file volcomp reads (expected {_EXPECTED})")


_EXPECTED = (f"a model.json ({MODEL_FORMAT!r}) or an older model file: an element set, a closed loop's model.json, "
             "an arm's or PKM's calibration.json, a drift model or a trained model folder")


MODEL_FILES_IN_FOLDER = ("model.json", "calibration.json")
"""A folder named as a model is read as the model file in it (``calibrate --out DIR``: an arm's or parallel
machine's), after a trained model folder's ``config.json``."""


def resolve_model(spec) -> ModelSource:
    """Recognise ``spec`` by content (see module doc); InputError for anything else."""
    spec = str(spec).strip()
    p = Path(spec)
    if p.is_file():
        kind = _json_format(p)
        # a trained model's config.json names its folder
        return ModelSource(kind, spec, p.parent if kind in ("network", "chain-network") else p)
    if p.is_dir():
        for d in (p, p / "model"):
            if (d / "config.json").is_file():
                kind = _json_format(d / "config.json")
                if kind in ("network", "chain-network"):
                    return ModelSource(kind, spec, d)
        for name in MODEL_FILES_IN_FOLDER:      # the folder a command wrote its model file in
            if (p / name).is_file():
                return resolve_model(p / name)
        raise InputError(f"{p}: a folder, but not a trained model folder (no config.json of format "
                         f"{NETWORK_FORMAT!r} in it or in {p / 'model'}) and no model.json in it; expected {_EXPECTED}")
    if _RUN_ID.match(spec) or spec.startswith(("runs:/", "models:/")):
        return ModelSource("mlflow", spec, None)
    raise InputError(f"{spec}: no such file or folder, and not an MLflow run id (32 hex digits), runs:/ or "
                     "models:/ URI")


def require_kind(src: ModelSource, kinds, what: str) -> ModelSource:
    """Refuse (InputError, one line) a model whose kind is not in ``kinds``; ``what``: what the
    command does with it (\"predict evaluates\")."""
    if src.kind not in kinds:
        want = ", ".join(KIND_NAMES[k].split(" (")[0] for k in kinds)
        hint = {"drift": "; a drift model is applied by `volcomp drift-predict` and exported with `volcomp export "
                         "--format drift`",
                "diagnosed": "; `volcomp compensate` takes a diagnosed model.json",
                "chain-model": "; a chain's model.json is for `predict` / `compensate` with --machine",
                "model": "; a model.json is for `predict`, `compensate`, `export` and `report`"}.get(src.kind, "")
        name = KIND_NAMES[src.kind]
        article = "an" if name[0] in "aeiou" else "a"
        raise InputError(f"{src.path or src.spec}: {article} {name}, but {what} one of: {want}{hint}")
    return src


# --- the diagnosis's verdict ---------------------------------------------------------------------
FAILED_VERDICT = "failed-verdict"
"""The ``--allow`` name that uses a model whose diagnosis verdict failed (compensate, predict, export)."""
DIAGNOSIS_NAME = "diagnosis.json"   # written beside the model by volcomp diagnose


def verdict_of(path) -> dict | None:
    """The diagnosis verdict that governs the model file ``path``: its own key ``verdict`` (a diagnosed
    model.json), else that of the ``diagnosis.json`` written beside it by the same diagnose run (its
    ``updated_elements.json``, a drift model). ``{"status", "reasons", "file"}``; None: no verdict."""
    from errormap.io import read_json
    path = Path(path)
    if path.is_dir():   # the model file in the folder (a trained model folder: none, no diagnosis verdict)
        path = next((path / n for n in MODEL_FILES_IN_FOLDER if (path / n).is_file()), None)
        if path is None:
            return None
    for f in (path, path.parent / DIAGNOSIS_NAME):
        if not f.is_file():
            continue
        doc = read_json(f, "a model or its diagnosis")
        v = doc.get("verdict") if isinstance(doc, dict) else None
        if isinstance(v, dict) and v.get("status") in ("passed", "failed"):
            return {"status": v["status"], "reasons": [str(r) for r in v.get("reasons") or []], "file": str(f),
                    "model": str(path)}
    return None


def check_verdict(path, allowed: bool) -> dict | None:
    """Refuse (InputError, exit 2) the model file ``path`` when its diagnosis verdict failed, naming the
    file and the verdict's reasons, unless ``allowed`` (``--allow failed-verdict``): then a warning on
    stderr, and the returned record (``overridden_by`` set) is what the command writes into its output.
    Returns the verdict record (None: the model carries none)."""
    v = verdict_of(path) if path is not None else None
    if v is None or v["status"] != "failed":
        return v
    why = "; ".join(v["reasons"]) or "no reasons recorded"
    if not allowed:
        of = "" if v["file"] == v["model"] else f" of {Path(v['model']).name}"
        raise InputError(f"{v['file']}: the diagnosis verdict{of} failed, so the model is not used (--allow "
                         f"{FAILED_VERDICT} uses it, recorded in the output): {why}")
    import sys
    print(f"warning: {v['file']}: the diagnosis verdict of {v['model']} is failed ({why}); used as --allow {FAILED_VERDICT} asks "
          "(recorded in the output)", file=sys.stderr)
    return dict(v, overridden_by=f"--allow {FAILED_VERDICT}")


def verdict_notes(verdict) -> list[str]:
    """The comment line a compensated program carries when its model's failed verdict was overridden
    (``check_verdict``'s record; [] otherwise), ASCII: a G-code program is written in Latin-1."""
    if not verdict or not verdict.get("overridden_by"):
        return []
    text = (f"volcomp compensate: MODEL DIAGNOSIS VERDICT FAILED ({verdict['file']}), used with --allow "
            f"{FAILED_VERDICT}; reasons in the summary")
    return [text.encode("ascii", "replace").decode("ascii")]
