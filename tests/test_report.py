"""Method comparison, true residual and the HTML report (compensation.app.workflows.compare,
compensation.app.reports.methods, compensation.evaluate)."""
import base64
import json
import re

import numpy as np
import pytest

import compensation.app.workflows.compare as compare_mod
from compensation.app.cli import main
from compensation.evaluate import load_truth, residual_metrics, true_residual_um
from compensation.app.reports.methods import write_report
from compensation.app.workflows.compare import compare_methods, subset_index
from compensation.solvers import solve
from compensation.toolpath import flute_path
from errormap.io import InputError
from errormap.chain_field import ChainField
from errormap.chain_kernel import NominalChain
from errormap.chain_truth import make_chain_truth

TOL_UM = 1e-6
MIN_TURN_CORRELATION = 0.95  # between the traditional residual's profiles on successive turns
METRIC_KEYS = {"model_max_um", "model_mean_sq_um2", "true_max_um", "seconds", "points"}


@pytest.fixture(scope="module")
def truth(grinder):
    return make_chain_truth(grinder, 11)


def HTMField(machine, elements):
    """The error field of ``elements`` on ``machine``'s chain (every machine tool's field)."""
    return ChainField(machine, elements)


@pytest.fixture(scope="module")
def flute():
    return flute_path(turns=3, points_per_turn=60)


def test_true_residual_of_nominal_commands_is_the_truth_error(grinder, truth, flute):
    ax = flute.axes(grinder)
    r = true_residual_um(truth, ax, NominalChain(grinder).forward(ax))
    assert np.abs(r - truth.spatial_error(ax, **truth.default_conditions(len(ax)))).max() < TOL_UM
    s = residual_metrics(r, "true")
    assert s["true_max_sq_um2"] == pytest.approx(s["true_max_um"] ** 2)


def test_traditional_residual_repeats_once_per_turn(grinder, truth, flute):
    """The paper's Fig. 18: the traditional model residual has the same profile on every turn."""
    field = HTMField(grinder, truth.elements)
    cmp = compare_methods(field, flute.targets_mm, grinder, methods=("traditional", "exact"), truth=truth,
                          nominal_axes=flute.axes(grinder))
    r = np.linalg.norm(cmp.runs["traditional"].result.residual_um, axis=1).reshape(3, 60)
    assert np.ptp(r[0]) > 1.0                                   # it varies within a turn ...
    for k in (1, 2):                                            # ... and repeats turn after turn
        assert np.corrcoef(r[0], r[k])[0, 1] > MIN_TURN_CORRELATION
    assert np.corrcoef(r[0], np.roll(r[0], 30))[0, 1] < MIN_TURN_CORRELATION  # not just flat
    m = cmp.metrics()["methods"]
    assert METRIC_KEYS <= set(m["traditional"]) and METRIC_KEYS <= set(m["exact"])
    # model == truth here, so the exact solver's true residual is ~0 and far below traditional's
    assert m["exact"]["true_max_um"] < 1e-3 < m["traditional"]["true_max_um"]
    assert cmp.baseline["true_max_um"] > m["traditional"]["true_max_um"]


def test_per_point_ga_runs_on_a_subset_and_says_so(grinder, truth, flute, monkeypatch):
    calls = []

    def stand_in(method, field, targets, machine, options):
        calls.append((method, len(targets)))
        opts = {k: v for k, v in options.items() if k == "target_axes"}
        return solve("traditional", field, targets, machine, **opts)

    monkeypatch.setattr(compare_mod, "_solve", stand_in)
    field = HTMField(grinder, truth.elements)
    cmp = compare_methods(field, flute.targets_mm, grinder, methods=("ga", "batched-ga"), truth=truth, ga_points=25)
    run = cmp.runs["ga"]
    assert len(run.index) == 25 and run.index[0] == 0 and run.index[-1] == len(flute) - 1
    assert run.metrics["points"] == 25 and run.metrics["subset"] and "25 of 180" in run.metrics["note"]
    assert not cmp.runs["batched-ga"].metrics["subset"] and cmp.runs["batched-ga"].metrics["points"] == 180
    # budget-driven subset: the probe plus a subset that fits
    calls.clear()
    cmp = compare_methods(field, flute.targets_mm, grinder, methods=("ga",), ga_budget_s=0.0)
    assert calls[0] == ("ga", compare_mod.GA_PROBE_POINTS) and calls[1][1] < len(flute)
    assert subset_index(10, 20).tolist() == list(range(10))


