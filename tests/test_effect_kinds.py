"""The effect-kind registry (errormap/effect_kinds.py): every kind the simulator can draw and the
diagnosis can name is in it, the two vocabularies name the same physics, each consumer covers
exactly its kinds, and an unknown kind is refused — in code a ValueError, in a user's file one
line naming the file and the key (exit 2) — never drawn or exported as some other kind."""
import json

import numpy as np
import pytest

from compensation.app.cli import main
from errormap import effect_kinds as ek
from errormap.diagnosis import effects as fx
from errormap.chain_elements import ChainElementSet
from errormap.elements import A_ELEMENTS, IDX, X_ELEMENTS, Z_ELEMENTS
from errormap.chain_truth import (CHAIN_TRUTH_ONLY as OUT_OF_CATALOGUE, EFFECT_DEFAULTS, ChainTruth as TruthGrinder,
                                  SIMULATED_KINDS, independent_effect_parameters, make_chain_truth, random_axes)

SEED = 11
N_POINTS = 200
SAME_PHYSICS_UM = 1e-9
"""The simulator's sinusoid and the diagnosis's basis with the same parameters are the same
formula evaluated in a different order (sin(w + φ) against A·cosφ·sin w + A·sinφ·cos w): they
agree to float rounding of μm/μrad-sized values, far below a nanometre."""
KIND_AXES = {k: ek.effect_kind(k).axes(("x", "z"), ("a",)) for k in ek.DIAGNOSED_KINDS}
"""The grinder's axes of each diagnosed kind, from the registry."""
AXIS_ELEMENTS = {"x": X_ELEMENTS, "z": Z_ELEMENTS, "a": A_ELEMENTS, "x*z": X_ELEMENTS + Z_ELEMENTS}


def reference(machine, conditions):
    """The terms' references (errormap.diagnosis.effects.Context.ref): strokes, 20 °C, the first time_s."""
    t = conditions.get("time_s")
    return {"strokes": {k: tuple(machine.strokes[k]) for k in ("x_mm", "z_mm", "a_deg")}, "ref_temp_c": 20.0,
            "ref_time_s": float(np.min(t)) if t is not None else 0.0}


def test_every_name_is_registered_once():
    names = [n for k in ek.EFFECT_KINDS for n in (k.name, *k.aliases)]
    assert len(names) == len(set(names))
    assert all(k.acts_on in ("linear", "rotary", "any", "pair") for k in ek.EFFECT_KINDS)
    for k in ek.EFFECT_KINDS:
        assert ek.effect_kind(k.name) is k
        assert all(ek.effect_kind(a) is k for a in k.aliases)


def test_simulator_draws_registered_kinds_only():
    drawn = {k.name for k in ek.EFFECT_KINDS if k.simulator}   # the registry's kinds with a simulator name
    assert set(SIMULATED_KINDS) == {ek.effect_kind(n).name for n in EFFECT_DEFAULTS} == drawn
    assert {ek.effect_kind(n).name for n in independent_effect_parameters(np.random.default_rng(0))} == drawn
    assert set(OUT_OF_CATALOGUE) == set(ek.TRUTH_ONLY) == {"bump", "a_tilt", "squareness", "squareness_xz", "a_lobe_x",
                                                                "xz_saddle"}
    for kind in (k for k in ek.EFFECT_KINDS if k.simulator):
        assert ek.effect_kind(kind.simulator) is kind
        assert kind.truth_only == (not kind.diagnosed)


