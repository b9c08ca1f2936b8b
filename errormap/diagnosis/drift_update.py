"""Online update of a drift model from on-machine measurements.

:class:`DriftUpdater` re-fits a saved :class:`~errormap.diagnosis.drift_models.DriftModel`'s intercept and
coefficients per measured channel by a Kalman filter on the parameters (a random walk, its covariance
opened up on a step larger than ``STEP_CHI2``; the prediction at a row uses only measurements strictly
before it), and keeps the saved model's distance rule (the updated prediction shrunk toward the updated
OLS baseline beyond ρ = 1). Equations, defaults and measured behaviour: ``docs/explanation/drift.md``,
"Online update"."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..io import InputError

from .drift_models import (COV_FLOOR, ChannelFit, DriftModel, distance_weight, feature_matrix, input_values,
                           mahalanobis)

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
    """``pred_um`` / ``fixed_um`` {channel: (n,)}: updated (a priori) and saved-model predictions (both as
    delivered: with the distance rule where the channel has one);
    ``measured`` {channel: (m,) row indices}; ``model`` the DriftModel with the final parameters;
    ``history`` {channel: [(row, a priori error μm, fixed-model error μm)]}."""

    pred_um: dict
    fixed_um: dict
    measured: dict
    model: DriftModel
    history: dict = field(default_factory=dict)
    rho: dict = field(default_factory=dict)        # {channel: (n,) ρ from the fit data + measurements before each row}
    band_um: dict = field(default_factory=dict)    # {channel: (n,) band95 · max(1, ρ)^band_gamma}

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


class RunningReference:
    """The distance reference of :func:`~errormap.diagnosis.drift_models.whitener`, grown sample by sample.

    Built from a saved ``mean`` (k,), whitening matrix ``whiten`` (k, r) and the number of samples ``n`` it was
    computed from (covariance recovered as pinv(W·Wᵀ)); :meth:`add` merges one sample (k,) (Welford);
    :meth:`distance` gives the Mahalanobis distances (m,) of rows (m, k) from the current reference. Until a
    sample is added the saved (mean, whiten) are used exactly."""

    def __init__(self, mean, whiten, n: int):
        self.mu = np.asarray(mean, float)
        self.W = np.asarray(whiten, float).reshape(len(self.mu), -1)
        self.n = int(max(n, 2))
        self._M = None                     # scatter matrix n·C, built at the first add

    def add(self, u):
        if self._M is None:                # the saved covariance (the whitener's, ddof = 1) as a scatter matrix
            self._M = (self.n - 1) * np.linalg.pinv(self.W @ self.W.T)
        u = np.asarray(u, float)
        self.n += 1
        d = u - self.mu
        self.mu = self.mu + d / self.n
        self._M = self._M + np.outer(d, u - self.mu)
        C = self._M / (self.n - 1)
        sd = np.sqrt(np.maximum(np.diag(C), 0.0))
        sd = np.where(sd > 0, sd, 1.0)
        ev, V = np.linalg.eigh(C / np.outer(sd, sd))
        keep = ev > COV_FLOOR * max(ev.max(), 1e-300)
        self.W = (V[:, keep] / np.sqrt(ev[keep])) / sd[:, None]

    def distance(self, U):
        return mahalanobis(U, self.mu, self.W)


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

    @staticmethod
    def _rho(refs, rows, n) -> np.ndarray:
        """ρ (n,) at every row from the references as they stood before it: rows up to and including a measured
        row r use the fit data + the measured rows before r; r joins the references after."""
        rho = np.empty(n)

        def at(a, b):
            return np.max([ref.distance(X[a:b]) / d0 for ref, X, d0 in refs], axis=0)
        k0 = 0
        for r in rows:
            rho[k0:r + 1] = at(k0, r + 1)
            for ref, X, _ in refs:
                ref.add(X[r])
            k0 = r + 1
        if k0 < n:
            rho[k0:] = at(k0, n)
        return rho

    def _kalman(self, F, intercept_um, coef, features, t, y, rows, band):
        """The filter of the module doc on one linear model (features ``F`` (n, p), its intercept and coef (p,)):
        (a-priori prediction (n,), final intercept, final coef (p,), rows where a step opened the filter)."""
        n = len(t)
        warm = max(int(rows[0]), MIN_WARM_ROWS)
        cj = F[0]
        sj = np.maximum(F[:warm].std(axis=0), [scale_floor(f) for f in features])
        Z = (F - cj) / sj
        sp = self.prior_um or band
        R = (self.noise_um or band / 2) ** 2
        phi = np.concatenate([[intercept_um + cj @ coef], coef * sj])
        P0 = np.eye(len(phi)) * sp**2
        P = P0.copy()
        Q = P0 * self.drift_per_h
        out = np.empty(n)
        steps = []
        last_t = t[rows[0]]
        k0 = 0
        for r in rows:                           # rows up to and including r use φ from before r's update
            X = np.column_stack([np.ones(r + 1 - k0), Z[k0:r + 1]])
            out[k0:r + 1] = X @ phi
            x = X[-1]
            P = P + Q * (t[r] - last_t) / 3600.0
            last_t = t[r]
            e = y[r] - x @ phi
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
        c = phi[1:] / sj
        return out, float(phi[0] - cj @ c), c, steps

    def run(self, model: DriftModel, log, measured_um: dict) -> UpdateResult:
        """``measured_um`` {channel: (n,)} with NaN where the channel was not measured. Returns an
        :class:`UpdateResult`; channels without a measurement keep the saved model."""
        self._check()
        self.steps_ = {}
        t = np.asarray(log.time_s, float)
        n = len(t)
        cache = {}
        pred, fixed, meas, hist, chans, rho_out, band_out = {}, {}, {}, {}, {}, {}, {}
        saved = model.predict(log, cache)                                   # the saved model as it predicts (distance rule)
        saved_rho = model.channel_rho(log, cache)
        nov = (model.meta or {}).get("novelty") or {}
        n_fit = int((model.meta or {}).get("fit_rows") or 2)
        try:
            U = np.stack([input_values(log, i) for i in nov["inputs"]], axis=1) if nov.get("range_distance") else None
        except InputError:
            U = None
        for ch, c in model.channels.items():
            F = feature_matrix(log, c.features, cache)                       # (n, p)
            fixed[ch] = saved[ch]
            y = np.asarray(measured_um.get(ch, np.full(n, np.nan)), float)
            rows = np.flatnonzero(np.isfinite(y))
            meas[ch] = rows
            band95 = c.band95_um
            if not rows.size:
                pred[ch], hist[ch], chans[ch] = saved[ch].copy(), [], c
                rho_out[ch] = saved_rho[ch]
                band_out[ch] = band95 * (np.ones(n) if saved_rho[ch] is None
                                         else np.maximum(1.0, saved_rho[ch]) ** c.band_gamma)
                continue
            # the distance references (raw inputs; the channel's own features) grown by the measured rows
            refs = []
            if U is not None:
                refs.append((RunningReference(nov["mean"], nov["whiten"], n_fit), U, float(nov["range_distance"])))
            if c.novelty:
                refs.append((RunningReference(c.novelty["mean"], c.novelty["whiten"], n_fit),
                             feature_matrix(log, c.novelty["features"], cache), float(c.novelty["range_distance"])))
            rho = self._rho(refs, rows, n) if refs else None
            band = c.band95_um if np.isfinite(c.band95_um) and c.band95_um > 0 else max(float(np.std(y[rows])), 1.0)
            lin, a_new, coef, steps = self._kalman(F, c.intercept_um, c.coef, c.features, t, y, rows, band)
            out = lin
            base_new = c.base
            shrink = rho is not None and c.base is not None and np.isfinite(c.shrink_scale)
            if shrink:
                # the baseline is updated from the same measurements by the same filter: the shrinkage blends two
                # current models (a stale baseline would undo what the update learned in the new regime)
                bf, ba, bc = c.base
                blin, ba_new, bc_new, _ = self._kalman(feature_matrix(log, bf, cache), ba, np.asarray(bc, float), bf,
                                                       t, y, rows, band)
                out = blin + distance_weight(rho, c.shrink_scale) * (lin - blin)
                base_new = (list(bf), ba_new, bc_new)
            pred[ch] = out
            hist[ch] = [(int(r), float(y[r] - out[r]), float(y[r] - saved[ch][r])) for r in rows]
            rho_out[ch] = rho
            band_out[ch] = band95 * (np.ones(n) if rho is None else np.maximum(1.0, rho) ** c.band_gamma)
            self.steps_[ch] = steps
            chans[ch] = ChannelFit(c.family, c.hyper, list(c.features), a_new, coef, c.band95_um,
                                   base_new, c.shrink_scale, c.novelty, c.band_gamma)
        meta = dict(model.meta)
        meta["online_update"] = {"method": "Kalman filter on the parameters (random walk)",
                                 "drift_per_h": self.drift_per_h, "prior_um": self.prior_um,
                                 "noise_um": self.noise_um,
                                 "measurements": {ch: int(len(v)) for ch, v in meas.items()},
                                 "log": str(log.path)}
        return UpdateResult(pred, fixed, meas, DriftModel(chans, meta), hist, rho_out, band_out)