def test_a_method_run_on_a_subset_gets_its_own_residual_file_without_nan_padding(grinder, truth, flute, monkeypatch,
                                                                                 tmp_path):
    """residuals.csv holds the methods that ran on every point; the per-point GA on 25 of 180 points is written
    to residuals_ga.csv with those 25 rows only (it used to pad 155 rows of residuals.csv with NaN)."""
    from errormap.io import read_table

    def stand_in(method, field, targets, machine, options):
        return solve("traditional", field, targets, machine,
                     **{k: v for k, v in options.items() if k == "target_axes"})
    monkeypatch.setattr(compare_mod, "_solve", stand_in)
    cmp = compare_methods(HTMField(grinder, truth.elements), flute.targets_mm, grinder, methods=("ga", "exact"),
                          truth=truth, ga_points=25)
    paths = write_report(cmp, tmp_path / "rep")
    full, sub = read_table(paths["residuals"]), read_table(paths["residuals_ga"])
    assert len(full) == len(flute) and not any(c.startswith("ga_") for c in full.names)
    assert "exact_true_um" in full.names and "residuals_ga.csv" in " ".join(full.comments)
    assert sub.names == ["point", "x_mm", "z_mm", "a_deg", "ga_model_um", "ga_true_um"] and len(sub) == 25
    np.testing.assert_array_equal(sub.float("point"), cmp.runs["ga"].index)
    assert "ran on 25 of the 180 points" in " ".join(sub.comments)
    for t in (full, sub):
        assert all(np.isfinite(t.float(c)).all() for c in t.names)


