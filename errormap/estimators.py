"""The public estimators, one contract (scikit-learn's): the constructor stores settings only, ``fit``
validates them and the data, solves, and returns ``self``; what it learned ends in ``_``; ``fit`` reads
no file; ``predict`` or a learned attribute before ``fit`` raises :class:`NotFittedError`. Each calls the
existing numerical code (:class:`Identification`, :class:`ClosedLoop`, :class:`ArmCalibration`,
:class:`PKMCalibration`; the drift estimator :class:`errormap.diagnosis.drift_models.DriftSelector` shares
:class:`Estimator`). Overview: ``docs/reference/python-api.md``."""
from __future__ import annotations

import dataclasses
import inspect

import numpy as np

from .settings import keep_settings, settings_of


class NotFittedError(ValueError, AttributeError):
    """An estimator used before :meth:`fit` (a ValueError and an AttributeError, as scikit-learn's)."""


class Estimator:
    """Settings access for every public estimator: ``get_params`` / ``set_params`` read and write the
    constructor's arguments by name; ``_check_fitted`` refuses use before ``fit``."""

    @classmethod
    def defaults(cls) -> dict:
        """``{setting: default}`` of the constructor's settings that have one (what a command line takes for its
        own defaults, so that the command and the estimator cannot disagree)."""
        sig = inspect.signature(cls.__init__)
        return {p.name: p.default for p in sig.parameters.values() if p.default is not p.empty}

    @classmethod
    def _param_names(cls) -> list:
        return settings_of(cls)

    def get_params(self, deep: bool = False) -> dict:
        """``{setting: value}`` as given to the constructor (``deep`` accepted for scikit-learn tools)."""
        return {k: getattr(self, k) for k in self._param_names()}

    def set_params(self, **params):
        """Change settings by name (unknown names refused); returns self. Learned attributes are left as
        they are until the next ``fit``."""
        known = self._param_names()
        bad = sorted(set(params) - set(known))
        if bad:
            raise ValueError(f"{type(self).__name__}: unknown setting(s) {bad}; settings are {known}")
        for k, v in params.items():
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={_short(v)}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    def _check_fitted(self, attr: str) -> None:
        if not hasattr(self, attr):
            raise NotFittedError(f"This {type(self).__name__} is not fitted yet: call fit(...) before using "
                                 f"{attr.rstrip('_') or attr}")


def _short(v) -> str:
    name = getattr(v, "name", None)
    return repr(name) if isinstance(name, str) and not isinstance(v, (str, int, float)) else repr(v)


def machine_tool(machine, what: str):
    """``machine`` as the machine-tool chain every machine-tool estimator runs on: a chain itself, the
    grinder among them; anything else refused naming ``what``."""
    from .machine_tool import MachineTool
    _require_type(machine, (MachineTool,), what,
                  "a machine-tool chain or the grinder file (load_machine('mill-xyz'), load_machine()); an arm: "
                  "ArmCalibration, compensate_joints")
    return machine


def _require_type(value, types, what: str, hint: str) -> None:
    if not isinstance(value, types):
        raise TypeError(f"{what}: expected {' or '.join(t.__name__ for t in types)}, got {type(value).__name__}; "
                        f"{hint}")


