"""The measurement side on machine-tool chain files: truth simulator, sweeps, identification, closed loop, CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest

from errormap.diagnosis.chain_loop import ChainChecks, closed_loop_chain, parameter_matrix
from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.identification import ChainIdentification, root_axis
from errormap.chain_truth import FAMILIES, TARGET_MAX_RANGE_UM, ChainTruth, make_chain_truth, volume_grid
from errormap.chain_sweeps import simulated_sweeps, swept_words
from errormap.chain_truth import make_chain_truth
from errormap.sweeps import read_sweeps, sweeps_from_columns, write_sweeps

EXACT_MM = 1e-9
"""Two implementations of the same rigid-body chain agree to round-off on ~1 m coordinates (double precision
gives ~1e-13 mm; 1e-9 leaves room for the different operation order)."""
NOISE_FREE_UM = 1e-6
"""Noise-free sweeps: the identification reproduces the truth's tool-point error exactly up to the Gauss–Newton
stopping rule (update < 1e-7 μm/μrad); 1e-6 μm is far below any measurement."""
GRINDER_AGREE_UM = 1e-3
"""Generic vs grinder identification on the same noisy sweeps (2 μm): both solve each body's rigid motion per
station exactly; they differ only in how the full-turn A axis' repeated station is combined (the grinder averages
the two poses, the generic fit ties one parameter) and in the stopping rule — 1e-3 μm RMS is 2000× below the
2 μm noise (measured 7e-5 μm)."""
BAND_FACTOR = 2.0
"""The identification's TRUE error over the volume lies within a factor 2 of the error its own covariance
propagates (one noise draw of a χ²-like quantity over ~400 parameters: a factor 2 either way is generous
for one draw, a wrong covariance or a biased estimate is off by far more)."""
PERIOD_REL_TOL = 1e-3
"""A pitch period found from 360 fitting checks over a 400 mm stroke: 0.1 % is 0.04 of a cycle of phase drift over
the ~45 cycles of the stroke (the refinement grid steps 0.025 %; measured 0.014 % off)."""
FLOOR_RATIO_TRUTH = 1.25
"""With the truth as the model, the held-out measured RMS is the noise itself: within the goal ratio 1.25
of the floor √3·σ (240 held-out points: the RMS of a χ²₃ sample is within ±6 % at 2σ)."""


@pytest.fixture(scope="module")
def mill():
    return load_machine("mill-xyz")


@pytest.fixture(scope="module")
def five():
    return load_machine("five-axis-ac")


@pytest.mark.parametrize("family", FAMILIES)
def test_truth_band_gauge_and_reproducible(mill, family):
    t = make_chain_truth(mill, 4, family=family)
    g = volume_grid(mill)
    e = np.linalg.norm(t.spatial_error(g), axis=1).max()
    lo, hi = TARGET_MAX_RANGE_UM[family]
    assert lo <= e <= hi
    for s in mill.function_slots:
        assert t.elements.functions[s][0] == 0.0        # zero at the first station (the gauge)
    t2 = make_chain_truth(mill, 4, family=family)          # same seed, same truth; another seed, another
    assert t2.elements.functions["dx_x"].tolist() == t.elements.functions["dx_x"].tolist()
    assert make_chain_truth(mill, 5, family=family).elements.functions["dx_x"].tolist() != t.elements.functions["dx_x"].tolist()


def test_full_turn_axis_is_closed(five):
    t = make_chain_truth(five, 4, family="independent")
    full = [a for a in five.axes if a.full_turn]
    assert [a.word for a in full] == ["C"]
    for s in five.slots_of("C"):
        assert t.elements.functions[s][-1] == t.elements.functions[s][0]
    e = t.spatial_error(np.array([[10.0, 20.0, -100.0, -30.0, 0.0], [10.0, 20.0, -100.0, -30.0, 360.0]]))
    assert np.abs(e[0] - e[1]).max() < NOISE_FREE_UM


def test_effects_generic_by_axis(mill):
    t = make_chain_truth(mill, 1, effects=["periodic:Y", "reversal:Z", "thermal:X", "interaction:X*Y"])
    q = np.array([[300.0, 200.0, -100.0]])
    cond = {"temp_c": np.array([24.0]), "dir_x": np.ones(1), "dir_y": np.ones(1), "dir_z": -np.ones(1)}
    v = t.element_values(q, **cond)
    v0 = t.elements.values(q)
    i = {n: j for j, n in enumerate(mill.slot_names)}
    p = t.effects
    assert v[0, i["dy_y"]] - v0[0, i["dy_y"]] == pytest.approx(
        p["periodic:Y"]["amplitude_um"] * np.sin(2 * np.pi * 200.0 / p["periodic:Y"]["period_mm"] + p["periodic:Y"]["phase_rad"]))
    assert v[0, i["dz_z"]] - v0[0, i["dz_z"]] == pytest.approx(-0.5 * p["reversal:Z"]["backlash_um"])
    assert v[0, i["dx_x"]] - v0[0, i["dx_x"]] == pytest.approx(
        p["thermal:X"]["k_um_per_mm_c"] * 4.0 * 300.0 + p["interaction:X*Y"]["corner_um"] * 300 * 200 / (600 * 400))
    with pytest.raises(ValueError, match="harmonic acts on"):
        make_chain_truth(mill, 1, effects=["harmonic"])
    with pytest.raises(ValueError, match="unknown effect kind"):
        make_chain_truth(mill, 1, effects=["wobble:X"])


def test_chain_sweeps_equal_grinder_sweeps():
    """The built-in grinder's truth and the grinder-chain file's (errormap.chain_truth) of the same elements
    give the same sweeps through the one simulator."""
    g, gc = load_machine(None), load_machine("grinder-chain")
    tg = make_chain_truth(g, 1)
    el = tg.elements
    tc = ChainTruth(gc, ChainElementSet(gc, el.stations, el.functions, el.constants), {})
    a = simulated_sweeps(tg, noise_um=0.0, seed=3)
    b = simulated_sweeps(tc, noise_um=0.0, seed=3)
    assert (a["axis"] == b["axis"]).all() and (a["station"] == b["station"]).all()
    for c in ("x_mm", "y_mm", "z_mm"):
        assert np.abs(a[c] - b[c]).max() < EXACT_MM


@pytest.mark.slow
@pytest.mark.parametrize("name", ["mill-xyz", "five-axis-ac"])
def test_identification_noise_free_is_exact(name):
    m = load_machine(name)
    t = make_chain_truth(m, 2, family="default")
    sw = sweeps_from_columns(simulated_sweeps(t, noise_um=0.0, seed=7), axes=swept_words(m))
    res = ChainIdentification().fit(sw, m).result_
    assert not res.unobservable
    g = m.stroke_lo + (m.stroke_hi - m.stroke_lo) * np.random.default_rng(0).random((2000, len(m.axes)))
    d = np.linalg.norm(ChainField(m, res.elements_).predict(g) - t.spatial_error(g), axis=1)
    assert d.max() < NOISE_FREE_UM


def test_root_axis(mill, five):
    assert root_axis(mill) == "Y"      # first linear axis of the work chain
    assert root_axis(five) == "X"      # the work chain has only rotary axes: the tool chain's first linear one


@pytest.mark.slow
@pytest.mark.parametrize("noise", [0.0, 2.0])
def test_generic_identification_agrees_with_grinder(noise):
    g, gc = load_machine(None), load_machine("grinder-chain")
    tg = make_chain_truth(g, 1)
    cols = simulated_sweeps(tg, noise_um=noise, seed=3)
    eg = ChainIdentification(gauge="first-station").fit(sweeps_from_columns(cols), g).elements_
    ec = ChainIdentification().fit(sweeps_from_columns(cols, axes=swept_words(gc)), gc).elements_
    grid = volume_grid(g, (9, 5, 13))
    d = np.linalg.norm(ChainField(g, eg).predict(grid) - ChainField(gc, ec).predict(grid), axis=1)
    assert np.sqrt(np.mean(d**2)) < (NOISE_FREE_UM if noise == 0 else GRINDER_AGREE_UM)
    for k in ("dy_oa", "dz_oa", "ey_oa", "ez_oa"):  # the A-axis line: the same gauge, the same numbers
        assert ec.constants[k] == pytest.approx(eg.constants[k], abs=max(NOISE_FREE_UM, 1e-2 * (noise > 0)))


@pytest.mark.slow
def test_mill_identification_within_its_noise_band(mill):
    t = make_chain_truth(mill, 6, family="independent")
    sw = sweeps_from_columns(simulated_sweeps(t, noise_um=2.0, seed=11), axes=swept_words(mill))
    res = ChainIdentification().fit(sw, mill).result_
    assert res.sigma_um == pytest.approx(2.0, rel=0.2)   # the ball residual gives the tracker noise back
    g = volume_grid(mill, 600)
    true_rms = np.sqrt(np.mean(np.sum((ChainField(mill, res.elements_).predict(g) - t.spatial_error(g)) ** 2, axis=1)))
    M = parameter_matrix(mill, res.elements_, g, res.param_slot, res.param_station)   # (n, 3, N)
    band = np.sqrt(np.einsum("nip,pq,niq->", M, res.cov, M) / len(g))
    assert band / BAND_FACTOR < true_rms < band * BAND_FACTOR


def test_loop_with_truth_model_is_at_the_floor_and_clean(mill):
    t = make_chain_truth(mill, 8, family="independent")
    ck = ChainChecks.from_columns(mill, t.check_measurements(400, noise_um=1.0, seed=9))
    s = closed_loop_chain(mill, t.elements, ck, cov=None, noise_um=1.0)
    assert s["effects"] == []
    assert s["held_out_over_floor"] < FLOOR_RATIO_TRUTH
    assert s["stages"]["baseline_ols_linear"]["held_out"]["rms_um"] > 0


# -- CLI -------------------------------------------------------------------------------------------
def _main(args):
    from compensation.app.cli import main
    return main(args)


def _one_line_exit2(capsys, args, *needles):
    assert _main(args) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if not ln.endswith(" ...")]  # progress lines
    assert len(err) == 1 and "Traceback" not in err[0], err
    for n in needles:
        assert n in err[0], err[0]
    return err[0]


def test_cli_refusals(tmp_path, capsys, mill):
    _one_line_exit2(capsys, ["simulate", "--machine", "mill-xyz", "--effect", "harmonic", "--out", str(tmp_path / "s")],
                    "--effect", "harmonic")
    # the grinder is a chain: its effects by the chain's names, an axis it has not refused naming the ones it has
    _one_line_exit2(capsys, ["simulate", "--effect", "periodic:Q", "--out", str(tmp_path / "g")], "periodic:Q",
                    "['X', 'Z']")
    # a sweep file with an axis the mill does not have
    t = make_chain_truth(mill, 0)
    cols = simulated_sweeps(t, noise_um=1.0, seed=0)
    cols["axis"] = np.where(cols["axis"] == "Z", "A", cols["axis"])
    write_sweeps(tmp_path / "bad.csv", cols)
    line = _one_line_exit2(capsys, ["identify", str(tmp_path / "bad.csv"), "--machine", "mill-xyz", "--out",
                                    str(tmp_path / "E.json")], "bad.csv", "column 'axis'")
    assert "row" in line
    # a grinder element set is no model of the mill
    g = load_machine(None)
    make_chain_truth(g, 0).elements.save(tmp_path / "grinder.json")
    ck = t.check_measurements(20, seed=1)
    from errormap.io import write_csv
    write_csv(tmp_path / "checks.csv", ck)
    _one_line_exit2(capsys, ["diagnose", str(tmp_path / "checks.csv"), "--machine", "mill-xyz", "--model",
                             str(tmp_path / "grinder.json"), "--out", str(tmp_path / "d")], "grinder.json")
    # checks without a column of the machine's axes
    del ck["y_mm"]
    write_csv(tmp_path / "checks2.csv", ck)
    t.elements.save(tmp_path / "mill.json")
    _one_line_exit2(capsys, ["diagnose", str(tmp_path / "checks2.csv"), "--machine", "mill-xyz", "--model",
                             str(tmp_path / "mill.json"), "--out", str(tmp_path / "d")], "checks2.csv", "y_mm")


@pytest.mark.slow
def test_cli_closed_loop_on_the_mill(tmp_path, capsys, mill):
    base = ["--machine", "mill-xyz", "--seed", "3", "--family", "independent", "--effect", "periodic:Y"]
    assert _main(["sweeps", *base, "--out", str(tmp_path / "sw.csv")]) == 0
    assert _main(["simulate", *base, "--checks", "600", "--out", str(tmp_path / "sim")]) == 0
    hdr = (tmp_path / "sim" / "checks.csv").read_text().splitlines()
    assert [h for h in hdr if not h.startswith("#")][0].startswith("x_mm,y_mm,z_mm,dx_um,dy_um,dz_um")
    sw = read_sweeps(tmp_path / "sw.csv", mill)
    assert sorted(sw.axes) == ["X", "Y", "Z"]
    assert _main(["identify", str(tmp_path / "sw.csv"), "--machine", "mill-xyz", "--out", str(tmp_path / "E.json")]) == 0
    assert (tmp_path / "E.cov.npz").is_file()
    # --no-learned: everything asserted is the loop's (the learned stage after it is most of the CPU)
    assert _main(["diagnose", str(tmp_path / "sim" / "checks.csv"), "--machine", "mill-xyz", "--model",
                  str(tmp_path / "E.json"), "--noise-um", "1", "--no-learned", "--out", str(tmp_path / "d")]) == 0
    s = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert ("periodic", "Y") in [(e["kind"], e["axis"]) for e in s["effects"]]
    found = next(e for e in s["effects"] if e["kind"] == "periodic")
    truth = json.loads((tmp_path / "sim" / "truth.json").read_text())["effects"]["periodic:Y"]
    assert found["shape"]["period_mm"] == pytest.approx(truth["period_mm"], rel=PERIOD_REL_TOL)
    st = s["stages"]
    # the loop beats the identification and the plain baseline on the held-out checks
    assert s["held_out_rms_um"] < st["identified"]["held_out"]["rms_um"]
    assert s["held_out_rms_um"] < st["baseline_ols_linear"]["held_out"]["rms_um"]
    assert s["noise_floor_um"] == pytest.approx(np.sqrt(3.0))


def test_cli_refuses_options_the_chain_path_does_not_use(tmp_path, capsys, mill):
    t = make_chain_truth(mill, 0)
    from errormap.io import write_csv
    write_csv(tmp_path / "checks.csv", t.check_measurements(20, seed=1))
    t.elements.save(tmp_path / "mill.json")
    _one_line_exit2(capsys, ["diagnose", str(tmp_path / "checks.csv"), "--machine", "mill-xyz", "--model",
                             str(tmp_path / "mill.json"), "--alpha", "0.05", "--out", str(tmp_path / "d")], "--alpha")


def test_chain_checks_refuse_radians_and_metres(tmp_path, five):
    from errormap.diagnosis.chain_loop import load_chain_checks
    from errormap.io import InputError, write_csv
    t = make_chain_truth(five, 0)
    ck = t.check_measurements(40, seed=1)
    assert len(load_chain_checks(write_csv(tmp_path / "ok.csv", ck), five)) == 40
    bad = dict(ck, c_deg=np.deg2rad(ck["c_deg"]))
    with pytest.raises(InputError, match=r"column 'c_deg'.*radians"):
        load_chain_checks(write_csv(tmp_path / "rad.csv", bad), five)
    bad = dict(ck, x_mm=ck["x_mm"] / 1000)
    with pytest.raises(InputError, match=r"column 'x_mm'.*metres"):
        load_chain_checks(write_csv(tmp_path / "m.csv", bad), five)


def test_chain_sweep_reader_shares_the_grinder_readers_row_checks(tmp_path, mill):
    """The chain sweep file is read by the grinder's column checks (one reader): a station number
    beyond the maximum and a command unit that does not fit the axis are refused naming row and column."""
    from errormap.io import InputError, write_csv
    from errormap.chain_sweeps import write_sweeps
    cols = simulated_sweeps(make_chain_truth(mill, 0), noise_um=1.0, seed=0)
    write_sweeps(tmp_path / "ok.csv", cols)
    assert sorted(read_sweeps(tmp_path / "ok.csv", mill).axes) == ["X", "Y", "Z"]
    bad = {k: np.array(v).copy() for k, v in cols.items()}
    bad["station"][0] = 10 ** 9
    write_csv(tmp_path / "station.csv", bad)
    with pytest.raises(InputError, match=r"station\.csv: row \d+, column 'station'"):
        read_sweeps(tmp_path / "station.csv", mill)
    unit = {**{k: np.array(v) for k, v in cols.items()}, "command_unit": np.full(len(cols["axis"]), "deg")}
    write_csv(tmp_path / "unit.csv", unit)
    with pytest.raises(InputError, match=r"unit\.csv: row \d+, column 'command_unit'.*expected 'mm'"):
        read_sweeps(tmp_path / "unit.csv", mill)


COV_REL_TOL = 1e-12
"""The same Gauss-Newton solution and Jacobian scaled by (σ_given / σ̂)²: equal to float rounding."""
COV_SCALE_TOL = 1e-13
"""...relative to the covariance's largest entry as well: the block normal equations give entries near zero with the
rounding of the large ones (measured 4.9e-14 absolute where the largest entry is 31)."""
FILE_DIGITS = 1e-9
"""An element set written to JSON and read back: its values to the file's digits (μm / μrad)."""


