"""The closed loop on the built-in grinder through the user's CLI path, and the flute compensated end to end.

``volcomp sweeps`` (2 μm) → ``volcomp simulate`` (800 checks at 1 μm) → ``volcomp identify``
→ ``volcomp diagnose`` → evaluation against the hidden truth (only here). With ``flute=True``
on a no-effect case, also ``volcomp compensate flute.csv --method exact --model`` with the
loop's ``model.json`` and with the identified elements, scored by the TRUE residual on the
hidden truth. Per case (truth family ``default``, seed, effect of :data:`EXPECTED`): the held-out MEASURED RMS
of the kept stage beside the identified stage's (the plain baseline), whether the first effect named is the
injected one; on the no-effect case, the flute's TRUE residual with the loop's model and with the identified
elements alone.
"""
from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

EXPECTED = {"none": None, "pitch": ("periodic", "X"), "reversal": ("reversal", "Z"), "thermal": ("thermal", "X"),
            "interaction": ("interaction", "X*Z"), "worm": ("harmonic", "A")}
"""The effect the loop should name first: (kind, the axis word(s) of the machine, as diagnosis.json names them)."""
N_PROBE = 5000
Z95 = 1.959963984540054
# the conditions under which the flute is ground and scored: the truth's reference conditions
FLUTE_CONDITIONS = ["--temp-c", "20", "--time-s", "0", "--dir-x", "1", "--dir-z", "1", "--dir-a", "1"]


TRUTH_ELEMENT = {"thermal": "dx_x", "reversal": "dz_z", "pitch": "dx_x", "worm": "ex_a", "interaction": "dx_x"}
"""The element each simulated effect acts on (errormap.chain_truth.ChainTruth.element_values)."""


def _implied_sign(machine, truth_element: str, found_element: str):
    """Factor turning the truth's coefficient into the one a term on ``found_element`` has:
    1 on the same element; on a WCS component, the sign of the truth element's Jacobian column
    when that column is a constant unit vector along it (``dx_x`` acts as −x); else None (the
    term's parameter lives in another unit or frame: not comparable)."""
    from errormap.diagnosis.effects import WCS_ELEMENTS
    from errormap.chain_kernel import error_jacobian
    from errormap.elements import IDX
    from errormap.chain_truth import random_axes
    if found_element == truth_element:
        return 1.0
    if found_element not in WCS_ELEMENTS:
        return None
    col = error_jacobian(machine, random_axes(machine, 8, np.random.default_rng(0)))[:, :, IDX[truth_element]]
    unit = np.zeros(3)
    unit[WCS_ELEMENTS.index(found_element)] = 1.0
    for sign in (1.0, -1.0):
        if np.allclose(col, sign * unit, atol=1e-9):
            return sign
    return None


def _param_cover(effect, found, truth):
    """Whether the found effect's 95 % interval holds the parameter the truth implies for the found
    term (None if not comparable: see :func:`_implied_sign`)."""
    p = found["parameters"]
    t = truth.parameters(effect)
    key = {"thermal": ("k_um_per_mm_c", "k_um_per_mm_c"), "reversal": ("backlash_um", "backlash_um"),
           "pitch": ("period_mm", "period_mm"), "worm": ("amplitude_urad", "amplitude_urad"),
           "interaction": ("corner_um", "corner_um")}[effect]
    sign = _implied_sign(truth.machine, TRUTH_ELEMENT[effect], found["element"])
    if sign is None or key[0] not in p or not np.isfinite(p[key[0]].get("se") or np.nan):
        return None
    v, se = p[key[0]]["value"], p[key[0]]["se"]
    tv = t[key[1]] * (1.0 if effect in ("pitch", "worm") else sign)
    if effect == "worm":
        v, tv = abs(v), abs(tv)
    return bool(abs(v - tv) <= Z95 * se)


def _stats(r_um) -> dict:
    n = np.linalg.norm(r_um, axis=1)
    return {"max_um": float(n.max()), "rms_um": float(np.sqrt(np.mean(n**2)))}


