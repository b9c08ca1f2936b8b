"""The fleet file (docs/reference/file-formats.md, "Fleet file"): the documented example reads, and what the
reader cannot interpret is refused naming the file and the key."""
import re
from pathlib import Path

import pytest

from compensation.app.workflows.fleet import read_fleet
from errormap.io import InputError

ROOT = Path(__file__).resolve().parents[1]


def _doc_example() -> str:
    text = (ROOT / "docs" / "reference" / "file-formats.md").read_text(encoding="utf-8")
    section = text.split("## Fleet file (TOML)", 1)[1]
    return re.search(r"```text\n(.*?)```", section, flags=re.S).group(1)


def _touch(d, *names):
    for n in names:
        (d / n).parent.mkdir(parents=True, exist_ok=True)
        (d / n).write_text("x\n")


def test_the_documented_example_reads(tmp_path):
    _touch(tmp_path, "g07/sweeps.csv", "g07/checks.csv", "machines/g12.toml", "g12/x.csv", "g12/za.csv",
           "g12/checks.csv")
    (tmp_path / "fleet.toml").write_text(_doc_example(), encoding="utf-8")
    m = read_fleet(tmp_path / "fleet.toml")
    assert [e["name"] for e in m] == ["grinder-07", "grinder-12"]
    assert m[0]["machine"] is None and m[0]["noise_um"] is None
    assert m[1]["sweeps"] == [(tmp_path / "g12/x.csv").resolve(), (tmp_path / "g12/za.csv").resolve()]
    assert m[1]["noise_um"] == 2.0


@pytest.mark.parametrize("body, key", [
    ('name = "a"\nsweeps = "s.csv"\nchecks = "c.csv"\nspeed = 3\n', "machine[0].speed"),
    ('name = "a"\nsweeps = "s.csv"\nchecks = "missing.csv"\n', "machine[0].checks"),
    ('name = "../a"\nsweeps = "s.csv"\nchecks = "c.csv"\n', "machine[0].name"),
    ('name = "a"\nsweeps = []\nchecks = "c.csv"\n', "machine[0].sweeps"),
    ('name = "a"\nsweeps = "s.csv"\nchecks = "c.csv"\nnoise_um = -1\n', "machine[0].noise_um"),
])
def test_refusals_name_the_key(tmp_path, body, key):
    _touch(tmp_path, "s.csv", "c.csv")
    (tmp_path / "f.toml").write_text(f'format = "volcomp-fleet/1"\n[[machine]]\n{body}')
    with pytest.raises(InputError, match=re.escape(f"f.toml: key '{key}'")):
        read_fleet(tmp_path / "f.toml")


def test_repeated_names_and_a_wrong_format_are_refused(tmp_path):
    _touch(tmp_path, "s.csv", "c.csv")
    one = 'name = "a"\nsweeps = "s.csv"\nchecks = "c.csv"\n'
    (tmp_path / "f.toml").write_text(f'format = "volcomp-fleet/1"\n[[machine]]\n{one}[[machine]]\n{one}')
    with pytest.raises(InputError, match="machine\\[1\\].name': 'a' appears twice"):
        read_fleet(tmp_path / "f.toml")
    (tmp_path / "f.toml").write_text(f'[[machine]]\n{one}')
    with pytest.raises(InputError, match="key 'format'"):
        read_fleet(tmp_path / "f.toml")


@pytest.mark.slow
def test_a_fleet_runs_in_process_without_ray(tmp_path, grinder, capsys):
    """Without --cluster the machines run one after another here (no Ray needed); a file store is
    fine for one writer at a time. ``--no-learned``: the diagnosis's learned-residual stage (GP fits, 3.8 of this
    fleet's 7.6 CPU s warm, measured 2026-12-04), whose figures this test does not read; the fleet's default, the
    stage run, is the mill test's below (it asserts the stage reached the diagnosis)."""
    import json

    from mlflow.tracking import MlflowClient

    from compensation.app.cli import main
    from errormap.io import write_csv
    from errormap.chain_truth import ChainTruth, make_chain_truth
    from errormap.chain_sweeps import simulated_sweeps
    from errormap.sweeps import write_sweeps
    truth = make_chain_truth(grinder, 3)
    write_sweeps(tmp_path / "sweeps.csv", simulated_sweeps(ChainTruth(grinder, truth.elements, {}), seed=3))
    write_csv(tmp_path / "checks.csv", truth.check_measurements(n=150, seed=13),
              header_comments=["format: volcomp-checks/1"])
    (tmp_path / "fleet.toml").write_text('format = "volcomp-fleet/1"\n[[machine]]\nname = "only"\n'
                                         'sweeps = "sweeps.csv"\nchecks = "checks.csv"\n')
    uri = f"sqlite:///{tmp_path / 'ml.db'}"
    rc = main(["fleet", str(tmp_path / "fleet.toml"), "--out", str(tmp_path / "out"), "--tracking-uri", uri,
               "--train-iter", "2", "--bootstrap", "3", "--grid", "5", "--hidden", "5", "--no-learned"])
    assert rc == 0, capsys.readouterr().err
    m = json.loads((tmp_path / "out" / "fleet_summary.json").read_text())["machines"][0]
    assert m["status"] == "ok" and m["train_iterations"] <= 2
    diag = json.loads((tmp_path / "out" / "only" / "diagnosis" / "diagnosis.json").read_text())
    run = MlflowClient(tracking_uri=uri).get_run(m["run_id"])
    assert run.data.metrics["diagnose_heldout_rms_updated_um"] == diag["stages"]["updated"]["held_out"]["rms_um"]
    assert "learned_residual" not in diag   # --no-learned reached the diagnosis
    assert (tmp_path / "out" / "only" / "machine_summary.json").is_file()


