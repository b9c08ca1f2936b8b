"""The learned residual and the hybrid field: a fitted regressor tapered to zero outside the checks' box,
the physical model plus it, their band and map (module doc of :mod:`compensation.hybrid`)."""
from __future__ import annotations

import numpy as np

from errormap.field import GRINDER_AXES, JACOBIAN, PREDICT_AND_JACOBIAN, is_rotary_column
from errormap.machine_tool import WorkRotation
from errormap.transforms import check_points
from training.residual import Z95, ResidualRegressor

from .inputs import (INPUT_SETS, MAP_N, OUTPUT_FRAMES, TAPER_FRAC, check_input_set, input_features, input_set_features,
                     linear_columns)

FORMAT = "volcomp-learned-residual/1"
"""The ``format`` of a learned residual inside ``model.json`` (key ``learned_residual``)."""


def _smoothstep_out(v, lo, hi, margin):
    """Taper (n,) and its derivative in v: 1 inside [lo, hi], cubic fall to 0 over ``margin`` outside."""
    d = np.maximum(lo - v, 0.0) + np.maximum(v - hi, 0.0)
    sgn = np.where(v < lo, -1.0, np.where(v > hi, 1.0, 0.0))
    t = np.clip(d / margin, 0.0, 1.0)
    w = 1.0 - (3 * t**2 - 2 * t**3)
    dw = -(6 * t - 6 * t**2) / margin * sgn
    return w, dw