def test_report_html_is_self_contained_and_names_its_residuals(tmp_path, grinder, truth, flute):
    field = HTMField(grinder, truth.elements)
    cmp = compare_methods(field, flute.targets_mm, grinder, methods=("traditional", "exact"), truth=truth)
    paths = write_report(cmp, tmp_path / "rep", context={"model": "test"})
    text = paths["html"].read_text()
    assert "MODEL" in text and "TRUE" in text and "Model residual" in text and "True residual" in text
    assert not re.search(r"""(src|href)=["'](?!data:|#)""", text)  # nothing external (in-page anchors are fine)
    pngs = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", text)
    assert len(pngs) >= 5 and all(base64.b64decode(p)[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    metrics = json.loads(paths["metrics"].read_text())
    assert set(metrics["methods"]) == {"traditional", "exact"} and "model" in metrics["residuals"]
    assert metrics["methods"]["exact"]["points"] == len(flute)


def test_report_cli_with_simulate_folder(tmp_path, capsys):
    sim = tmp_path / "sim"
    assert main(["simulate", "--seed", "2", "--out", str(sim), "--checks", "20", "--effect", "pitch"]) == 0
    out = tmp_path / "rep"
    rc = main(["report", "--model", str(sim / "truth_elements.json"), "--flute", "--turns", "1",
               "--points-per-turn", "40", "--truth", str(sim), "--methods", "traditional,exact", "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "report.html" in printed and "metrics.json" in printed
    m = json.loads((out / "metrics.json").read_text())
    assert m["truth"] == str(sim) and m["points"] == 40
    # the truth has an undeclared effect (pitch) the model lacks: the true residual stays above the model's
    assert m["methods"]["exact"]["true_max_um"] > m["methods"]["exact"]["model_max_um"]


def test_load_truth_from_folder_and_file(tmp_path, grinder):
    sim = tmp_path / "sim"
    assert main(["simulate", "--seed", "5", "--out", str(sim), "--checks", "10", "--effect", "worm"]) == 0
    t = load_truth(sim, grinder)
    assert set(t.effects) == {"harmonic:A"} and t.seed == 5   # the simulator's worm: the chain's harmonic on A
    assert load_truth(sim / "truth_elements.json", grinder).effects == {}
    with pytest.raises(InputError, match="no such"):
        load_truth(tmp_path / "nothing", grinder)


def test_report_cli_bad_methods(tmp_path, capsys):
    rc = main(["report", "--model", "x.json", "--flute", "--methods", "traditional,magic", "--out", str(tmp_path)])
    assert rc == 2 and "magic" in capsys.readouterr().err


EXACT_MODEL_TOL_UM = 1e-6   # the exact solver's own residual (it iterates to ~1e-9 um)


def test_report_runs_on_a_machine_tool_chain(tmp_path, capsys):
    """The comparison on mill-xyz through the same solvers: a CSV of its axis columns, the truth of simulate
    --machine with an effect the model lacks (periodic on X), so exact's TRUE residual is the effect and the
    plain baseline (uncompensated) is far above it."""
    from errormap.machine import load_machine
    sim, out = tmp_path / "sim", tmp_path / "rep"
    assert main(["simulate", "--machine", "mill-xyz", "--seed", "2", "--checks", "20", "--effect", "periodic",
                 "--out", str(sim)]) == 0
    m = load_machine("mill-xyz")
    u = np.linspace(0.2, 0.8, 30)[:, None]
    path = tmp_path / "p.csv"
    path.write_text(",".join(m.axis_columns) + "\n" + "\n".join(
        ",".join(f"{v:.6f}" for v in row) for row in m.stroke_lo + (m.stroke_hi - m.stroke_lo) * u) + "\n")
    assert main(["report", "--machine", "mill-xyz", "--model", str(sim / "truth_elements.json"), "--path", str(path),
                 "--truth", str(sim), "--methods", "traditional,exact", "--out", str(out)]) == 0
    capsys.readouterr()
    met = json.loads((out / "metrics.json").read_text())
    exact = met["methods"]["exact"]
    assert exact["points"] == 30 and exact["model_max_um"] < EXACT_MODEL_TOL_UM < exact["true_max_um"]
    assert exact["true_max_um"] < met["uncompensated"]["true_max_um"]
    assert open(out / "residuals.csv").read().count("x_mm,y_mm,z_mm") == 1


def test_a_truth_effect_the_chain_does_not_carry_is_refused_naming_file_and_key(tmp_path, grinder):
    """A truth.json without a format key (a grinder file's simulate folder) is read on the grinder's chain, its
    effects as the chain's kinds (worm = harmonic on A, the stroke fractions renamed); an effect the chain's truth
    cannot carry (``drift``: not simulated) is refused naming the file and the key, never dropped."""
    t = make_chain_truth(grinder, 4)
    t.elements.save(tmp_path / "truth_elements.json")
    (tmp_path / "truth.json").write_text(json.dumps(
        {"seed": 4, "effects": {"worm": {"amplitude_urad": 90.0, "teeth": 40, "phase_rad": 1.1},
                                "bump": {"amplitude_um": 8.0, "x_frac": 0.6, "z_frac": 0.4, "width_frac": 0.18}}}))
    got = load_truth(tmp_path, grinder)
    assert got.effects["harmonic:A"]["amplitude_urad"] == 90.0 and got.effects["bump:X*Z"]["q_frac"] == 0.4
    (tmp_path / "truth.json").write_text(json.dumps({"seed": 4, "effects": {"a_tilt": {"k_urad": 120.0}}}))
    assert load_truth(tmp_path, grinder).effects["a_tilt:A*X"]["k_urad"] == 120.0   # a rotary axis' tilt, generic
    (tmp_path / "truth.json").write_text(json.dumps({"seed": 4, "effects": {"drift": {"k_um_per_mm_h": 1.0}}}))
    with pytest.raises(InputError, match=r"truth.json: key 'effects', 'drift'"):
        load_truth(tmp_path, grinder)