class Identification(Estimator):
    """Error elements of a machine tool from laser-tracker sweeps of one set-up (docs/how-to/machine-file.md).

    Settings: ``machine`` (a machine-tool chain, or the grinder file, identified as its chain:
    :func:`errormap.load_machine`); ``max_iter`` / ``tol`` of the Gauss–Newton solve (None: 30 / 1e-7
    μm or μrad); ``min_separation_mm`` (balls closer coincide); ``distance_tol_mm`` (allowed difference of
    measured and nominal ball distances); ``noise_um`` (the known tracker σ per coordinate the covariance
    is scaled with, None: the residuals' σ̂); ``gauge`` (the machine-frame gauge,
    :data:`errormap.identification.GAUGES`; default station-mean, as ``volcomp identify``); ``smooth`` (the
    station values smoothed by the UBRE smoother, :func:`errormap.identification.smooth_chain`, and the
    covariance with them; False: interpolating splines through the noisy stations, ``identify --raw``); ``n_boot``
    (None: Gauss–Newton's covariance; N ≥ 2: the residual bootstrap's, N draws seeded by ``seed``,
    :func:`errormap.identification.bootstrap_covariance`, before smoothing). The defaults are ``volcomp identify``'s
    (the command takes them from :meth:`defaults`).

    ``fit(sweeps)``: ``sweeps`` a :class:`errormap.sweeps.Sweeps` (:func:`errormap.read_sweeps`,
    :func:`errormap.simulate_sweeps`). Learned: ``elements_`` (the chain's element set), ``result_``
    (:class:`errormap.identification.ChainIdentificationResult`: residuals, conditioning, warnings, how the
    covariance was obtained), ``raw_result_`` (the same before smoothing: the interpolating station values),
    ``covariance_`` (``(slot names, stations (N,), Σ (N, N))`` μm² / μrad²), ``prior_covariance_`` (the same
    with the smoother's extra variance on the diagonal: the prior of a closed loop's element update, as
    ``volcomp diagnose`` reads it from ``NAME.cov.npz``), ``field_`` (the elements' error field:
    ``predict(axes (n, k)) -> (n, 3)`` μm).
    """

    def __init__(self, machine, max_iter: int | None = None, tol: float | None = None,
                 min_separation_mm: float = 1.0, distance_tol_mm: float = 2.0, noise_um: float | None = None,
                 gauge: str = "station-mean", smooth: bool = True, n_boot: int | None = None, seed: int = 0):
        keep_settings(self, locals())

    def fit(self, sweeps) -> "Identification":
        from .chain_field import ChainField
        from .identification import ChainIdentification, bootstrap_covariance, smooth_chain
        from .sweeps import Sweeps
        mt = machine_tool(self.machine, "Identification(machine=...)")
        if not isinstance(self.smooth, bool):
            raise TypeError(f"Identification(smooth=...): expected True or False, got {self.smooth!r}")
        _require_type(sweeps, (Sweeps,), "Identification.fit(sweeps)", "read the file first (errormap.read_sweeps)")
        given = {k: v for k, v in (("max_iter", self.max_iter), ("tol", self.tol)) if v is not None}
        settings = dict(min_separation_mm=self.min_separation_mm, distance_tol_mm=self.distance_tol_mm,
                        noise_um=self.noise_um, gauge=self.gauge, **given)
        raw = ChainIdentification(**settings).fit(sweeps, mt).result_
        if self.n_boot is not None:
            raw = bootstrap_covariance(sweeps, mt, raw, self.n_boot, self.seed, **settings)
        res = smooth_chain(raw, mt) if self.smooth else raw
        self.raw_result_, self.result_ = raw, res
        self.elements_ = res.elements_
        self.covariance_ = (list(res.param_slot), res.param_station.copy(), res.cov.copy())
        extra = 0.0 if res.prior_extra is None else np.diag(np.asarray(res.prior_extra, float))
        self.prior_covariance_ = (list(res.param_slot), res.param_station.copy(), res.cov + extra)
        self.field_ = ChainField(mt, self.elements_)
        return self

    def predict(self, axes) -> np.ndarray:
        """The identified elements' error (n, 3) μm at ``axes`` (n, k) in the machine's axis columns."""
        self._check_fitted("field_")
        return self.field_.predict(axes)