class LearnedResidual:
    """A fitted :class:`ResidualRegressor` on the features of input set ``inputs``
    (:func:`input_features`; ``rho0_mm`` the machine's tool radius at z = 0 for the work-frame
    sets) of a machine whose axis columns are ``axes`` (default the grinder's), tapered to zero
    outside the checks' box ``lo``/``hi`` over its LINEAR axes (:func:`linear_columns`, in axis order)."""

    def __init__(self, regressor: ResidualRegressor, lo, hi, inputs: str = "axes", rho0_mm: float | None = None,
                 axes=GRINDER_AXES, frame: str = "work", rotation: WorkRotation | None = None):
        self.axes = tuple(str(c) for c in axes)
        if frame not in OUTPUT_FRAMES:
            raise ValueError(f"Expected an output frame of {list(OUTPUT_FRAMES)}, got {frame!r}")
        if (frame == "work") != (rotation is None):
            raise ValueError("the machine output frame needs the work rotation, the work frame none")
        if rotation is not None and rotation.n_axes != len(self.axes):
            raise ValueError(f"expected a work rotation of {len(self.axes)} axes, got {rotation.n_axes}")
        self.frame, self.rotation = frame, rotation
        rho0_mm = check_input_set(inputs, rho0_mm, self.axes)
        self.linear = linear_columns(self.axes)
        self.regressor = regressor
        self.lo = np.asarray(lo, dtype=float)
        self.hi = np.asarray(hi, dtype=float)
        if self.lo.shape != (len(self.linear),) or self.hi.shape != (len(self.linear),):
            raise ValueError(f"expected box_lo and box_hi of {len(self.linear)} values "
                             f"({', '.join(self.box_names) or 'no linear axis'})")
        self.margin = TAPER_FRAC * np.maximum(self.hi - self.lo, 1e-9)
        self.inputs, self.rho0_mm = inputs, rho0_mm

    @property
    def chosen(self) -> str:
        return self.regressor.chosen_

    @property
    def feature_names(self) -> tuple:
        return input_set_features(self.inputs, self.axes)

    @property
    def box_names(self) -> tuple:
        """The axis columns of the checks' box (the linear axes), in the order of ``lo``/``hi``."""
        return tuple(self.axes[j] for j in self.linear)

    @property
    def axes_label(self) -> str:
        return f"axes ({', '.join(self.axes)})"

    def features(self, axes):
        """axes (n, k) → features (n, d), d(features)/d(axes) (n, d, k)."""
        return input_features(axes, self.inputs, self.rho0_mm, self.axes)

    def inside(self, axes, tol: float = 1e-9) -> np.ndarray:
        """(n,) bool: the points of axes (n, k) inside the checks' box (every linear axis within lo/hi ± tol)."""
        axes = check_points(axes, self.axes_label, len(self.axes))
        v = axes[:, list(self.linear)]
        return np.all((v >= self.lo - tol) & (v <= self.hi + tol), axis=1)

    def _taper(self, axes):
        """The taper (n,) = Π over the linear axes of their smoothsteps, and its derivative (n, k)."""
        ws = [_smoothstep_out(axes[:, j], self.lo[i], self.hi[i], self.margin[i]) for i, j in enumerate(self.linear)]
        w = np.ones(axes.shape[0])
        for wi, _ in ws:
            w = w * wi
        dw = np.zeros(axes.shape)
        for i, j in enumerate(self.linear):
            rest = np.ones(axes.shape[0])
            for m, (wm, _) in enumerate(ws):
                if m != i:
                    rest = rest * wm
            dw[:, j] = ws[i][1] * rest
        return w, dw

    def work_var(self, axes, var_um2) -> np.ndarray:
        """Per-component variances ``var_um2`` ((n, 3) or (3,), μm²) of independent components in the
        learned frame → the work frame's per-component variances (n, 3) at axes (n, k)."""
        var = np.broadcast_to(np.asarray(var_um2, dtype=float), (len(axes), 3))
        if self.rotation is None:
            return np.array(var)
        R = self.rotation(axes)[0]
        return np.einsum("nji,nj->ni", R * R, var)

    def predict(self, axes, return_std=False):
        """Learned correction (n, 3) μm [, its 1-σ band (n, 3) μm] at axes (n, k), in the work frame
        (learned in the machine frame: turned back, ``Rᵀ·g``, its band's variances with it)."""
        axes = check_points(axes, self.axes_label, len(self.axes))
        w, _ = self._taper(axes)
        f, _ = self.features(axes)
        if return_std:
            v, s = self.regressor.predict(f, return_std=True)
            # outside the box the band is the regressor's prior there (its std grows away from data)
            v = v * w[:, None]
            if self.rotation is None:
                return v, s
            R = self.rotation(axes)[0]
            return np.einsum("nji,nj->ni", R, v), np.sqrt(np.einsum("nji,nj->ni", R * R, s * s))
        v = self.regressor.predict(f) * w[:, None]
        return v if self.rotation is None else np.einsum("nji,nj->ni", self.rotation(axes)[0], v)

    def predict_and_jacobian(self, axes):
        """(value (n, 3) μm, d/d(axes) (n, 3, k)), closed form (taper × regressor, chain rule; in the
        machine frame ``d(Rᵀg) = dRᵀ·g + Rᵀ·dg``)."""
        axes = check_points(axes, self.axes_label, len(self.axes))
        w, dw = self._taper(axes)
        f, Jf = self.features(axes)
        v, Jv = self.regressor.predict_and_jacobian(f)                 # (n, 3), (n, 3, d)
        J = np.einsum("nkf,nfa->nka", Jv, Jf) * w[:, None, None] + v[:, :, None] * dw[:, None, :]
        v = v * w[:, None]
        if self.rotation is None:
            return v, J
        R, dR = self.rotation(axes)                                     # (n, 3, 3), (n, 3, 3, k)
        return (np.einsum("nji,nj->ni", R, v),
                np.einsum("nji,nja->nia", R, J) + np.einsum("njia,nj->nia", dR, v))

    def to_dict(self) -> dict:
        """The saved form; ``axes`` (the machine's axis columns) is written when they are not the
        grinder's (a file without it has the grinder's, as every file written before it)."""
        out = {"format": FORMAT, "features": list(self.feature_names), "inputs": self.inputs,
               "box_lo": self.lo.tolist(), "box_hi": self.hi.tolist(), "taper_frac": TAPER_FRAC,
               "regressor": self.regressor.to_dict()}
        if self.axes != GRINDER_AXES:
            out["axes"] = list(self.axes)
            out["box_axes"] = list(self.box_names)
        if self.rho0_mm is not None:
            out["rho0_mm"] = self.rho0_mm
        if self.rotation is not None:   # a file without output_frame learned in the work frame
            out["output_frame"] = self.frame
            out["work_rotation"] = self.rotation.to_dict()
        return out

    @classmethod
    def from_dict(cls, doc) -> "LearnedResidual":
        """ValueError on anything but :meth:`to_dict`'s output (a file without ``inputs``, written
        before the input sets, has the ``axes`` features; one without ``axes`` the grinder's axes)."""
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise ValueError(f"expected a learned residual (format {FORMAT!r})")
        axes = doc.get("axes", list(GRINDER_AXES))
        if (not isinstance(axes, list) or not axes or not all(isinstance(c, str) for c in axes)
                or not all(c.endswith(("_mm", "_deg")) for c in axes) or len(set(axes)) != len(axes)):
            raise ValueError(f"expected axes a list of distinct axis columns (*_mm, *_deg), got {axes!r}")
        axes = tuple(axes)
        inputs = doc.get("inputs", "axes")
        if inputs not in INPUT_SETS:
            raise ValueError(f"expected inputs one of {sorted(INPUT_SETS)}, got {inputs!r}")
        names = input_set_features(inputs, axes)
        if list(doc.get("features", [])) != list(names):
            raise ValueError(f"expected features {list(names)}, got {doc.get('features')!r}")
        lin = linear_columns(axes)
        if "box_axes" in doc and list(doc["box_axes"]) != [axes[j] for j in lin]:
            raise ValueError(f"expected box_axes {[axes[j] for j in lin]} (the linear axes), got {doc['box_axes']!r}")
        rho0 = None
        if inputs != "axes":
            try:
                rho0 = float(doc["rho0_mm"])
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"expected a number rho0_mm for the inputs {inputs!r}") from None
            if not np.isfinite(rho0):
                raise ValueError("expected a finite rho0_mm")
            check_input_set(inputs, rho0, axes)
        try:
            lo, hi = np.asarray(doc["box_lo"], dtype=float), np.asarray(doc["box_hi"], dtype=float)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"bad box ({exc})") from None
        if lo.shape != (len(lin),) or hi.shape != (len(lin),) or not np.all(lo <= hi):
            raise ValueError(f"expected box_lo ≤ box_hi, {len(lin)} values each "
                             f"({', '.join(axes[j] for j in lin)})")
        reg = ResidualRegressor.from_dict(doc["regressor"])
        if reg.n_features_in_ != len(names):
            raise ValueError(f"expected a regressor of {len(names)} inputs")
        frame = doc.get("output_frame", "work")
        if frame not in OUTPUT_FRAMES:
            raise ValueError(f"expected output_frame one of {list(OUTPUT_FRAMES)}, got {frame!r}")
        rotation = None
        if frame != "work":
            if "work_rotation" not in doc:
                raise ValueError(f"expected work_rotation with output_frame {frame!r}")
            rotation = WorkRotation.from_dict(doc["work_rotation"])
            if rotation.n_axes != len(axes):
                raise ValueError(f"expected a work_rotation of {len(axes)} axes, got {rotation.n_axes}")
        return cls(reg, lo, hi, inputs, rho0, axes, frame, rotation)


