"""A fitted causal drift model: its prediction, its distance rule and band, and its controller form, the file
``volcomp.drift_model`` v1 (docs/explanation/drift.md)."""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from ..io import InputError, read_document_text
from .drift import DriftLog
from .drift_features import Feature, distance_weight, feature_matrix, input_values, mahalanobis, novelty_rho

SCHEMA = "volcomp.drift_model"
SCHEMA_VERSION = 1
# other volcomp files a user may hand over in place of a drift model, recognised by their ``format`` key
OTHER_FORMATS = {"volcomp-elements/": "an element set",
                 "volcomp-identification/": "an identification result",
                 "volcomp-diagnosed-model/": "a diagnosed volumetric model (from `volcomp diagnose CHECKS`)",
                 "volcomp-sweeps/": "a sweeps file", "volcomp-fleet/": "a fleet file",
                 "volcomp-report/": "a comparison report"}


def _kind_of(fmt) -> str:
    """What a file with ``format`` = ``fmt`` is, in words."""
    for k, v in OTHER_FORMATS.items():
        if isinstance(fmt, str) and fmt.startswith(k):
            return f"{v} ({fmt})"
    return f"a file of format {fmt!r}"


@dataclass
class ChannelFit:
    family: str
    hyper: str
    features: list
    intercept_um: float
    coef: np.ndarray
    band95_um: float = float("nan")
    base: tuple | None = None          # (features, intercept, coef) of the OLS baseline the prediction shrinks toward
    shrink_scale: float = float("inf")  # g(ρ) = exp(−(ρ − 1)/shrink_scale) beyond ρ = 1; inf: no per-sample shrinkage
    novelty: dict | None = None         # the distance on the channel's OWN features (:func:`feature_novelty`): ρ of the
                                        # channel = max(ρ of the raw inputs, ρ of these features)
    band_gamma: float = 1.0             # the band grows as band95_um · max(1, ρ)^band_gamma (:func:`rho_power_band`)