@pytest.mark.slow  # three Gauss-Newton identifications of the mill: over 5 CPU s
def test_identify_noise_um_scales_the_covariance_as_on_the_grinder(tmp_path, mill):
    """``identify --noise-um`` on a chain (as on the grinder): the known tracker σ scales the covariance; the
    elements are the same as without it."""
    import json
    t = make_chain_truth(mill, 0)
    write_sweeps(tmp_path / "sw.csv", simulated_sweeps(t, noise_um=1.0, seed=0))
    sw = read_sweeps(tmp_path / "sw.csv", mill)   # what the command reads
    est = ChainIdentification().fit(sw, mill).result_
    given = ChainIdentification(noise_um=2.5).fit(sw, mill).result_
    for s, v in est.elements_.functions.items():
        np.testing.assert_array_equal(given.elements_.functions[s], v)
    assert given.elements_.constants == est.elements_.constants
    np.testing.assert_allclose(given.cov, est.cov * (2.5 / est.sigma_um) ** 2, rtol=COV_REL_TOL,
                               atol=COV_SCALE_TOL * np.abs(est.cov).max() * (2.5 / est.sigma_um) ** 2)
    assert given.sigma_um == est.sigma_um and given.noise_um == 2.5 and est.noise_um is None
    assert _main(["identify", str(tmp_path / "sw.csv"), "--machine", "mill-xyz", "--noise-um", "2.5", "--raw",
                  "--gauge", "first-station", "--out", str(tmp_path / "E.json")]) == 0
    rep = json.loads((tmp_path / "E.report.json").read_text())
    assert rep["noise_um"] == 2.5 and rep["covariance_sigma_um"] == 2.5 and rep["smoothing"].startswith("none")
    written = ChainElementSet.load(tmp_path / "E.json", mill)   # --raw: the interpolating form
    for s, v in est.elements_.functions.items():
        np.testing.assert_allclose(written.functions[s], v, rtol=0, atol=FILE_DIGITS)
    with pytest.raises(ValueError, match="noise"):
        ChainIdentification(noise_um=0.0).fit(sw, mill)