class HybridField:
    """``base`` (an error field) + ``learned`` (:class:`LearnedResidual`): an
    :class:`errormap.field.ErrorField` over the base's calibrated volume; declares ``jacobian``
    and ``predict_and_jacobian`` when the base does (closed form: base's + learned part's)."""

    kind = "hybrid"

    def __init__(self, base, learned: LearnedResidual):
        self.base = base
        self.learned = learned
        self.machine = getattr(base, "machine", None)

    @property
    def capabilities(self) -> frozenset:
        return frozenset({JACOBIAN, PREDICT_AND_JACOBIAN}) & self.base.capabilities

    @property
    def calibrated_volume(self):
        """The base's calibrated box narrowed in its linear axes to the checks' box the learned part was
        fitted in (:attr:`LearnedResidual.lo` / ``hi``): outside it the learned part is tapered
        away and says nothing, so the guards refuse commands there (``compensate --allow volume``
        overrides, and the override is recorded in the output)."""
        from errormap.field import CalibratedVolume
        vol = self.base.calibrated_volume
        if vol is None:
            return None
        lo, hi = vol.lo_array.copy(), vol.hi_array.copy()
        names = list(vol.names)
        for j, name in enumerate(self.learned.box_names):
            if name in names:
                k = names.index(name)
                lo[k] = max(lo[k], self.learned.lo[j])
                hi[k] = min(hi[k], self.learned.hi[j])
        if np.any(lo > hi):   # disjoint boxes: nothing is calibrated; an empty box at the base's lo refuses all
            hi = np.maximum(hi, lo)
            lo = hi.copy()
        return CalibratedVolume(tuple(lo), tuple(hi), vol.names)

    def predict(self, axes) -> np.ndarray:
        axes = check_points(axes, self.learned.axes_label, len(self.learned.axes))
        return np.asarray(self.base.predict(axes), dtype=float) + self.learned.predict(axes)

    __call__ = predict

    def predict_and_jacobian(self, axes, dtype=np.float64):
        if PREDICT_AND_JACOBIAN not in self.capabilities:
            raise TypeError("the hybrid field's base has no Jacobian")
        axes = check_points(axes, self.learned.axes_label, len(self.learned.axes))
        e, J = self.base.predict_and_jacobian(axes)
        v, Jv = self.learned.predict_and_jacobian(axes)
        return e + v, J + Jv

    def jacobian(self, axes) -> np.ndarray:
        return self.predict_and_jacobian(axes)[1]

    def band_std(self, axes, covariance=None) -> np.ndarray:
        """The hybrid's TOTAL predictive 1-σ band per component, shape (n, 3) μm, at axes (n, 3):
        the learned part's band (its posterior std, calibrated on its cross-validation) ⊕ the
        elements' band ``diag(J Σ Jᵀ)`` from ``covariance`` (a function of the axes,
        :func:`total_band_std`; None: the learned band alone). Measurement noise is not in it (a band of the
        field, not of a measurement)."""
        axes = check_points(axes, self.learned.axes_label, len(self.learned.axes))
        return total_band_std(self.learned, self.machine, axes, covariance)


