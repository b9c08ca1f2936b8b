"""compensation: from an error field to corrected commands, evaluation, reports and the CLI.

May import ``errormap`` and ``training``. The public names below (``compensation.__all__``;
docs/reference/python-api.md) load lazily on first use, so ``import compensation`` imports nothing heavy:

* :func:`compensate_points` — compensated axis commands for points in memory (solver and guards);
  :func:`compensate_joints` for a calibrated arm;
* :func:`compensate_program` — tool-path files (G-code, axis CSV) of a machine-tool chain, written as
  ``volcomp compensate`` writes them; :class:`CompensateSettings` how;
* :class:`Compensation` — the one result of both (commands, residuals, notes, refused, overrides);
* :func:`save_model` / :func:`load_model` — a model to files every command reads, and back as a field;
  :func:`read_model` — any model file as a :class:`Model` (the field and what it holds: elements, covariance,
  effect terms, learned residual, network, provenance).
"""

from errormap import lazy_exports

_LAZY = {
    "compensate_points": "compensation.compensate",
    "compensate_program": "compensation.compensate",
    "compensate_joints": "compensation.compensate",
    "Compensation": "compensation.compensate",
    "save_model": "compensation.compensate",
    "load_model": "compensation.compensate",
    "read_model": "compensation.model_file",
    "Model": "compensation.model_file",
    "CompensateSettings": "compensation.app.workflows.compensate",
}

__all__ = sorted(_LAZY)

__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