class ClosedLoop(Estimator):
    """The closed loop of a machine-tool chain on check measurements (docs/explanation/identification.md).

    Settings: ``machine`` (a machine-tool chain, or the grinder file as its chain); ``fit_fraction`` (the
    first share of the checks, by ``seq``, fits; the rest is held out); ``noise_um`` (known noise σ per coordinate, None: estimated);
    ``effects`` / ``max_effects`` (the effect search); ``smoothing`` (``"gcv"`` or a weight); ``refit_all`` (the
    kept stage re-estimated on all checks once chosen, as ``volcomp diagnose`` ships it).

    ``fit(checks, elements, covariance=None)``: ``checks`` an :class:`errormap.diagnosis.chain_loop.ChainChecks`
    (:func:`errormap.read_checks`, :func:`errormap.simulate_checks`), ``elements`` the identified element
    set, ``covariance`` the update's prior ``(slot names, stations, Σ)`` (``Identification.prior_covariance_``,
    what ``volcomp diagnose`` reads; None: no element update). Learned: ``summary_`` (stages with held-out and fitting statistics, the kept stage and why,
    effects accepted/rejected, noise floor), ``kept_stage_``, ``held_out_rms_um_``, ``elements_`` and
    ``terms_`` (the kept model: as ``volcomp diagnose --no-learned`` ships it, re-estimated on ALL checks once
    chosen on the split when ``refit_all``, :func:`errormap.diagnosis.chain_loop.ship_on_all_checks`; the held-out
    figures are the split's), ``field_`` (its error field; terms that need conditions take them by
    ``field_.with_conditions``). The learned-residual stage of ``volcomp diagnose`` is not part of it.
    """

    def __init__(self, machine, fit_fraction: float = 0.6, noise_um: float | None = None, effects: bool = True,
                 max_effects: int = 4, smoothing="gcv", refit_all: bool = True):
        keep_settings(self, locals())

    def fit(self, checks, elements, covariance=None) -> "ClosedLoop":
        from .diagnosis.chain_loop import ChainChecks, closed_loop_chain, ship_on_all_checks
        from .diagnosis.loop_model import ChainModelField
        from .chain_elements import ChainElementSet
        mt = machine_tool(self.machine, "ClosedLoop(machine=...)")
        _require_type(checks, (ChainChecks,), "ClosedLoop.fit(checks)", "read the file first (errormap.read_checks)")
        _require_type(elements, (ChainElementSet,), "ClosedLoop.fit(elements)", "an identified element set "
                      "(Identification.elements_ or ChainElementSet.load)")
        summary = closed_loop_chain(mt, elements, checks, cov=covariance, fit_fraction=self.fit_fraction,
                                    noise_um=self.noise_um, effects=self.effects, max_effects=self.max_effects,
                                    smoothing=self.smoothing)
        models = summary.pop("_models")
        terms = models["terms"] if summary["kept_stage"].endswith("plus_effects") else []
        elements = models["elements"]
        if self.refit_all:
            elements, terms = ship_on_all_checks(summary, models, terms)
        self.summary_ = summary
        self.kept_stage_ = summary["kept_stage"]
        self.held_out_rms_um_ = float(summary["held_out_rms_um"])
        self.elements_ = elements
        self.terms_ = list(terms)
        self.field_ = ChainModelField(mt, self.elements_, self.terms_)
        return self

    def predict(self, axes, **conditions) -> np.ndarray:
        """The kept model's error (n, 3) μm at ``axes`` (n, k); ``conditions`` (``temp_c=``, ``dir_x=`` …,
        scalars or (n,)) for the terms that need them."""
        self._check_fitted("field_")
        f = self.field_.with_conditions(conditions) if conditions else self.field_
        return f.predict(axes)


class ArmCalibration(Estimator):
    """Geometric calibration of a serial arm (docs/explanation/serial-arms.md).

    Settings: ``chain`` (the arm, :func:`errormap.load_machine` of ``ur5``, ``wam`` or a file);
    ``max_iter`` (1–10,000 Levenberg–Marquardt iterations); ``models`` (candidate slot sets from
    :data:`errormap.arm_calibration.MODELS`; with more than one, each is cross-validated on ``k_folds``
    (2–20) folds of the fit poses, ``seed``, and the lowest CV mean error wins).

    ``fit(poses)``: an :class:`errormap.arm_poses.ArmPoses` (:func:`errormap.read_poses`). Learned:
    ``result_`` (:class:`errormap.arm_calibration.GeometricResult`: ``params``, ``cov``, ``sigma_mm`` …),
    ``model_`` (the chosen slot set), ``cv_table_`` (the CV figures, empty with one model).
    """

    def __init__(self, chain, max_iter: int = 100, models=("dh",), k_folds: int = 5, seed=0):
        keep_settings(self, locals())

    def fit(self, poses) -> "ArmCalibration":
        from .arm_calibration import MODELS, choose_model, cv_models, fit_model
        from .arm_poses import ArmPoses
        from .chain import Chain
        _require_type(self.chain, (Chain,), "ArmCalibration(chain=...)", "a serial arm (load_machine('ur5'))")
        _require_type(poses, (ArmPoses,), "ArmCalibration.fit(poses)", "read the file first (errormap.read_poses)")
        if not 1 <= int(self.max_iter) <= 10_000:
            raise ValueError(f"max_iter must be in [1, 10000], got {self.max_iter}")
        models = tuple(self.models)
        bad = [m for m in models if m not in MODELS]
        if bad or not models:
            raise ValueError(f"models must be from {MODELS}, got {list(models)}")
        if not 2 <= int(self.k_folds) <= 20:
            raise ValueError(f"k_folds must be in [2, 20], got {self.k_folds}")
        table, model = [], models[0]
        if len(models) > 1:
            table = cv_models(self.chain, poses, models, int(self.k_folds), self.seed, plain=False)
            model = choose_model(table)
        res = fit_model(self.chain, poses, model, int(self.max_iter))
        self.result_ = dataclasses.replace(res, cv_table=table)
        self.model_ = model
        self.cv_table_ = table
        return self

    def predict(self, q) -> np.ndarray:
        """The calibrated arm's tool point (n, 3) mm at joint values ``q`` (n, nq)."""
        self._check_fitted("result_")
        return self.result_.predict(q)


