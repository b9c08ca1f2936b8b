"""training: the learned error field (BP network, Levenberg–Marquardt, MLflow tracking).

May import ``errormap``; never ``compensation``. The public names below load lazily, so
``import training`` stays cheap (torch and MLflow load on first use).

* :class:`training.model.MLPField` — the network as an error field
  (:class:`errormap.field.ErrorField`: ``predict``, ``calibrated_volume`` and every optional
  capability, ``jacobian`` to the fused GA fitness of :mod:`training.ga_fitness`; ``save``/``load``).
* :class:`training.model.PhysicsMLPField` — the network on what an element set fitted to the same
  feature points leaves (``fit_field(..., physics="first-order")``, :mod:`training.physics`).
* :func:`training.trainers.fit_field` — train on feature points, measure, track in MLflow;
  :class:`training.trainers.TrainSettings` / :class:`~training.trainers.TrackSettings` say how.
* :func:`training.trainers.validation_points` — random off-grid points from the HTM model.
* :func:`training.tracking.load_field` — a trained field by run id / ``runs:/`` / ``models:/``.
"""

from errormap import lazy_exports

# Training stops on iterations by default (the same settings give the same model on any machine):
DEFAULT_MAX_ITER = 1000  # LM on the paper's network: ~0.2 s an iteration on 2 cores (~3-4 min)
QUICK_MAX_ITER = 300     # the demo-sized setting
# The defaults of `volcomp train` and `volcomp demo`: the measured best (docs/decisions/020-benchmark-notebook.md, "The surrogate network on
# feature points"): the network on what an element set fitted to the same feature points leaves, on the 21^3 grid
# (errormap.featurepoints.DEFAULT_GRID), 40 LM iterations, the iterate best on the off-grid selection points kept.
DEFAULT_PHYSICS = "first-order"
PHYSICS_MAX_ITER = 40    # LM iterations with physics "first-order" (~2 CPU s an iteration on 9,261 points)


def default_max_iter(physics: str, quick: bool = False) -> int:
    """LM iterations when none are given: :data:`PHYSICS_MAX_ITER` on a physical part (``quick`` or not), else
    :data:`DEFAULT_MAX_ITER` (:data:`QUICK_MAX_ITER` with ``quick``)."""
    if physics != "none":
        return PHYSICS_MAX_ITER
    return QUICK_MAX_ITER if quick else DEFAULT_MAX_ITER


_LAZY = {
    "MLPField": "training.model",
    "PhysicsMLPField": "training.model",
    "fit_field": "training.trainers",
    "FitResult": "training.trainers",
    "TrainSettings": "training.trainers",
    "TrackSettings": "training.trainers",
    "validation_points": "training.trainers",
    "fit_metrics": "training.trainers",
    "load_field": "training.tracking",
    "default_tracking_uri": "training.tracking",
}

__all__ = sorted(_LAZY)

__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
