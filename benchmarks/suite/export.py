"""What each controller table leaves, against the identified model and against the simulated truth.

Machine: the default grinder; truth ``make_chain_truth(100 + seed, effects=(reversal, interaction))`` (8 μm Z
backlash; X positioning that grows with Z: a coupling no per-axis table and no 23-element model holds);
model = the 23 elements identified from simulated tracker sweeps (2 μm noise, seed ``seed``); backlash and
axis-only terms diagnosed from 400 simulated check measurements (1 μm noise) against that model. Never the
truth's own numbers. Each table is re-simulated on the controller (:func:`compensation.export.check_export`)
on the default flute (2,800 points) and random points over the volume; residual = per-point norm, max, μm.
Anchor: no compensation (or the plain table beside the improved one).

    python -m benchmarks.run export
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from compensation import export as ex
from errormap.chain_sweeps import simulated_sweeps
from errormap.io import write_json
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth
from errormap.identification import ChainIdentification
from errormap.sweeps import sweeps_from_columns

FLUTE_REGION = {"x_mm": (90.0, 116.0), "z_mm": (0.3, 0.3)}
"""The default flute's axis box (x 90..115.3 mm, z = 0.3 mm): the per-joint fitting region."""
TOLERANCES_UM = (4.0, 2.0, 1.0, 0.5)
"""Table tolerances of the full run (the figures at the last); the quick run builds the first only."""
CHECK_POINTS = (2000, 200)
"""Random volume points checked: full, quick."""

TITLE = "Controller tables (grid, ISO component tables, LinuxCNC per-joint): what each leaves on the flute and the volume"
DATA = ("default grinder; truth `make_chain_truth(100 + seed, effects=(reversal, interaction))`; model = 23 elements "
        "identified from simulated sweeps (2 μm noise); diagnosis from 400 simulated checks (1 μm); default flute "
        "(2,800 points) + 2,000 random volume points")


def _diagnosis(m, truth, el, seed):
    """The user's path: check measurements -> closed loop on the identified model -> diagnosed terms."""
    from errormap.chain_elements import ChainElementSet
    from errormap.diagnosis.chain_loop import ChainChecks, closed_loop_chain
    checks = ChainChecks.from_columns(m, truth.check_measurements(n=400, noise_um=1.0, seed=seed))
    with tempfile.TemporaryDirectory() as tmp:
        el_chain = ChainElementSet.load(el.save(Path(tmp) / "el.json"), m)
    d = closed_loop_chain(m, el_chain, checks, cov=None)
    terms = d["_models"]["terms"] if d["kept_stage"].endswith("plus_effects") else []
    with tempfile.TemporaryDirectory() as tmp:
        p = write_json(Path(tmp) / "diagnosis.json", {"machine": m.name, "machine_sha256": m.sha256,
                                                       "effects": [t.to_dict() for t in terms]})   # as diagnose writes it
        try:
            back, left = ex.reversal_from_diagnosis(p, ex.ModelError(m, el_chain))
            kept = [t for t in terms if f"{t.kind}({'*'.join(t.axes)}) on {t.element}" not in left]
            note = f"diagnosed terms a per-joint table carries: {len(kept)} (left out: {left})"
            back = back if kept else None
        except ValueError as exc:  # the refusal itself is a result worth reporting
            back, note = None, f"diagnosis not usable by a per-joint table: {exc}"
    return el_chain, terms, back, note