class PKMCalibration(Estimator):
    """Kinematic calibration of a parallel machine, hexapod or tripod (docs/explanation/parallel-kinematics.md): the
    regularised identification of its joints, leg offsets (and scales) and the instrument frame
    (:class:`errormap.pkm.calibration.PKMCalibrator`), without ``volcomp calibrate``'s loop on the leg residuals.

    Settings: ``machine`` (:func:`errormap.load_machine` of ``hexapod``, ``tripod`` or a file); ``estimate_scales``
    (the leg scales identified too); ``register`` (the instrument frame estimated; False: it is the machine's);
    ``noise_um`` (measurement σ per component, None: estimated); ``lever_mm`` (orientation residual weight, mm/rad,
    None: estimated); ``lambda_rule`` (``"gcv"``, ``"morozov"``, ``"lcurve"``); ``max_iter`` (Gauss–Newton iterations
    per phase, 1–10,000).

    ``fit(poses)``: a :class:`errormap.pkm.poses.PoseData` (:func:`errormap.read_poses`). Learned: ``result_``
    (:class:`errormap.pkm.calibration.CalibrationResult`: parameters, standard errors, λ, conditioning, residuals),
    ``machine_`` (the identified machine: what ``model.json``'s ``calibration`` section holds), ``frame_`` (instrument ← machine:
    translation (3,) mm, rotation (3, 3)).
    """

    def __init__(self, machine, estimate_scales: bool = True, register: bool = True, noise_um: float | None = None,
                 lever_mm: float | None = None, lambda_rule: str = "gcv", max_iter: int = 50):
        keep_settings(self, locals())

    def fit(self, poses) -> "PKMCalibration":
        from .pkm.calibration import PKMCalibrator
        from .pkm.machine_file import PKM
        from .pkm.poses import PoseData
        _require_type(self.machine, (PKM,), "PKMCalibration(machine=...)", "a hexapod or tripod (load_machine('hexapod'))")
        _require_type(poses, (PoseData,), "PKMCalibration.fit(poses)", "read the file first (errormap.read_poses)")
        if not 1 <= int(self.max_iter) <= 10_000:
            raise ValueError(f"max_iter must be in [1, 10000], got {self.max_iter}")
        res = PKMCalibrator(self.machine, estimate_scales=self.estimate_scales, register=self.register,
                            noise_um=self.noise_um, lever_mm=self.lever_mm, lambda_rule=self.lambda_rule,
                            max_iter=int(self.max_iter)).fit(poses)
        self.result_ = res
        self.machine_ = res.machine
        self.frame_ = (np.array(res.frame_translation_mm, float), np.array(res.frame_rotation, float))
        return self

    def predict(self, q) -> np.ndarray:
        """The calibrated machine's tool tip (n, 3) mm in the instrument's frame at drive commands ``q`` (n, k)."""
        self._check_fitted("result_")
        return self.result_.predict(np.atleast_2d(np.asarray(q, float)))[0]


__all__ = ["ArmCalibration", "ClosedLoop", "Estimator", "Identification", "NotFittedError", "PKMCalibration",
           "machine_tool"]