@pytest.mark.slow  # two Gauss-Newton identifications of the mill: over 5 CPU s
def test_identify_plot_and_truth_on_a_chain(tmp_path, mill):
    """``identify --plot PREFIX --truth ELEMENTS`` on a chain (as on the grinder): one figure per swept axis, the
    truth overlaid in the identified gauge (the identification of its noise-free sweeps: the same tool points)."""
    from compensation.app.workflows.measurement import truth_in_gauge
    t = make_chain_truth(mill, 0)
    write_sweeps(tmp_path / "sw.csv", simulated_sweeps(t, noise_um=1.0, seed=0))
    truth_file = t.elements.save(tmp_path / "truth.json")
    assert _main(["identify", str(tmp_path / "sw.csv"), "--machine", "mill-xyz", "--out", str(tmp_path / "E.json"),
                  "--plot", str(tmp_path / "el"), "--truth", str(truth_file)]) == 0
    for w in swept_words(mill):
        assert (tmp_path / f"el_{w}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    g = volume_grid(mill, 300)
    gauged = truth_in_gauge(mill, ChainElementSet.load(truth_file, mill))
    np.testing.assert_allclose(ChainField(mill, gauged).predict(g), ChainField(mill, t.elements).predict(g),
                               rtol=0, atol=NOISE_FREE_UM)


SAME_FORMULA_UM = 1e-12
"""The chain's truth-only effect and the grinder simulator's are the same formula on the same element: equal to
float rounding."""


@pytest.mark.parametrize("grinder_name, chain_effect, element", [
    ("bump", "bump:X*Z", "dy_x"), ("xz_saddle", "xz_saddle:X*Z", "dy_z"), ("squareness", "squareness:X*Z", "s_xz"),
    ("squareness_xz", "squareness_xz:X*Z", "s_xz"), ("a_tilt", "a_tilt:A*X", "ey_a"), ("a_lobe_x", "a_lobe_x:A*X", "dy_a")])
def test_truth_only_effects_on_a_chain_are_the_grinders(grinder_name, chain_effect, element):
    """``simulate --effect bump:V*W`` / ``xz_saddle:V*W`` on a chain: on the grinder's own chain file the added
    element values equal the grinder simulator's ``bump`` / ``xz_saddle``, on that element and no other."""
    g, gc = load_machine(None), load_machine("grinder-chain")
    axes = np.random.default_rng(5).uniform(g.stroke_lo, g.stroke_hi, (400, 3))
    el = make_chain_truth(g, 0).elements
    d_g = ChainTruth(g, el, {grinder_name: {}}).element_values(axes) - ChainTruth(g, el, {}).element_values(axes)
    cel = ChainElementSet.zeros(gc)
    d_c = ChainTruth(gc, cel, {chain_effect: {}}).element_values(axes) - ChainTruth(gc, cel, {}).element_values(axes)
    from errormap.elements import ELEMENT_NAMES
    k = list(gc.slot_names).index(element)
    assert np.abs(d_c[:, k]).max() > 1.0                         # the effect is there (μm or μrad)
    np.testing.assert_allclose(d_c[:, k], d_g[:, ELEMENT_NAMES.index(element)], rtol=0, atol=SAME_FORMULA_UM)
    assert np.count_nonzero(np.abs(d_c).max(axis=0)) == 1        # on that element only


def test_truth_only_effects_through_the_cli(tmp_path):
    """A mill's checks and sweeps with ``bump:X*Y`` (the straightness of X in Z): simulated, recorded in truth.json."""
    assert _main(["simulate", "--machine", "mill-xyz", "--seed", "0", "--checks", "20", "--effect", "bump:X*Y",
                  "--out", str(tmp_path / "sim")]) == 0
    doc = json.loads((tmp_path / "sim" / "truth.json").read_text())
    assert doc["effects"] == {"bump:X*Y": {"amplitude_um": 8.0, "p_frac": 0.6, "q_frac": 0.4, "width_frac": 0.18}}
    assert _main(["sweeps", "--machine", "mill-xyz", "--seed", "0", "--effect", "xz_saddle:X*Z",
                  "--out", str(tmp_path / "sw.csv")]) == 0
    assert _main(["simulate", "--machine", "mill-xyz", "--seed", "0", "--checks", "20", "--effect", "squareness_xz:Y*Z",
                  "--out", str(tmp_path / "sq")]) == 0
    assert _main(["simulate", "--machine", "mill-xyz", "--effect", "bump:X", "--out", str(tmp_path / "bad")]) == 2


@pytest.mark.parametrize("effect, element", [("a_tilt:C*Z", "ex_c"), ("a_lobe_x:C*Y", "dx_c"), ("a_tilt", "ey_a")])
def test_rotary_by_linear_effects_on_any_rotary_axis(five, effect, element):
    """``a_tilt`` / ``a_lobe_x`` on any rotary axis W and linear axis V (``KIND:W*V``; without axes the first of
    each): the tilt or radial motion of W towards the first direction across it, on that element only; a linear
    axis first is refused naming the order."""
    el = ChainElementSet.zeros(five)
    axes = five.stroke_lo + (five.stroke_hi - five.stroke_lo) * np.random.default_rng(3).random((200, 5))
    d = np.abs(ChainTruth(five, el, {effect: {}}).element_values(axes)).max(axis=0)
    assert [five.slot_names[i] for i in np.flatnonzero(d)] == [element] and d.max() > 1.0
    with pytest.raises(ValueError, match="rotary axis of"):
        ChainTruth(five, el, {"a_tilt:X*C": {}})


def test_truth_recipe_of_a_machine_file_is_checked(mill):
    """A machine file's ``[truth]`` table (chain_truth.recipe): a wrong order, slot or grid is one line naming the key."""
    import dataclasses
    from errormap.machine_checks import MachineFileError
    for table, key in (({"default": {"order": "sideways"}}, "truth.default.order"),
                       ({"independent": {"scale": {"dq_q": [1.0, 2.0]}}}, "truth.independent.scale.dq_q"),
                       ({"grid": [3, 3]}, "truth.grid")):
        with pytest.raises(MachineFileError, match=key.replace(".", r"\.")):
            make_chain_truth(dataclasses.replace(mill, truth=table), 0, family="independent" if "independent" in table
                          else "default")