class DriftModel:
    """A fitted causal drift model: ``channels`` {channel: ChannelFit}. ``predict`` → {channel: (n,)} μm."""

    def __init__(self, channels: dict, meta: dict | None = None):
        self.channels = channels
        self.meta = meta or {}

    @property
    def features(self) -> list:
        seen = {}
        for c in self.channels.values():
            for f in list(c.features) + (list(c.base[0]) if c.base is not None else []) + \
                    (list(c.novelty["features"]) if c.novelty else []):
                seen.setdefault(f.key, f)
        return list(seen.values())

    def rho(self, log) -> np.ndarray | None:
        """ρ (n,) of every row of ``log``: :func:`input_novelty` (the distance of its raw inputs from the fit data)
        / the fit data's range distance d0 (``fitted_on.novelty.range_distance``); None where the model records no
        distance."""
        d0 = ((self.meta or {}).get("novelty") or {}).get("range_distance")
        d = input_novelty(self, log) if d0 else None
        return None if d is None else d / float(d0)

    def channel_rho(self, log, cache: dict | None = None) -> dict:
        """{channel: ρ (n,) or None}: the larger of the raw inputs' ρ (:meth:`rho`) and the ρ of the channel's own
        features (``ChannelFit.novelty``: its filtered inputs / states, its selected sensors), row by row (causal)."""
        raw = self.rho(log)
        cache = {} if cache is None else cache
        out = {}
        for ch, c in self.channels.items():
            r = raw
            if c.novelty:
                rf = novelty_rho(c.novelty, feature_matrix(log, c.novelty["features"], cache))
                r = rf if r is None else np.maximum(r, rf)
            out[ch] = r
        return out

    @property
    def inputs(self) -> list:
        return sorted({f.input for f in self.features})

    @property
    def max_delay_s(self) -> float:
        return max([f.delay_s for f in self.features], default=0.0)

    def predict(self, log: DriftLog, cache: dict | None = None, distance_shrink: bool = True) -> dict:
        """{channel: (n,) μm}. With ``distance_shrink`` (default), a channel that has a baseline and a finite
        ``shrink_scale`` predicts ``base + g(ρ)·(model − base)`` per sample (ρ: :meth:`rho`; g: :func:`distance_weight`),
        which equals the fixed linear model wherever ρ ≤ 1. ``distance_shrink=False``: the fixed linear model (what
        the exported controller gains run). Causal: the rule at a row uses that row's inputs (and the causal
        features) only."""
        cache = {} if cache is None else cache
        out = {ch: c.intercept_um + feature_matrix(log, c.features, cache) @ c.coef for ch, c in self.channels.items()}
        if not distance_shrink:
            return out
        rhos = self.channel_rho(log, cache) \
            if any(c.base is not None and np.isfinite(c.shrink_scale) for c in self.channels.values()) else {}
        for ch, c in self.channels.items():
            if c.base is None or rhos.get(ch) is None or not np.isfinite(c.shrink_scale):
                continue
            bf, ba, bc = c.base
            b = ba + feature_matrix(log, bf, cache) @ np.asarray(bc)
            out[ch] = b + distance_weight(rhos[ch], c.shrink_scale) * (out[ch] - b)
        return out

    def band_um(self, log, cache: dict | None = None) -> dict:
        """The 95 % band half-width per row {channel: (n,) μm}: ``band95_um · max(1, ρ)^band_gamma`` with the
        channel's ρ (:meth:`channel_rho`; constant where the model records no distance)."""
        rhos = self.channel_rho(log, cache)
        one = np.ones(len(log.time_s))
        return {ch: c.band95_um * (one if rhos[ch] is None else np.maximum(1.0, rhos[ch]) ** c.band_gamma)
                for ch, c in self.channels.items()}

    # -- controller form --------------------------------------------------------------------
    def to_json(self) -> dict:
        feats = self.features
        ids = {f.key: f"f{i}" for i, f in enumerate(feats)}
        units = {"temp": "degC", "speed_rpm": "rpm"}
        return {
            "schema": SCHEMA, "schema_version": SCHEMA_VERSION,
            "description": "Causal thermal-drift model: prediction_um(t) = intercept_um + sum(coef * feature(t)); "
                           "the controller compensates by subtracting the prediction.",
            "units": {"time": "s", "temperature": "degC", "speed": "rpm", "displacement": "um"},
            "filter": "v[k] = (u[k]/scale)**power; y[0] = v[0]; y[k] = y[k-1] + (1 - exp(-(t[k]-t[k-1])/tau_s)) * "
                      "(v[k] - y[k-1]); tau_s = 0: y = v (exact for v held at v[k] over (t[k-1], t[k]]; "
                      "run from power-on, at every logged sample)",
            "delay": "feature(t) = y(t - delay_s), linear interpolation between samples at or before t; "
                     "before the first sample: y[0]",
            "missing_samples": "hold the last valid value of the input",
            "inputs": [{"name": i, "unit": units["temp"] if i.startswith("temp_") else units.get(i, "")}
                       for i in self.inputs],
            "features": [{"id": ids[f.key], "input": f.input, "power": f.power, "scale": f.scale,
                          "tau_s": f.tau_s, "delay_s": f.delay_s} for f in feats],
            "channels": {ch: self._channel_json(c, ids, ch) for ch, c in self.channels.items()},
            "fitted_on": self.meta,
        }

    @staticmethod
    def _channel_json(c, ids, ch) -> dict:
        out = {"output": f"{ch}_um", "family": c.family, "hyper": c.hyper, "intercept_um": c.intercept_um,
               "terms": [{"feature": ids[f.key], "coef": float(b), "unit": f.unit()} for f, b in zip(c.features, c.coef)],
               "band95_um": c.band95_um, "band_gamma": float(c.band_gamma),
               "band_rule": "band(t) = band95_um * max(1, rho(t)) ** band_gamma; rho = Mahalanobis distance of the inputs at t "
                            "from the fitting data (fitted_on.novelty) / fitted_on.novelty.range_distance; where the "
                            "channel has feature_distance, rho = max(that, the same distance of its listed features)"}
        if c.novelty:
            nv = c.novelty
            out["feature_distance"] = {
                "rule": "rho_features(t) = norm((f(t) - mean) @ whiten) / range_distance over the listed features f "
                        "(the channel's own filtered inputs); the channel's rho = max(rho_inputs, rho_features)",
                "features": [ids[f.key] for f in nv["features"]], "mean": np.asarray(nv["mean"], float).tolist(),
                "whiten": np.asarray(nv["whiten"], float).tolist(), "range_distance": float(nv["range_distance"])}
        if c.base is not None and np.isfinite(c.shrink_scale):
            bf, ba, bc = c.base
            out["distance_shrink"] = {
                "rule": "prediction_um(t) = base(t) + g(rho(t)) * (model(t) - base(t)); g = 1 for rho <= 1, "
                        "exp(-(rho - 1) / scale) beyond; model: intercept_um + terms; base: the OLS baseline below",
                "scale": c.shrink_scale,
                "base": {"intercept_um": float(ba), "terms": [{"feature": ids[f.key], "coef": float(b), "unit": f.unit()}
                                                            for f, b in zip(bf, bc)]}}
        return out

    @classmethod
    def from_json(cls, obj, path="<model>") -> "DriftModel":
        """Read the controller form back; errors name the file and the key."""
        def need(d, k, where):
            if not isinstance(d, dict) or k not in d:
                raise InputError(f"{path}: key '{where}{k}': missing")
            return d[k]
        if not isinstance(obj, dict):
            raise InputError(f"{path}: not a drift model: expected a JSON object with schema {SCHEMA!r}, "
                             f"got a JSON {type(obj).__name__}")
        if "schema" not in obj and "format" in obj:   # another volcomp file, recognised by its own key
            raise InputError(f"{path}: key 'format': {_kind_of(obj['format'])}, not a drift model "
                             "(drift_model.json from `volcomp diagnose --drift`)")
        if need(obj, "schema", "") != SCHEMA:
            raise InputError(f"{path}: key 'schema': expected {SCHEMA!r}, got {obj.get('schema')!r}")
        if need(obj, "schema_version", "") != SCHEMA_VERSION:
            raise InputError(f"{path}: key 'schema_version': expected {SCHEMA_VERSION}, got {obj['schema_version']!r}")
        feats = {}
        for i, f in enumerate(need(obj, "features", "")):
            try:
                feats[f["id"]] = Feature(str(f["input"]), float(f["tau_s"]), float(f["delay_s"]), int(f["power"]),
                                         float(f["scale"]))
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError(f"{path}: key 'features[{i}]': expected id, input, power, scale, tau_s, delay_s "
                                 f"({exc})") from None
            if feats[f["id"]].tau_s < 0 or feats[f["id"]].delay_s < 0:
                raise InputError(f"{path}: key 'features[{i}]': expected tau_s >= 0 and delay_s >= 0")
        _refuse_withdrawn(obj, path)
        chans = {}
        for ch, c in need(obj, "channels", "").items():
            try:
                chans[ch] = _channel_from_json(c, feats)
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError(f"{path}: key 'channels.{ch}': expected intercept_um and terms "
                                 f"[{{feature, coef}}] naming listed features ({exc!r})") from None
        return cls(chans, obj.get("fitted_on", {}))

    def save(self, path):
        from ..io import write_json
        return write_json(path, self.to_json())

    @classmethod
    def load(cls, path) -> "DriftModel":
        try:
            obj = json.loads(read_document_text(path, "a drift model"))
        except FileNotFoundError:
            raise InputError(f"{path}: no such file") from None
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: line {exc.lineno}, column {exc.colno}: not JSON ({exc.msg})") from None
        return cls.from_json(obj, path)