def total_band_std(learned, machine, axes, covariance=None) -> np.ndarray:
    """(n, 3) μm: ``learned``'s 1-σ band (zeros when None) ⊕ the elements' ``diag(J Σ Jᵀ)``: ``covariance`` a
    function axes (n, k) → their standard deviation (n, 3) μm (:func:`errormap.chain_covariance.band_sd`)."""
    var = np.zeros((len(axes), 3))
    if learned is not None:
        var += learned.predict(axes, return_std=True)[1] ** 2
    if covariance is not None:
        var += covariance(axes) ** 2
    return np.sqrt(var)


def learned_map(learned: LearnedResidual, machine, a_deg=(0.0, 90.0, 180.0, 270.0), covariance=None) -> dict | None:
    """The learned correction over the plane of the machine's FIRST TWO LINEAR axes (the grinder's
    X–Z; ``MAP_N`` × ``MAP_N`` over their strokes), its norm and band, averaged over the rotary
    positions ``a_deg`` (every rotary axis at the same angle, clipped to its stroke when that is less
    than a turn; a machine without a rotary axis: one evaluation), any further linear axis at the
    middle of its stroke: {<first linear column> (MAP_N,), <second> (MAP_N,) — ``x_mm``, ``z_mm`` on
    the grinder —, ``<rotary columns>_averaged`` (``a_deg``), ``rotary_deg`` {rotary column: the angles it
    was evaluated at, after the clipping}, norm_um (MAP_N, MAP_N) [second, first],
    band95_um (MAP_N, MAP_N)} and, with the elements' ``covariance``, ``band95_total_um`` (the
    hybrid's total band, :func:`total_band_std`, vector norm). None on a machine with fewer than two
    linear axes (no plane to map)."""
    cols, lin = learned.axes, learned.linear
    if len(lin) < 2:
        return None
    c1, c2 = cols[lin[0]], cols[lin[1]]
    rot = [j for j, c in enumerate(cols) if is_rotary_column(c)]
    xs = np.linspace(*machine.strokes[c1], MAP_N)
    zs = np.linspace(*machine.strokes[c2], MAP_N)
    X, Z = np.meshgrid(xs, zs)
    norm = np.zeros_like(X)
    band = np.zeros_like(X)
    total = np.zeros_like(X)
    angles = tuple(a_deg) if rot else (None,)
    evaluated = {cols[j]: [] for j in rot}   # the angle each rotary axis was at (clipped to a short stroke)
    for a in angles:
        columns = []
        for j, c in enumerate(cols):
            if j == lin[0]:
                columns.append(X.ravel())
            elif j == lin[1]:
                columns.append(Z.ravel())
            elif j in rot:
                lo_j, hi_j = machine.strokes[c]
                v = float(a) if hi_j - lo_j >= 360.0 else float(np.clip(a, lo_j, hi_j))
                evaluated[c].append(v)
                columns.append(np.full(X.size, v))
            else:
                columns.append(np.full(X.size, 0.5 * (machine.strokes[c][0] + machine.strokes[c][1])))
        P = np.stack(columns, axis=1)
        v, s = learned.predict(P, return_std=True)
        norm += np.linalg.norm(v, axis=1).reshape(X.shape) / len(angles)
        band += Z95 * np.linalg.norm(s, axis=1).reshape(X.shape) / len(angles)
        if covariance is not None:
            total += Z95 * np.linalg.norm(total_band_std(learned, machine, P, covariance), axis=1).reshape(X.shape) / len(angles)
    out = {c1: xs.tolist(), c2: zs.tolist()}
    if rot:
        out["+".join(cols[j] for j in rot) + "_averaged"] = list(a_deg)
        out["rotary_deg"] = evaluated   # per rotary axis the angles actually averaged over (the figure's caption)
    out.update({"norm_um": norm.tolist(), "band95_um": band.tolist()})
    if covariance is not None:
        out["band95_total_um"] = total.tolist()
    return out