def test_the_diagnosis_fits_exactly_the_diagnosed_kinds(grinder):
    """Its library, the axes of each kind (generic in the registry, the grinder's words here)
    and a basis for every kind, from the registry."""
    assert ek.DIAGNOSED_KINDS == ("thermal", "drift", "reversal", "periodic", "harmonic", "interaction")
    assert KIND_AXES == {"thermal": ("x", "z"), "drift": ("x", "z"), "reversal": ("x", "z", "a"),
                            "periodic": ("x", "z"), "harmonic": ("a",), "interaction": ("x*z",)}
    assert not set(ek.TRUTH_ONLY) & set(ek.DIAGNOSED_KINDS)
    rng = np.random.default_rng(SEED)
    axes = random_axes(grinder, N_POINTS, rng)
    cond = {"temp_c": 20 + rng.random(N_POINTS), "time_s": np.arange(N_POINTS) * 10.0,
            **{f"dir_{a}": rng.choice([-1.0, 1.0], N_POINTS) for a in "xza"}}
    ctx = fx.Context.build(grinder, axes, cond, reference(grinder, cond))
    for kind in ek.DIAGNOSED_KINDS:
        spec = ek.diagnosed_kind(kind)
        cand = fx.Candidate(kind, KIND_AXES[kind][0], AXIS_ELEMENTS[KIND_AXES[kind][0]][0])
        b = fx.basis(cand, ctx, period_mm=10.0, order=40)
        assert b.shape == (N_POINTS, spec.n_linear) and np.all(np.isfinite(b))
        term = fx.EffectTerm(cand, np.ones(spec.n_linear), ctx.ref, 10.0 if kind == "periodic" else None,
                             40 if kind == "harmonic" else None)
        assert set(term.parameters()) == {n.format(u=fx.unit_of(cand.element)) for n, _ in spec.parameters}


@pytest.mark.parametrize("sim, canonical, element, params, basis_args, axis_word", [
    ("pitch", "periodic", "dx_x", {"amplitude_um": 3.0, "period_mm": 7.0, "phase_rad": 0.4},
     {"period_mm": 7.0}, "X"),
    ("worm", "harmonic", "ex_a", {"amplitude_urad": 90.0, "teeth": 37, "phase_rad": 2.1}, {"order": 37}, "A"),
])
def test_simulator_alias_is_the_same_physics_as_the_diagnosis_kind(grinder, sim, canonical, element, params,
                                                                   basis_args, axis_word):
    """Merging ``pitch``/``periodic`` and ``worm``/``harmonic`` into one kind each is only right if
    they are the same term: the simulator's addition to the element equals the diagnosis basis
    with the amplitude and phase written as its ``s·sin + c·cos`` coefficients."""
    assert ek.effect_kind(sim).name == canonical and ek.effect_kind(canonical).simulator == sim
    el = ChainElementSet.zeros(grinder)
    axes = random_axes(grinder, N_POINTS, np.random.default_rng(SEED))
    by_alias = TruthGrinder(grinder, el, {sim: params}).element_values(axes)[:, IDX[element]]
    by_name = TruthGrinder(grinder, el, {canonical: params})
    assert set(by_name.effects) == set(TruthGrinder(grinder, el, {sim: params}).effects) == {f"{canonical}:{axis_word}"}
    amp = params.get("amplitude_um", params.get("amplitude_urad"))
    coef = amp * np.array([np.cos(params["phase_rad"]), np.sin(params["phase_rad"])])
    ctx = fx.Context.build(grinder, axes, {}, reference(grinder, {}))
    axis = KIND_AXES[canonical][0]
    fitted_form = fx.basis(fx.Candidate(canonical, axis, element), ctx, **basis_args) @ coef
    np.testing.assert_allclose(by_alias, fitted_form, rtol=0, atol=SAME_PHYSICS_UM)
    np.testing.assert_allclose(by_name.element_values(axes)[:, IDX[element]], by_alias, rtol=0, atol=0)


def test_unknown_kinds_raise_in_code(grinder):
    with pytest.raises(ValueError, match="unknown effect kind 'bogus'"):
        ek.effect_kind("bogus")
    with pytest.raises(ValueError, match="'bogus'"):
        TruthGrinder(grinder, ChainElementSet.zeros(grinder), {"bogus": {}})
    with pytest.raises(ValueError, match="unknown effect kind 'bogus'"):
        fx.Candidate("bogus", "x", "dx_x")
    with pytest.raises(ValueError, match="simulator's name; the diagnosis calls it 'periodic'"):
        fx.Candidate("pitch", "x", "dx_x")
    with pytest.raises(ValueError, match="simulated only"):
        fx.Candidate("bump", "x*z", "dx_x")
    with pytest.raises(ValueError, match="effect kind not simulated on a machine-tool chain: 'drift'"):
        make_chain_truth(grinder, 0, effects=["drift"])   # the diagnosis fits drift; the simulator draws none