def _flute(main, td: Path, m, truth, points_per_turn=None) -> dict:
    """The default flute compensated (exact) with the loop's model and with the identified
    elements alone: TRUE residual on the truth (reference conditions) and the MODEL residual
    compensate reports."""
    from compensation.evaluate import true_residual_um
    from compensation.toolpath import flute_path
    from errormap.io import read_table, write_csv
    from errormap.chain_kernel import forward
    fp = flute_path() if points_per_turn is None else flute_path(points_per_turn=points_per_turn)
    nominal = fp.axes(m)
    write_csv(td / "flute.csv", dict(zip(("x_mm", "z_mm", "a_deg"), nominal.T)), float_fmt="%.12g")
    targets = forward(m, nominal)
    out = {"uncompensated": _stats(true_residual_um(truth, nominal, targets))}
    for label, model in (("loop_model", td / "diag" / "model.json"), ("identified", td / "el.json")):
        od = td / f"comp_{label}"
        extra = FLUTE_CONDITIONS if label == "loop_model" else []
        rc = main(["compensate", str(td / "flute.csv"), "--model", str(model), "--method", "exact", "--out", str(od),
                   *extra])
        if rc != 0 and extra:   # a model without condition terms refuses the conditions: it is the same field
            rc = main(["compensate", str(td / "flute.csv"), "--model", str(model), "--method", "exact", "--out",
                       str(od), "--force"])
        if rc != 0:
            out[label] = {"refused_exit": rc}
            continue
        t = read_table(od / "flute.csv")
        comp = np.stack([t.float(k) for k in ("x_mm", "z_mm", "a_deg")], axis=1)
        summ = json.loads((od / "compensate_summary.json").read_text())["files"][0]
        out[label] = dict(_stats(true_residual_um(truth, comp, targets)), model_max_um=summ.get("model_max_um"))
    return out


def run_case(family: str, seed: int, effect: str, flute: bool = False, also=None, checks: int = 800,
             flute_points_per_turn=None) -> dict:
    """One case (module doc); ``also(td, machine, truth, probe_seed)``: a further scoring of the same files
    (sweeps ``sw.csv``, checks ``sim/checks.csv``, identified ``el.json``), its result the row's ``also``."""
    from compensation.app.cli import main
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    from errormap.seeds import spawn_seeds
    from errormap.chain_truth import make_chain_truth, random_axes
    from errormap.chain_covariance import band_sd, covariance_path, read_chain_covariance
    t_cpu = time.process_time()
    eff = [] if effect == "none" else [effect]
    m = load_machine()
    noise_ss, probe_ss = spawn_seeds(seed, 2)  # the sweep noise (a CLI integer from its child) and the probe points
    truth = make_chain_truth(m, seed, effects=eff, family=family)
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        ea = sum((["--effect", e] for e in eff), [])
        q = ["--family", family, "--seed", str(seed)] + ea
        assert main(["sweeps", *q, "--noise-um", "2", "--seed-noise", str(int(noise_ss.generate_state(1)[0])), "--out", str(td / "sw.csv")]) == 0
        assert main(["simulate", *q, "--checks", str(checks), "--noise-um", "1", "--out", str(td / "sim")]) == 0
        assert main(["identify", str(td / "sw.csv"), "--out", str(td / "el.json")]) == 0
        assert main(["diagnose", str(td / "sim" / "checks.csv"), "--model", str(td / "el.json"),
                     "--out", str(td / "diag")]) == 0
        cpu_loop = time.process_time() - t_cpu
        s = json.loads((td / "diag" / "diagnosis.json").read_text())
        el = ChainElementSet.load(td / "el.json", m)
        cov = read_chain_covariance(covariance_path(td / "el.json"), el)
        upd = ChainElementSet.load(td / "diag" / "updated_elements.json", m)
        fl = _flute(main, td, m, truth, flute_points_per_turn) if flute and effect == "none" else None
        more = also(td, m, truth, probe_ss) if also is not None else None
    P = random_axes(m, N_PROBE, np.random.default_rng(probe_ss))
    et = ChainField(m, truth.elements).predict(P)
    e_id = ChainField(m, el).predict(P) - et
    sd = band_sd(m, el, cov, P)
    e_up = ChainField(m, upd).predict(P) - et
    found = s["effects"]
    exp = EXPECTED[effect]
    top = (found[0]["kind"], found[0]["axis"]) if found else None
    named = (not found) if exp is None else (top == exp)
    st = s["stages"]
    return {"family": family, "seed": seed, "effect": effect,
            "sweeps_rms_um": float(np.sqrt(np.mean(np.sum(e_id**2, axis=1)))),
            "sweeps_floor_um": float(np.sqrt(np.mean(np.sum(sd**2, axis=1)))),
            "band95_cover": float(np.mean(np.abs(e_id) <= Z95 * sd)),
            "updated_geometry_rms_um": float(np.sqrt(np.mean(np.sum(e_up**2, axis=1)))),
            "held_identified_um": st["identified"]["held_out"]["rms_um"],
            "held_updated_um": st["updated"]["held_out"]["rms_um"],
            "held_effects_um": st.get("updated_plus_effects", st["updated"])["held_out"]["rms_um"],
            "held_final_um": s["held_out_rms_um"],
            "held_final_over_floor": s.get("held_out_over_floor"),
            "kept_stage": s["kept_stage"],
            "effects": [f"{e['kind']} {e['axis']}" for e in found],
            "effects_elements": [e["element"] for e in found], "named_right": bool(named),
            "param_cover": None,
            "flute": fl, "also": more, "cpu_loop_s": cpu_loop, "cpu_s": time.process_time() - t_cpu}


