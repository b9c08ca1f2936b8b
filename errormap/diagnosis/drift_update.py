"""Online update of a drift model from on-machine measurements (issue 29, point 3).

A saved :class:`~errormap.diagnosis.drift_models.DriftModel` predicts each channel as
``intercept + Σ coef_j·f_j(t)`` from causal features. When the machine measures a channel (a probe
cycle, a laser check) at some times ``t_k``, :class:`DriftUpdater` re-fits that channel's intercept
and coefficients by a **Kalman filter on the parameters** (a random walk: the machine's thermal
behaviour may change — a new fixture, a changed coolant — and the parameters follow):

    z_j(t) = (f_j(t) − c_j) / s_j          c_j: f_j at the first row; s_j: its scale (below)
    φ = [a, g_1 … g_p]                     prediction = a + Σ g_j z_j  (φ0 from the saved model)
    at each measurement y_k (in time order):
        prediction before the update:  ŷ_k = x_kᵀφ,  x_k = [1, z(t_k)]       (a priori: causal)
        P ← P + Q·Δt_k / 3600          (random walk since the previous measurement, Δt_k in s)
        S = x_kᵀ P x_k + R;  e = y_k − ŷ_k
        if e² > STEP_CHI2·S:  P ← P·min(e²/S, MAX_INFLATE)    (a step: the covariance is opened up)
        K = P x_k / (x_kᵀ P x_k + R);  φ ← φ + K e;  P ← (I − K x_kᵀ) P

``s_j``: the standard deviation of f_j over the rows before the first measurement (at least
``MIN_WARM_ROWS`` rows), floored at a typical excursion of its input (:func:`scale_floor`: 1 °C,
1000 rpm, 0.1 for a power of speed): the gains are then in μm per typical excursion and one prior
scale fits all.
``P0 = diag(σ_a², σ_g² …)`` with σ = ``prior_um`` (default: the channel's band); ``R`` = (``noise_um``)²
(default: half the band, squared); ``Q = P0 · drift_per_h`` (the fraction of the prior variance the
parameters may wander per hour). The prediction at every row uses the parameters as they stood
after the last measurement strictly before that row — never a measurement at or after it. The
random walk alone adapts slowly (that is its job: measurement noise must not move the gains); an
abrupt change — a 3 σ innovation — is met by opening the covariance up (an adaptive, fading-memory
filter), and the rows where that happened are reported (``steps_``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .drift_models import ChannelFit, DriftModel, feature_matrix

MIN_WARM_ROWS = 10
FLOOR_C = 1.0           # a temperature feature's scale is at least 1 °C (gains in μm per °C or per larger excursion)
FLOOR_RPM = 1000.0      # a speed feature's: 1000 rpm
FLOOR_POWER = 0.1       # a power feature's ((rpm/scale)^power, ~0…2): 0.1


def scale_floor(f) -> float:
    """The smallest scale of a feature: a typical excursion of its input (°C, rpm, or a power of speed)."""
    if f.power != 1 or f.scale != 1.0:
        return FLOOR_POWER
    return FLOOR_C if f.input.startswith("temp_") else FLOOR_RPM
DRIFT_PER_H = 0.01      # the parameters may wander by 1 % of their prior variance per hour
STEP_CHI2 = 9.0         # a measurement whose innovation exceeds 3 σ of its predicted spread signals a step ...
MAX_INFLATE = 1e4       # ... and scales the parameter covariance by e²/S (at most 1e4): the filter re-learns


@dataclass
class UpdateResult:
    """``pred_um`` / ``fixed_um`` {channel: (n,)}: updated (a priori) and saved-model predictions;
    ``measured`` {channel: (m,) row indices}; ``model`` the DriftModel with the final parameters;
    ``history`` {channel: [(row, a priori error μm, fixed-model error μm)]}."""

    pred_um: dict
    fixed_um: dict
    measured: dict
    model: DriftModel
    history: dict = field(default_factory=dict)

    def evolution(self, n_windows: int = 4) -> dict:
        """Per channel: [(first time index, last, RMS updated, RMS fixed, measurements)] over ``n_windows``
        consecutive groups of the measurements (how the error evolves as the updates accumulate)."""
        out = {}
        for ch, h in self.history.items():
            if not h:
                out[ch] = []
                continue
            arr = np.array(h)
            rows = []
            for part in np.array_split(np.arange(len(arr)), min(n_windows, len(arr))):
                e = arr[part]
                rows.append((int(e[0, 0]), int(e[-1, 0]), float(np.sqrt(np.mean(e[:, 1] ** 2))),
                             float(np.sqrt(np.mean(e[:, 2] ** 2))), int(len(e))))
            out[ch] = rows
        return out


class DriftUpdater:
    """Kalman filter on a drift model's parameters (module doc). Settings: ``prior_um`` (σ of the
    intercept and of each gain per typical excursion; None: the channel's band), ``noise_um`` (σ of a
    measurement; None: half the band), ``drift_per_h``."""

    def __init__(self, prior_um: float | None = None, noise_um: float | None = None,
                 drift_per_h: float = DRIFT_PER_H):
        self.prior_um = prior_um
        self.noise_um = noise_um
        self.drift_per_h = drift_per_h

    def _check(self):
        for k in ("prior_um", "noise_um"):
            v = getattr(self, k)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"Expected {k} > 0, got {v}")
        if not (np.isfinite(self.drift_per_h) and self.drift_per_h >= 0):
            raise ValueError(f"Expected drift_per_h >= 0, got {self.drift_per_h}")

    def run(self, model: DriftModel, log, measured_um: dict) -> UpdateResult:
        """``measured_um`` {channel: (n,)} with NaN where the channel was not measured. Returns an
        :class:`UpdateResult`; channels without a measurement keep the saved model."""
        self._check()
        self.steps_ = {}
        t = np.asarray(log.time_s, float)
        n = len(t)
        cache = {}
        pred, fixed, meas, hist, chans = {}, {}, {}, {}, {}
        for ch, c in model.channels.items():
            F = feature_matrix(log, c.features, cache)                       # (n, p)
            base = c.intercept_um + F @ c.coef
            fixed[ch] = base
            y = np.asarray(measured_um.get(ch, np.full(n, np.nan)), float)
            rows = np.flatnonzero(np.isfinite(y))
            meas[ch] = rows
            if not rows.size:
                pred[ch], hist[ch], chans[ch] = base.copy(), [], c
                continue
            warm = max(int(rows[0]), MIN_WARM_ROWS)
            cj = F[0]
            sj = np.maximum(F[:warm].std(axis=0), [scale_floor(f) for f in c.features])
            Z = (F - cj) / sj
            band = c.band95_um if np.isfinite(c.band95_um) and c.band95_um > 0 else max(float(np.std(y[rows])), 1.0)
            sp = self.prior_um or band
            R = (self.noise_um or band / 2) ** 2
            phi = np.concatenate([[c.intercept_um + cj @ c.coef], c.coef * sj])
            P0 = np.eye(len(phi)) * sp**2
            P = P0.copy()
            Q = P0 * self.drift_per_h
            out = np.empty(n)
            h, steps = [], []
            last_t = t[rows[0]]
            k0 = 0
            for r in rows:                           # rows up to and including r use φ from before r's update
                X = np.column_stack([np.ones(r + 1 - k0), Z[k0:r + 1]])
                out[k0:r + 1] = X @ phi
                x = X[-1]
                P = P + Q * (t[r] - last_t) / 3600.0
                last_t = t[r]
                e = y[r] - x @ phi
                h.append((int(r), float(e), float(y[r] - base[r])))
                Px = P @ x
                S = x @ Px + R
                if e * e > STEP_CHI2 * S:             # an innovation beyond 3 σ: a step, open the filter up
                    infl = min(e * e / S, MAX_INFLATE)
                    P, Px = P * infl, Px * infl
                    S = x @ Px + R
                    steps.append(int(r))
                K = Px / S
                phi = phi + K * e
                P = P - np.outer(K, Px)
                P = 0.5 * (P + P.T)
                k0 = r + 1
            if k0 < n:
                out[k0:] = np.column_stack([np.ones(n - k0), Z[k0:]]) @ phi
            pred[ch], hist[ch] = out, h
            self.steps_[ch] = steps
            coef = phi[1:] / sj
            chans[ch] = ChannelFit(c.family, c.hyper, list(c.features), float(phi[0] - cj @ coef), coef, c.band95_um,
                                   c.base, c.shrink_scale)
        meta = dict(model.meta)
        meta["online_update"] = {"method": "Kalman filter on the parameters (random walk)",
                                 "drift_per_h": self.drift_per_h, "prior_um": self.prior_um,
                                 "noise_um": self.noise_um,
                                 "measurements": {ch: int(len(v)) for ch, v in meas.items()},
                                 "log": str(log.path)}
        return UpdateResult(pred, fixed, meas, DriftModel(chans, meta), hist)
