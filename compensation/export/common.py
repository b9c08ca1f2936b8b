"""What every controller table shares: format names and limits, the staging folder the files are written
into (renamed into place whole), the manifest, a table evaluated as an error field, and the per-node means
a per-joint table is built from."""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.io import InputError, sidecar_path, write_json

FORMATS = ("iso-tables", "grid", "linuxcnc")
"""The table formats of a volumetric error model; ``drift`` (a drift model's coefficients) is apart."""
ALL_FORMATS = FORMATS + ("drift",)
LINUXCNC_MAX_POINTS = 256
"""LinuxCNC's limit on compensation triplets per joint."""
FULL_TURN_DEG = 360.0


def fold(values, start: float) -> np.ndarray:
    """Positions of a full-turn rotary axis folded into its turn ``[start, start + 360)`` (deg)."""
    return start + np.mod(np.asarray(values, dtype=float) - start, FULL_TURN_DEG)


def meta_format(table, want: str) -> None:
    """InputError naming the file unless its provenance line ``format:`` (sidecar, or a ``#`` line) is ``want``."""
    got = table.meta().get("format")
    if got != want:
        raise InputError(f"{table.path}: provenance 'format' (its sidecar {sidecar_path(table.path).name} or a "
                         f"leading '#' line): expected {want!r}, got {got!r}")


@dataclass
class TableField:
    """An error field (``predict(axes) -> (n, 3) μm``) as the controller evaluates it from a table.

    No optional capabilities and no calibrated volume of its own (:mod:`errormap.field`): it is
    compared with the model it was sampled from, not used to guard commands.
    """

    fn: object
    capabilities = frozenset()
    calibrated_volume = None

    def predict(self, axes):
        return self.fn(np.asarray(axes, dtype=float))

    __call__ = predict


def node_means(nom, c, ok, empty_message: str, w=None) -> tuple[np.ndarray, np.ndarray]:
    """Per table node the (``w``-weighted) mean correction over its compensable samples: ``c``, ``ok``, ``w``
    (n_nodes, samples) at the nodes ``nom`` (n_nodes,). Nodes where no sample is compensable take the linear
    interpolation of their neighbours. Returns ``(mean (n_nodes,), filled (n_nodes,) bool)``; ValueError
    ``empty_message`` when no node has a compensable sample."""
    if w is None:
        cnt = ok.sum(axis=1)
        if not np.any(cnt):
            raise ValueError(empty_message)
        mean = np.where(ok, c, 0.0).sum(axis=1) / np.maximum(cnt, 1)
        good = cnt > 0
    else:
        ww = np.where(ok, w, 0.0)
        tot = ww.sum(axis=1)
        good = tot > 0
        if not good.any():
            raise ValueError(empty_message)
        mean = (ww * np.where(ok, c, 0.0)).sum(axis=1) / np.where(good, tot, 1.0)
    mean[~good] = np.interp(nom[~good], nom[good], mean[good])
    return mean, good


def weighted_node_means(nom, c, ok, w, empty_message: str) -> np.ndarray:
    """:func:`node_means` weighted by ``w`` (n_nodes, samples): the means alone."""
    return node_means(nom, c, ok, empty_message, w)[0]


@contextlib.contextmanager
def staged_folder(out):
    """A temporary folder beside ``out``; on success its files replace those in ``out``."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o777 & ~mask)  # mkdtemp makes 0700; give the folder the usual mode
    try:
        yield tmp
        if not out.exists():
            os.replace(tmp, out)
        else:
            for p in sorted(tmp.iterdir()):
                os.replace(p, out / p.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def table_bytes(paths) -> int:
    return int(sum(Path(p).stat().st_size for p in paths))


def write_manifest(folder, info: dict) -> Path:
    return write_json(Path(folder) / "export.json", info)