def _channel_from_json(c: dict, feats: dict) -> ChannelFit:
    """One channel of the controller form, its features looked up in ``feats`` {id: Feature}; raises KeyError,
    TypeError or ValueError on what it cannot read (the caller names the file and the key)."""
    terms = c["terms"]
    fl = [feats[t["feature"]] for t in terms]
    base, scale = None, float("inf")
    if c.get("distance_shrink") is not None:
        ds = c["distance_shrink"]
        scale = float(ds["scale"])
        if not scale > 0:
            raise ValueError(f"distance_shrink.scale must be > 0, got {scale}")
        base = ([feats[t["feature"]] for t in ds["base"]["terms"]], float(ds["base"]["intercept_um"]),
                np.array([float(t["coef"]) for t in ds["base"]["terms"]]))
    nv = None
    if c.get("feature_distance") is not None:
        fd = c["feature_distance"]
        nf = [feats[i] for i in fd["features"]]
        Wf = np.array(fd["whiten"], float).reshape(len(nf), -1)
        mf = np.array(fd["mean"], float)
        d0 = float(fd["range_distance"])
        if mf.shape != (len(nf),) or not d0 > 0:
            raise ValueError("feature_distance: expected one mean per feature and range_distance > 0")
        nv = {"features": nf, "mean": mf, "whiten": Wf, "range_distance": d0}
    gamma = float(c.get("band_gamma", 1.0))     # files before the ρ-power band: γ = 1
    if not 0 <= gamma <= 10:
        raise ValueError(f"band_gamma must be in [0, 10], got {gamma}")
    return ChannelFit(c.get("family", ""), c.get("hyper", ""), fl, float(c["intercept_um"]),
                      np.array([float(t["coef"]) for t in terms]), float(c.get("band95_um") or "nan"),
                      base, scale, nv, gamma)


def _refuse_withdrawn(obj: dict, path) -> None:
    """Refuse a model file that uses a prediction rule no longer applied (the disagreement gate, the per-input range
    term of ρ; docs/decisions): predicting without it would silently differ from what the file describes."""
    if "input_range" in ((obj.get("fitted_on") or {}).get("novelty") or {}):
        raise InputError(f"{path}: key 'fitted_on.novelty.input_range': the per-input range term of the distance is no "
                         "longer applied; refit the model with `volcomp diagnose --drift LOG --out DIR`")
    for ch, c in (obj.get("channels") or {}).items():
        if isinstance(c, dict) and c.get("disagreement_gate") is not None:
            raise InputError(f"{path}: key 'channels.{ch}.disagreement_gate': the disagreement gate is no longer "
                             "applied; refit the model with `volcomp diagnose --drift LOG --out DIR`")

def input_novelty(model, log) -> np.ndarray | None:
    """Mahalanobis distance (n,) of each row's inputs from the model's fitting data (``fitted_on.novelty``
    in drift_model.json), or None when the model records none. Causal: row by row."""
    nov = (model.meta or {}).get("novelty")
    if not nov:
        return None
    try:
        U = np.stack([input_values(log, name) for name in nov["inputs"]], axis=1)
    except InputError:          # an input the model does not need is missing: no distance, the prediction stands
        return None
    return mahalanobis(U, np.asarray(nov["mean"], float), np.asarray(nov["whiten"], float).reshape(len(nov["inputs"]), -1))