def run_seed(seed: int, tolerances, n_volume: int) -> tuple[dict, list[str]]:
    """Every table on one truth: ``{label: (check, values)}`` and notes."""
    from errormap.diagnosis.loop_model import ChainModelField
    m = load_machine()
    truth = make_chain_truth(m, 100 + seed, effects=("reversal", "interaction"))
    el = ChainIdentification(gauge="first-station").fit(
        sweeps_from_columns(simulated_sweeps(truth, noise_um=2.0, seed=seed)), m).elements_
    model = ex.ModelError(m, el)
    sets, tool, cache, rows = ex.check_sets(m, n_volume, seed), ex.truth_tool_points(truth, m), {}, {}

    def one(kind, label, mdl, cch, tol=1.0, **options):
        table, _, chk = ex.build_checked_table(kind, mdl, m, tol, sets, tool, cch, **options)
        rows[label] = (chk, table.n_values())

    for tol in tolerances:
        for fmt in ("grid", "iso-tables"):
            one(fmt, f"{fmt} {tol:g}", model, cache, tol)
    one("linuxcnc", "linuxcnc whole", model, cache, seed=seed)
    one("linuxcnc", "linuxcnc flute", model, cache, region=FLUTE_REGION, seed=seed)
    el_chain, terms, back, note = _diagnosis(m, truth, el, seed)
    if back is not None:
        one("linuxcnc", "linuxcnc flute + backlash", back, {}, region=FLUTE_REGION, seed=seed)
    axis_only = [t for t in terms if t.kind not in ("thermal", "reversal")]
    if axis_only:
        one("grid", "grid + terms", ex.ModelError(m, field=ChainModelField(m, el_chain, axis_only)), {}, tolerances[-1])
    effects = ", ".join(f"{t.kind}({'*'.join(t.axes)}) on {t.element}" for t in terms) or "nothing"
    excluded = next(iter(rows.values()))[0]["volume"]["excluded"]
    return rows, [f"diagnosis selected: {effects}; {note}",
                  f"volume points excluded (the model cannot compensate them): {excluded}"]


def _max(chk, where, kind="true", base=None):
    s = chk[where] if base is None else chk[where][base]
    return float(s[kind]["max_um"])


def run(quick: bool, seed: int) -> dict:
    """Full: tolerances 4, 2, 1, 0.5 μm and 2,000 volume points; quick: 4 μm and 200 points (same figures)."""
    t0 = time.perf_counter()
    tols = TOLERANCES_UM[:1] if quick else TOLERANCES_UM
    rows, notes = run_seed(seed, tols, CHECK_POINTS[quick])
    t = tols[-1]
    base = rows[f"grid {t:g}"][0]
    none_f, none_v = _max(base, "flute", base="baseline_none"), _max(base, "volume", base="baseline_none")
    fig = lambda what, v, anchor, av, res="true": {"what": what, "value": v, "unit": "μm", "residual": res,  # noqa: E731
                                                   "anchor": anchor, "anchor_value": av}
    figs = [fig("exact compensation with the model (no table), flute max", _max(base, "flute", base="baseline_exact"),
                "uncompensated", none_f),
            fig("exact compensation with the model (no table), volume max", _max(base, "volume", base="baseline_exact"),
                "uncompensated", none_v)]
    for fmt in ("iso-tables", "grid"):
        chk, n = rows[f"{fmt} {t:g}"]
        figs += [fig(f"{fmt}, tolerance {t:g} μm ({n} values), flute max", _max(chk, "flute"), "uncompensated", none_f),
                 fig(f"{fmt}, tolerance {t:g} μm ({n} values), volume max", _max(chk, "volume"), "uncompensated", none_v)]
    chk, n = rows["linuxcnc flute"]
    figs.append(fig(f"LinuxCNC per-joint, fitted over the flute ({n} values), flute max", _max(chk, "flute"),
                    "uncompensated", none_f))
    chk, n = rows["linuxcnc whole"]
    figs.append(fig(f"LinuxCNC per-joint, fitted over the whole strokes ({n} values), volume max", _max(chk, "volume", "model"),
                    "uncompensated", _max(chk, "volume", "model", "baseline_none"), "model"))
    if "linuxcnc flute + backlash" in rows:
        figs.append(fig("LinuxCNC per-joint over the flute + diagnosed backlash, flute max",
                        _max(rows["linuxcnc flute + backlash"][0], "flute"), "without the backlash column",
                        _max(rows["linuxcnc flute"][0], "flute")))
    if "grid + terms" in rows:
        figs.append(fig(f"grid of the model + diagnosed axis-only terms, tolerance {t:g} μm, volume max",
                        _max(rows["grid + terms"][0], "volume"), f"iso-tables, tolerance {t:g} μm",
                        _max(rows[f"iso-tables {t:g}"][0], "volume")))
    for tol in tols[:-1]:
        notes.append(f"tolerance {tol:g} μm: " + "; ".join(
            f"{fmt} {rows[f'{fmt} {tol:g}'][1]} values, flute / volume true max "
            f"{_max(rows[f'{fmt} {tol:g}'][0], 'flute'):.3g} / {_max(rows[f'{fmt} {tol:g}'][0], 'volume'):.3g} μm"
            for fmt in ("grid", "iso-tables")))
    return {"figures": figs, "notes": notes}
