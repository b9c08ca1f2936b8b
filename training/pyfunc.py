"""The learned field as an MLflow ``pyfunc`` model.

A run's ``model/`` artifact is a pyfunc model folder (``MLmodel``: flavor ``python_function``, loader module
``training.pyfunc``, signature the network's axis columns (x_mm, z_mm, a_deg on the grinder) -> dx_um, dy_um,
dz_um; ``input_example.json``; the network's files (:meth:`training.model.MLPField.save`); ``machine.toml`` when
known), so ``mlflow models serve`` and ``mlflow.pyfunc.load_model(...).predict(df)`` work on it and ``volcomp
--model <run id>`` loads it. It predicts exactly what the network's ``predict`` does and applies no guard.
docs/reference/file-formats.md."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

OUTPUTS = ("dx_um", "dy_um", "dz_um")


class PyfuncField:
    """What ``mlflow.pyfunc.load_model`` wraps: ``predict(DataFrame[<the network's axis columns>]) ->
    DataFrame[dx_um, dy_um, dz_um]`` (μm), one row per point."""

    def __init__(self, field):
        self.field = field
        self.inputs = tuple(field.config()["inputs"])

    def predict(self, model_input, params=None):
        import pandas as pd
        df = pd.DataFrame(model_input)
        missing = [c for c in self.inputs if c not in df.columns]
        if missing:
            raise ValueError(f"Expected columns {list(self.inputs)}, missing {missing}")
        e = self.field.predict(df[list(self.inputs)].to_numpy(dtype=float))
        return pd.DataFrame(np.asarray(e, dtype=float), columns=list(OUTPUTS), index=df.index)


def _load_pyfunc(data_path):
    """MLflow's entry point (``loader_module``): ``data_path`` is the ``model/`` folder itself."""
    from .model import MLPField
    return PyfuncField(MLPField.load(data_path))


def save_pyfunc(model_dir, out_dir, machine_file=None) -> Path:
    """Write the pyfunc folder ``out_dir`` (new) for the network saved in ``model_dir``, with the
    machine file when given, the signature and an input example; returns ``out_dir``."""
    import mlflow.pyfunc
    import pandas as pd
    from mlflow.models import Model, infer_signature

    from .model import MLPField
    model_dir, out_dir = Path(model_dir), Path(out_dir)
    field = PyfuncField(MLPField.load(model_dir))
    lo, hi = np.asarray(field.field.in_lo_, dtype=float), np.asarray(field.field.in_hi_, dtype=float)
    example = pd.DataFrame(lo + (hi - lo) * np.array([[0.25], [0.5], [0.75]]), columns=list(field.inputs))
    mlflow.pyfunc.save_model(str(out_dir), loader_module="training.pyfunc",
                             signature=infer_signature(example, field.predict(example)),
                             input_example=example, pip_requirements=["volcomp"])
    for p in model_dir.iterdir():
        shutil.copyfile(p, out_dir / p.name)
    if machine_file is not None:
        shutil.copyfile(machine_file, out_dir / "machine.toml")
    # the network's files sit beside MLmodel: the flavor's data folder is the model folder itself
    mlm = Model.load(str(out_dir / "MLmodel"))
    mlm.flavors["python_function"]["data"] = "."
    mlm.save(str(out_dir / "MLmodel"))
    return out_dir