def _machine(name, verdict):
    from compensation.app.workflows.fleet import machine_status
    return {"name": name, "status": machine_status(verdict), "verdict": verdict, "run_id": "r",
            "train": {"train_max_um": 1.0},
            "diagnosis": {"diagnose_heldout_rms_identified_um": 9.0, "diagnose_heldout_rms_final_um": 2.0}}


def test_a_failed_verdict_is_marked_and_never_counted_as_a_pass(capsys):
    """A machine whose diagnosis verdict failed ran (its files are written) but is not a pass: its status says so,
    its line is marked with the reasons, the counts keep it apart, and the fleet exits 1 (4 when a machine failed)."""
    from compensation.app.commands.fleet import print_results
    from compensation.app.workflows.fleet import fleet_counts
    ok = _machine("a", {"status": "passed", "reasons": []})
    bad = _machine("b", {"status": "failed", "reasons": ["the kept model loses to the plain baseline"]})
    assert (ok["status"], bad["status"]) == ("ok", "verdict-failed")
    assert fleet_counts([ok, bad]) == {"passed": ["a"], "verdict_failed": ["b"], "failed": []}
    assert print_results([ok, bad]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("a: run r") and out[1].startswith("b: VERDICT FAILED: run r")
    assert "loses to the plain baseline" in out[1] and out[-1] == "fleet: 1 passed, 1 verdict failed, 0 failed"
    assert print_results([ok]) == 0
    lost = {"name": "c", "status": "failed", "error": "ValueError: x"}
    assert print_results([ok, bad, lost]) == 4
    assert "fleet: 1 passed, 1 verdict failed, 1 failed" in capsys.readouterr().out


@pytest.mark.slow
def test_a_fleet_of_a_machine_tool_chain_runs_the_same_steps(tmp_path, capsys):
    """A mill-xyz chain file in a fleet: identify from its sweep file, the chain network on its feature points
    (tracked), the chain loop on its checks; sweep files of two tracker set-ups are refused up front (as for the
    grinder: one identification is one set-up), naming the files."""
    import json
    from compensation.app.cli import main
    from compensation.app.workflows.fleet import read_fleet, validate_inputs
    from errormap.machine import load_machine
    sim = tmp_path / "sim"
    assert main(["simulate", "--machine", "mill-xyz", "--seed", "4", "--checks", "150", "--out", str(sim)]) == 0
    assert main(["sweeps", "--machine", "mill-xyz", "--truth", str(sim / "truth_elements.json"),
                 "--out", str(tmp_path / "sweeps.csv")]) == 0
    mill = load_machine("mill-xyz").path
    body = (f'format = "volcomp-fleet/1"\n[[machine]]\nname = "mill"\nmachine = "{mill}"\n'
            'sweeps = "sweeps.csv"\nchecks = "sim/checks.csv"\n')
    (tmp_path / "fleet.toml").write_text(body)
    uri = f"sqlite:///{tmp_path / 'ml.db'}"
    capsys.readouterr()
    rc = main(["fleet", str(tmp_path / "fleet.toml"), "--out", str(tmp_path / "out"), "--tracking-uri", uri,
               "--train-iter", "20", "--grid", "5", "--hidden", "6"])
    assert rc == 0, capsys.readouterr().err
    m = json.loads((tmp_path / "out" / "fleet_summary.json").read_text())["machines"][0]
    assert m["status"] == "ok" and m["run_id"] and m["machine_file"] == mill
    from errormap.featurepoints import FeaturePoints
    fp = FeaturePoints.load(tmp_path / "out" / "mill" / "featurepoints.csv")
    assert fp.meta["axis_columns"] == "x_mm,y_mm,z_mm" and (tmp_path / "out" / "mill" / "train" / "model").is_dir()
    diag = json.loads((tmp_path / "out" / "mill" / "diagnosis" / "diagnosis.json").read_text())
    assert m["diagnosis"]["diagnose_heldout_rms_final_um"] == diag["held_out_rms_um"]
    assert "learned_residual" in diag   # the fleet's default: the diagnosis's learned-residual stage ran
    (tmp_path / "sweeps2.csv").write_text((tmp_path / "sweeps.csv").read_text())   # its set-up not named
    (tmp_path / "fleet.toml").write_text(body.replace('sweeps = "sweeps.csv"', 'sweeps = ["sweeps.csv", "sweeps2.csv"]'))
    with pytest.raises(InputError, match=r"sweeps2.csv: several sweep files must all name the same tracker set-up"):
        validate_inputs(read_fleet(tmp_path / "fleet.toml"))


def test_a_built_in_machine_is_named_as_machine_takes_it(tmp_path):
    """``machine = "mill-xyz"`` names the built-in file, as ``--machine mill-xyz`` does; a path that names no file,
    and a name that is no built-in machine, are refused naming the key."""
    from errormap.machine import builtin_named
    _touch(tmp_path, "s.csv", "c.csv")
    body = 'format = "volcomp-fleet/1"\n[[machine]]\nname = "a"\nmachine = "{}"\nsweeps = "s.csv"\nchecks = "c.csv"\n'
    (tmp_path / "f.toml").write_text(body.format("mill-xyz"))
    assert read_fleet(tmp_path / "f.toml")[0]["machine"] == builtin_named("mill-xyz").resolve()
    for wrong in ("no-such-machine", "machines/none.toml"):
        (tmp_path / "f.toml").write_text(body.format(wrong))
        with pytest.raises(InputError, match=re.escape("f.toml: key 'machine[0].machine': no such file")):
            read_fleet(tmp_path / "f.toml")