TITLE = "Closed loop on the grinder (sweeps → identify → diagnose) and the flute compensated end to end"
DATA = ("simulated grinder (truth family `default`), sweeps at 2 μm, 800 checks at 1 μm (60/40 by seq), effects none, "
        "pitch X, reversal Z, thermal X, interaction X·Z, worm A, seed 0 (quick: the no-effect case, "
        "200 checks, a 280-point flute); "
        "the default flute (2,800 points) at the truth's reference conditions")


def run(quick: bool, seed: int) -> dict:
    effects = ["none"] if quick else list(EXPECTED)
    kw = {"checks": 200, "flute_points_per_turn": 40} if quick else {}
    rows = [run_case("default", seed, e, flute=True, **kw) for e in effects]
    med = lambda k, rs=rows: float(np.median([r[k] for r in rs]))  # noqa: E731
    fl = [r["flute"] for r in rows if r["flute"]]
    flm = lambda label, k="max_um": float(np.median([f[label][k] for f in fl]))  # noqa: E731
    eff = [r for r in rows if r["effect"] != "none"]
    figs = [{"what": f"held-out RMS of the kept stage, median over {len(rows)} runs", "value": med("held_final_um"),
             "unit": "μm", "residual": "measured", "anchor": "identified stage alone (plain)",
             "anchor_value": med("held_identified_um")},
            {"what": "flute with the loop's model, max", "value": flm("loop_model"), "unit": "μm", "residual": "true",
             "anchor": "identified elements alone", "anchor_value": flm("identified")},
            {"what": "flute with the loop's model, RMS", "value": flm("loop_model", "rms_um"), "unit": "μm",
             "residual": "true", "anchor": "uncompensated", "anchor_value": flm("uncompensated", "rms_um")}]
    if eff:
        figs.insert(1, {"what": "injected effect named first", "value": f"{sum(r['named_right'] for r in eff)}/{len(eff)}",
                        "unit": "", "residual": "none", "anchor": "no-effect runs with no effect named",
                        "anchor_value": f"{sum(r['named_right'] for r in rows if r['effect'] == 'none')}/{len(rows) - len(eff)}"})
    return {"figures": figs, "notes": []}
