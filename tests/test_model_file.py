"""One model file (``model.json``, ``volcomp-model/1``) and one reader (:func:`compensation.model_file.read_model`):
predict, compensate, export and report read the same model.json the same way; every older model format volcomp
wrote still loads through that reader; a foreign or garbled model.json is refused in one line naming the file
and the key."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.model_file import Model, read_model
from errormap.chain_truth import make_chain_truth
from errormap.diagnosis.chain_loop import EffectTerm
from errormap.diagnosis.loop_model import save_chain_model
from errormap.io import InputError, read_table, write_csv
from errormap.machine import load_machine

SAME_UM = 0.0
"""Two readers of one file that build the same field run the same float64 operations: equal to the bit."""
CSV_REL = 1e-8
"""``predict`` writes ``%.9g``: nine significant digits, a relative rounding of at most 5e-9 of each value."""


def _points(mt, n=40, seed=5):
    rng = np.random.default_rng(seed)
    return rng.uniform(mt.stroke_lo, mt.stroke_hi, (n, len(mt.axes)))


def _model_json(tmp_path, mt, seed=4, fmt=None):
    """A model.json of ``mt``: a seeded element set beside it and one periodic term (no conditions needed)."""
    el = make_chain_truth(mt, seed, family="independent").elements.save(tmp_path / "updated_elements.json")
    word = mt.axes[0].word
    own = next(s for s in mt.slot_names if s == f"d{word.lower()}_{word.lower()}")
    term = EffectTerm("periodic", (word,), own, {"period_mm": 7.3}, np.array([3.0, -2.0]))
    p = save_chain_model(tmp_path / "model.json", mt, el, [term], "updated_plus_effects",
                         provenance={"written_by": "tests/test_model_file.py"})
    if fmt is not None:   # an older file: its format key, without the keys it did not have
        d = json.loads(p.read_text())
        for k in ("covariance", "network", "provenance"):
            d.pop(k)
        p.write_text(json.dumps(dict(d, format=fmt)))
    return p


def test_every_command_reads_the_model_json_the_same_way(tmp_path):
    """On mill-xyz: the public loader, predict (CLI), compensate's and export's loaders give the same field."""
    from compensation import load_model
    from compensation.app.workflows.compensate import CompensateSettings, load_model_field
    from compensation.export.sources import load_model as export_model
    mt = load_machine("mill-xyz")
    p = _model_json(tmp_path, mt)
    model = read_model(p, mt)
    assert model.format == "volcomp-model/1" and model.holds() == ["elements", "effect terms"]
    assert model.provenance == {"written_by": "tests/test_model_file.py"} and model.stage == "updated_plus_effects"
    axes = _points(mt)
    ref = model.field.predict(axes)
    np.testing.assert_allclose(load_model(p, mt).predict(axes), ref, rtol=0, atol=SAME_UM)
    _, _, fld = load_model_field(mt, CompensateSettings(method="exact", model=str(p), out_dir=tmp_path / "c"))
    np.testing.assert_allclose(fld.predict(axes), ref, rtol=0, atol=SAME_UM)
    table_model, _, read = export_model(str(p), "grid", mt)
    np.testing.assert_allclose(table_model.field.predict(axes), ref, rtol=0, atol=SAME_UM)
    assert isinstance(read, Model) and [t.to_dict() for t in read.terms] == [t.to_dict() for t in model.terms]
    pts = write_csv(tmp_path / "pts.csv", {c: axes[:, j] for j, c in enumerate(mt.axis_columns)}, float_fmt="%.17g")
    assert main(["predict", "--machine", "mill-xyz", "--model", str(p), str(pts), "--out", str(tmp_path / "o.csv")]) == 0
    t = read_table(tmp_path / "o.csv")
    got = np.stack([t.float(c) for c in ("dx_um", "dy_um", "dz_um")], axis=1)
    np.testing.assert_allclose(got, ref, rtol=CSV_REL, atol=0)
    assert t.meta()["model_holds"] == "elements, effect terms"


def test_report_reads_the_model_json_as_predict_does(tmp_path, monkeypatch, capsys):
    """The method comparison (the grinder file's) evaluates the field the one reader builds from model.json."""
    import compensation.app.commands.report as report
    from compensation.app.validate import UsageError
    g = load_machine(None)
    mt = g
    p = _model_json(tmp_path, mt)
    seen = {}

    def capture(field, *a, **kw):
        seen["field"] = field
        raise UsageError("captured")
    monkeypatch.setattr(report, "compare_methods", capture)
    assert main(["report", "--model", str(p), "--flute", "--methods", "exact", "--out", str(tmp_path / "r")]) == 2
    assert "captured" in capsys.readouterr().err
    axes = _points(mt)
    np.testing.assert_allclose(seen["field"].predict(axes), read_model(p, g).field.predict(axes), rtol=0, atol=SAME_UM)


def test_the_chain_loops_older_model_json_loads_as_the_new_one(tmp_path):
    mt = load_machine("five-axis-ac")
    new = read_model(_model_json(tmp_path / "new", mt), mt)
    old = read_model(_model_json(tmp_path / "old", mt, fmt="volcomp-chain-model/1"), mt)
    assert old.format == "volcomp-chain-model/1" and old.holds() == new.holds()
    axes = _points(mt)
    np.testing.assert_allclose(old.field.predict(axes), new.field.predict(axes), rtol=0, atol=SAME_UM)


def test_a_model_made_on_the_built_in_grinders_earlier_file_loads_and_another_machines_is_refused(tmp_path):
    """A model.json recorded with the built-in grinder's earlier file (``kind = "grinder"``, before it became its
    chain file: :data:`errormap.machine.FORMER_SHA256`) is the built-in grinder's model: it loads, predicting as the
    same model recorded with today's file; a sha256 of any other file is still refused naming the key."""
    from errormap.machine import FORMER_SHA256
    mt = load_machine("grinder")
    today = read_model(_model_json(tmp_path / "today", mt), mt)
    p = _model_json(tmp_path / "earlier", mt, fmt="volcomp-chain-model/1")
    p.write_text(json.dumps({**json.loads(p.read_text()), "machine_sha256": FORMER_SHA256["grinder"][0]}))
    earlier = read_model(p, mt)
    axes = _points(mt)
    np.testing.assert_allclose(earlier.field.predict(axes), today.field.predict(axes), rtol=0, atol=SAME_UM)
    p.write_text(json.dumps({**json.loads(p.read_text()), "machine_sha256": "0" * 64}))
    with pytest.raises(InputError, match="key 'machine_sha256'"):
        read_model(p, mt)


def test_an_element_set_loads_as_a_model_of_elements(tmp_path):
    from errormap.chain_field import ChainField
    mt = load_machine("mill-xyz")
    el = make_chain_truth(mt, 2, family="independent").elements
    p = el.save(tmp_path / "E.json")
    m = read_model(p, mt)
    assert m.format == "volcomp-elements/1" and m.elements_only and m.covariance_path is None
    axes = _points(mt)
    np.testing.assert_allclose(m.field.predict(axes), ChainField(mt, el).predict(axes), rtol=0, atol=SAME_UM)


def test_the_grinders_old_closed_loop_model_loads(tmp_path):
    """``volcomp-diagnosed-model/1`` (the grinder's closed loop before the chain loop): its elements, the grinder's
    effect terms with the conditions they need, per point."""
    from errormap.chain_field import ChainField
    from errormap.chain_truth import make_chain_truth
    g = load_machine(None)
    el = make_chain_truth(g, 3).elements
    el.save(tmp_path / "updated_elements.json")
    term = {"kind": "thermal", "axis": "x", "element": "dx_x", "coefficients": [0.01],
            "reference": {"ref_temp_c": 20.0, "ref_time_s": 0.0}}
    (tmp_path / "model.json").write_text(json.dumps({"format": "volcomp-diagnosed-model/1", "stage": "updated_plus_effects",
                                                     "elements": "updated_elements.json", "terms": [term]}))
    m = read_model(tmp_path / "model.json", g)
    assert m.per_point and m.needs == ("temp_c",) and m.holds() == ["elements", "effect terms"]
    axes = np.column_stack([np.linspace(10, 150, 9), np.linspace(5, 50, 9), np.linspace(0, 300, 9)])
    at20 = m.field.corrected.predict(axes, temp_c=np.full(9, 20.0))   # the reference temperature: the elements alone
    np.testing.assert_allclose(at20, ChainField(g, el).predict(axes), rtol=0, atol=SAME_UM)
    with pytest.raises(InputError, match="grinder file's closed-loop model"):
        read_model(tmp_path / "model.json", load_machine("mill-xyz"))


def _chain_network(mt, folder):
    import torch
    from training.model import MLPField
    f = MLPField.for_machine(mt, hidden=(6, 5), activation="tanh")
    rng = np.random.default_rng(3)
    f.fit_scalers(_points(mt, 100, 3), rng.normal(0.0, 20.0, (100, 3)))
    f.theta_ = torch.randn(f.n_params, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    return f, f.save(folder)


def test_trained_networks_load_and_a_model_json_names_one(tmp_path):
    """A chain network folder (``volcomp-chain-mlpfield/1``), the grinder's (``volcomp-mlpfield/1``) and a
    model.json whose ``network`` names the folder: the same field as the network itself."""
    from training.model import MLPField
    mt = load_machine("mill-xyz")
    f, net = _chain_network(mt, tmp_path / "net")
    axes = _points(mt)
    m = read_model(net, mt)
    assert m.holds() == ["network"] and m.network == str(net)
    np.testing.assert_allclose(m.field.predict(axes), f.predict(axes), rtol=0, atol=SAME_UM)
    p = save_chain_model(tmp_path / "model.json", mt, None, network={"folder": net}, kept_stage="network")
    assert json.loads(p.read_text())["network"] == {"folder": "net"}
    via = read_model(p, mt)
    assert via.holds() == ["network"] and via.format == "volcomp-model/1"
    np.testing.assert_allclose(via.field.predict(axes), f.predict(axes), rtol=0, atol=SAME_UM)
    g = load_machine(None)
    rng = np.random.default_rng(0)
    gx = np.column_stack([rng.uniform(0, 200, 50), rng.uniform(0, 60, 50), rng.uniform(0, 360, 50)])
    grinder_net = MLPField((6, 6), "sigmoid", "raw").fit_scalers(gx, rng.normal(0.0, 20.0, (50, 3)))
    grinder_net.theta_ = grinder_net.init_params(0)
    folder = grinder_net.save(tmp_path / "gnet")
    np.testing.assert_allclose(read_model(folder, g).field.predict(gx), grinder_net.predict(gx), rtol=0, atol=SAME_UM)


GARBLED = {
    "format": ({"format": "volcomp-model/9"}, "'format'"),
    "machine_sha256": ({"machine_sha256": "ab" * 32}, "'machine_sha256'"),
    "elements": ({"elements": 5}, "'elements'"),
    "terms": ({"terms": "periodic"}, "'terms'"),
    "terms[0]": ({"terms": [{"kind": "worm-gear", "axis": "X", "element": "dx_x", "coefficients": [1.0]}]},
                 r"'terms\[0\]'"),
    "covariance": ({"covariance": "missing.cov.npz"}, "'covariance'"),
    "network": ({"elements": None, "network": {"url": "http://x"}}, "'network'"),
    "learned_residual": ({"learned_residual": {"format": "volcomp-learned-residual/1"}}, "'learned_residual'"),
}


@pytest.mark.parametrize("key", list(GARBLED))
def test_a_foreign_or_garbled_model_json_is_refused_naming_file_and_key(tmp_path, capsys, key):
    mt = load_machine("mill-xyz")
    p = _model_json(tmp_path, mt)
    change, match = GARBLED[key]
    p.write_text(json.dumps({**json.loads(p.read_text()), **change}))
    pts = write_csv(tmp_path / "pts.csv", {c: v for c, v in zip(mt.axis_columns, _points(mt, 3).T)})
    assert main(["predict", "--machine", "mill-xyz", "--model", str(p), str(pts), "--out", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(p) in err[0] and len(err[0]) <= 300, err   # the CLI's one line
    assert pytest.importorskip("re").search(f"key {match}", err[0]), err[0]
    assert not (tmp_path / "o.csv").exists()


def test_a_model_json_that_is_not_json_is_refused_naming_the_file(tmp_path):
    p = tmp_path / "model.json"
    p.write_text("{format: volcomp-model/1")
    with pytest.raises(InputError, match=f"{p}: not a model file"):
        read_model(p, load_machine("mill-xyz"))


def test_identify_writes_a_model_file_naming_its_elements_and_covariance(tmp_path, capsys):
    from errormap.chain_sweeps import simulated_sweeps
    from errormap.sweeps import write_sweeps
    m = load_machine("mill-xyz")
    write_sweeps(tmp_path / "sw.csv", simulated_sweeps(make_chain_truth(m, 0), noise_um=1.0, seed=1))
    assert main(["identify", str(tmp_path / "sw.csv"), "--machine", "mill-xyz", "--out", str(tmp_path / "E.json")]) == 0
    assert f"wrote model: {tmp_path / 'E.model.json'}" in capsys.readouterr().out
    named, bare = read_model(tmp_path / "E.model.json", m), read_model(tmp_path / "E.json", m)
    assert named.holds() == bare.holds() == ["elements", "covariance"]
    assert named.covariance_path == bare.covariance_path == tmp_path / "E.cov.npz"
    assert named.provenance == {"written_by": "volcomp identify", "sweeps": [str(tmp_path / "sw.csv")]}
    axes = _points(m)
    np.testing.assert_allclose(named.field.predict(axes), bare.field.predict(axes), rtol=0, atol=SAME_UM)


def test_diagnose_starts_from_a_model_file_of_elements_and_refuses_one_with_terms(tmp_path, capsys):
    """The closed loop reads --model through the one reader too: a model.json holding effect terms is not a start."""
    m = load_machine("mill-xyz")
    p = _model_json(tmp_path, m)
    checks = write_csv(tmp_path / "checks.csv", {c: v for c, v in zip(m.axis_columns, _points(m, 3).T)})
    assert main(["diagnose", str(checks), "--machine", "mill-xyz", "--model", str(p), "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(p) in err[0] and "holds elements, effect terms" in err[0], err


def test_export_refuses_the_grinders_old_closed_loop_model_naming_its_element_set(tmp_path):
    from compensation.export.sources import load_model as export_model
    from errormap.chain_truth import make_chain_truth
    g = load_machine(None)
    make_chain_truth(g, 3).elements.save(tmp_path / "updated_elements.json")
    term = {"kind": "thermal", "axis": "x", "element": "dx_x", "coefficients": [0.01],
            "reference": {"ref_temp_c": 20.0, "ref_time_s": 0.0}}
    (tmp_path / "model.json").write_text(json.dumps({"format": "volcomp-diagnosed-model/1", "stage": "updated",
                                                     "elements": "updated_elements.json", "terms": [term]}))
    with pytest.raises(InputError, match=r"model.json: its effect terms take their conditions per point.*updated_elements"):
        export_model(str(tmp_path / "model.json"), "grid", g)