def test_the_loop_never_takes_an_unknown_kind_for_another(grinder):
    """The machine tools' loop builds a term's columns by its kind: an unknown one is an error, never a default."""
    from errormap.diagnosis.chain_effects import effect_columns
    mt = grinder
    axes = random_axes(grinder, 5, np.random.default_rng(SEED))
    with pytest.raises(ValueError, match="unknown effect kind 'bogus'"):
        effect_columns(mt, "bogus", ("X", "Z"), axes, {})


def _one_error_line(capsys) -> str:
    """The one error line of a refused command (progress lines may precede it; no traceback)."""
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ": error" in ln]
    assert len(lines) == 1 and "Traceback" not in err
    return lines[0]


def test_export_refuses_an_unknown_kind_in_a_diagnosis_file(grinder, tmp_path, capsys):
    el_path = ChainElementSet.zeros(grinder).save(tmp_path / "el.json")
    diag = tmp_path / "diagnosis.json"
    diag.write_text(json.dumps({"effects": [
        {"kind": "reversal", "axis": "z", "element": "dz_z", "parameters": {"backlash_um": {"value": 8.0}}},
        {"kind": "wobble", "axis": "x", "element": "dx_x", "parameters": {}}]}))
    out = tmp_path / "lc"
    assert main(["export", str(el_path), "--format", "linuxcnc", "--diagnosis", str(diag), "--out", str(out),
                 "--force"]) == 2
    line = _one_error_line(capsys)
    assert str(diag) in line and "effects[1].kind" in line and "'wobble'" in line
    assert not out.exists()


def test_compensate_refuses_an_unknown_kind_in_a_diagnosed_model(grinder, tmp_path, capsys):
    ChainElementSet.zeros(grinder).save(tmp_path / "updated_elements.json")
    model = tmp_path / "model.json"
    model.write_text(json.dumps({"format": "volcomp-diagnosed-model/1", "elements": "updated_elements.json",
                                 "terms": [{"kind": "wobble", "axis": "x", "element": "dx_x",
                                            "coefficients": [1.0], "reference": {"ref_temp_c": 20.0,
                                                                                 "ref_time_s": 0.0}}]}))
    path = tmp_path / "path.csv"
    mid = (grinder.stroke_lo + grinder.stroke_hi) / 2
    path.write_text("x_mm,z_mm,a_deg\n" + "\n".join(f"{mid[0] + i},{mid[1]},{mid[2]}" for i in range(3)) + "\n")
    out = tmp_path / "out"
    assert main(["compensate", str(path), "--model", str(model), "--method", "exact", "--out", str(out)]) == 2
    line = _one_error_line(capsys)
    assert str(model) in line and "terms[0].kind" in line and "'wobble'" in line
    assert not out.exists()


def test_simulate_takes_the_canonical_name_for_the_simulator_one(tmp_path):
    """``--effect periodic`` is ``--effect pitch``: the same truth, recorded under the canonical name and its axis."""
    out = {}
    for name in ("pitch", "periodic"):
        out[name] = tmp_path / name
        assert main(["simulate", "--seed", "3", "--out", str(out[name]), "--effect", name, "--checks", "20"]) == 0
    info = {n: json.loads((d / "truth.json").read_text()) for n, d in out.items()}
    assert info["periodic"]["effects"] == info["pitch"]["effects"] and set(info["pitch"]["effects"]) == {"periodic:X"}
    rows = {n: [ln for ln in (d / "checks.csv").read_text().splitlines() if not ln.startswith("#")]
            for n, d in out.items()}
    assert rows["periodic"] == rows["pitch"]
