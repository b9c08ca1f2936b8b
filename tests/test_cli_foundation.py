"""The foundation's commands from the command line: simulate, featurepoints, predict."""
import json

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.chain_elements import ChainElementSet
from errormap.featurepoints import DEFAULT_GRID, FeaturePoints
from errormap.io import read_table, sidecar_path

TOL_UM = 1e-6


def test_simulate_featurepoints_predict(tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["simulate", "--seed", "4", "--out", str(out), "--effect", "worm", "--checks", "50"]) == 0
    printed = capsys.readouterr().out
    assert "truth_elements.json" in printed and "checks.csv" in printed
    info = json.loads((out / "truth.json").read_text())
    # worm is the harmonic kind's alias: recorded by its canonical name on the first rotary axis (A)
    assert 150 <= info["max_spatial_error_um"] <= 230 and list(info["effects"]) == ["harmonic:A"]
    fp = FeaturePoints.load(out / "featurepoints.csv")
    assert fp.axes.shape == (DEFAULT_GRID ** 3, 3) and fp.meta["grid"] == "x".join([str(DEFAULT_GRID)] * 3)
    assert fp.meta["elements_sha256"] and fp.meta["machine_sha256"]
    # featurepoints command from the saved element set reproduces the simulate output
    assert main(["featurepoints", "--elements", str(out / "truth_elements.json"), "--out", str(tmp_path / "fp.csv")]) == 0
    np.testing.assert_allclose(FeaturePoints.load(tmp_path / "fp.csv").errors_um, fp.errors_um, atol=TOL_UM)
    # predict at the feature points gives the feature-point errors, extra columns kept
    pts = tmp_path / "pts.csv"
    pts.write_text("x_mm,z_mm,a_deg,label\n" + "\n".join(f"{x},{z},{a},p{i}" for i, (x, z, a) in enumerate(fp.axes[:20])))
    assert main(["predict", "--model", str(out / "truth_elements.json"), str(pts), "--out", str(tmp_path / "pred.csv")]) == 0
    t = read_table(tmp_path / "pred.csv")
    assert t.raw("label")[3] == "p3"
    np.testing.assert_allclose(np.c_[t.float("dx_um"), t.float("dy_um"), t.float("dz_um")], fp.errors_um[:20], atol=TOL_UM)


def test_bad_inputs_exit_cleanly(tmp_path, capsys):
    bad = tmp_path / "m.toml"
    bad.write_text('[machine]\nkind = "grinder"\n')
    assert main(["simulate", "--machine", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "geometry" in capsys.readouterr().err
    pts = tmp_path / "pts.csv"
    pts.write_text("x_mm,z_mm,a_deg\n1,2,3\n4,oops,6\n")
    el = tmp_path / "el.json"
    from errormap.machine import load_machine
    ChainElementSet.zeros(load_machine()).save(el)
    assert main(["predict", "--model", str(el), str(pts), "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err
    assert "row 3" in err and "z_mm" in err
    assert not (tmp_path / "p.csv").exists()


@pytest.mark.parametrize("effect, key", [("thermal", "thermal:X"), ("reversal", "reversal:Z")])
def test_simulate_effects_that_need_conditions(tmp_path, effect, key):
    """Without axes an effect lands on the machine's default axis (thermal: the first linear, reversal: the last)."""
    assert main(["simulate", "--seed", "1", "--out", str(tmp_path), "--effect", effect, "--checks", "20"]) == 0
    info = json.loads((tmp_path / "truth.json").read_text())
    assert list(info["effects"]) == [key] and info["max_spatial_error_um"] > 150


def test_command_help_lines_match_the_modules():
    """The light `volcomp --help` table says what each command module registers."""
    import argparse

    from compensation.app.cli import COMMAND_HELP, build_parser
    parser = build_parser()  # every module in full
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    registered = {c.dest: c.help for c in sub._choices_actions}
    assert registered == COMMAND_HELP


def test_help_and_version_import_no_numerical_library():
    """`volcomp --help` / `--version` must not pay for numpy, torch, scipy, MLflow or matplotlib."""
    import subprocess
    import sys
    code = ("import sys, contextlib, io\n"
            "from compensation.app.cli import main\n"
            "for argv in (['--help'], ['--version']):\n"
            "    with contextlib.redirect_stdout(io.StringIO()) as out:\n"
            "        try: main(argv)\n"
            "        except SystemExit as e: assert e.code == 0\n"
            "    assert out.getvalue().startswith(('usage: volcomp', 'volcomp ')), out.getvalue()\n"
            "heavy = sorted(m for m in ('numpy', 'torch', 'scipy', 'mlflow', 'matplotlib') if m in sys.modules)\n"
            "assert not heavy, heavy\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


HEAVY_LIBRARIES = ("torch", "numba", "mlflow", "ray", "matplotlib")
"""What a command loads to do its work, never to build its parser or to refuse its input (seconds each)."""


def _heavy_left(code: str, tmp_path) -> list:
    """Run ``code`` in a fresh interpreter (from ``tmp_path``); the heavy libraries it left in ``sys.modules``."""
    import subprocess
    import sys
    code += f"\nimport sys; print(sorted(m for m in {HEAVY_LIBRARIES!r} if m in sys.modules))\n"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1].replace("'", '"'))


def test_every_command_registers_its_parser_without_heavy_libraries(tmp_path):
    """Guards the start of every command (its parser is built before anything is validated; `volcomp CMD --help`):
    registering all of them loads no torch, numba, MLflow, Ray or matplotlib; the workflows load them to run."""
    code = ("from compensation.app.cli import COMMAND_MODULES, build_parser\n"
            "build_parser(COMMAND_MODULES)\n")
    assert _heavy_left(code, tmp_path) == []


@pytest.mark.parametrize("machine", ["ur5", "hexapod"])
def test_calibrate_refuses_a_missing_pose_file_before_loading_torch(tmp_path, machine):
    """Guards a refused `volcomp calibrate` (serial arm and parallel machine): the one-line error, exit 2, and
    none of the heavy libraries loaded (torch was 2.5 s of the 6 s this refusal took)."""
    code = ("import contextlib, io\n"
            "from compensation.app.cli import main\n"
            "err = io.StringIO()\n"
            "with contextlib.redirect_stderr(err):\n"
            f"    rc = main(['calibrate', 'missing.csv', '--machine', {machine!r}, '--out', 'out'])\n"
            "assert rc == 2 and err.getvalue() == 'volcomp calibrate: error: missing.csv: no such file\\n', "
            "(rc, err.getvalue())\n")
    assert _heavy_left(code, tmp_path) == []


def test_compensate_refuses_a_missing_model_before_loading_the_solver(tmp_path):
    """Guards a refused `volcomp compensate --model missing.json` on a machine tool: the model file is looked for
    before the method is checked on the chain and the solver's numba kernels load (2.5 CPU s before): the one-line
    error, exit 2, none of the heavy libraries loaded."""
    (tmp_path / "P.nc").write_text("G1 X1\n")
    code = ("import contextlib, io\n"
            "from compensation.app.cli import main\n"
            "err = io.StringIO()\n"
            "with contextlib.redirect_stderr(err):\n"
            "    rc = main(['compensate', 'P.nc', '--model', 'missing.json', '--method', 'exact', '--out', 'out'])\n"
            "assert rc == 2 and err.getvalue() == ('volcomp compensate: error: missing.json: no such file or folder, "
            "and not an MLflow run id (32 hex digits), runs:/ or models:/ URI\\n'), (rc, err.getvalue())\n")
    assert _heavy_left(code, tmp_path) == []


def test_error_line_is_one_line_and_bounded():
    from compensation.app.cli import MAX_ERROR_CHARS, one_line
    msg = "f.csv: row 2, column 'x': " + "x" * 10_000 + "\nsecond line"
    s = one_line(msg)
    assert len(s) <= MAX_ERROR_CHARS and "\n" not in s and s.startswith("f.csv: row 2")


def test_provenance_paths_resolve_relative_to_the_file(tmp_path, monkeypatch):
    """simulate run from one folder, the feature points used from another: elements_file still found."""
    from training.trainers import chain_reference, machine_from_meta
    work = tmp_path / "a"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["simulate", "--seed", "2", "--out", "sim", "--checks", "20"]) == 0
    assert main(["featurepoints", "--elements", "sim/truth_elements.json", "--out", "fp/fp.csv", "--grid", "3"]) == 0
    # written relative to the CSV's folder (in its provenance sidecar)
    assert read_table(work / "sim" / "featurepoints.csv").meta()["elements_file"] == "truth_elements.json"
    assert read_table(work / "fp" / "fp.csv").meta()["elements_file"] == "../sim/truth_elements.json"
    other = tmp_path / "b"
    other.mkdir()
    monkeypatch.chdir(other)
    for f in (work / "sim" / "featurepoints.csv", work / "fp" / "fp.csv"):
        fp = FeaturePoints.load(f)
        assert fp.meta["elements_file"] == str((work / "sim" / "truth_elements.json").resolve())
        ref = chain_reference(machine_from_meta(fp.meta), fp.meta)
        assert ref is not None
        np.testing.assert_allclose(ref[1].predict(fp.axes), fp.errors_um, atol=TOL_UM)


def test_predict_refuses_outside_the_calibrated_volume(tmp_path, capsys):
    el = tmp_path / "el.json"
    from errormap.machine import load_machine
    ChainElementSet.zeros(load_machine()).save(el)
    pts = tmp_path / "pts.csv"
    pts.write_text("x_mm,z_mm,a_deg\n10,2,3\n1000000,2,3\n")
    argv = ["predict", "--model", str(el), str(pts), "--out", str(tmp_path / "p.csv")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "row 3" in err and "x_mm" in err and "μm rather than mm" in err and "--allow extrapolate" in err
    assert not (tmp_path / "p.csv").exists()
    assert main(argv + ["--allow", "extrapolate"]) == 0
    head = json.loads(sidecar_path(tmp_path / "p.csv").read_text())["lines"]
    # the override is recorded with the output (its provenance sidecar): which points it let through and by which option
    assert any("allowed: volume (1 of 2 points outside the calibrated volume, --allow extrapolate)" in ln
               for ln in head), head


@pytest.mark.parametrize("column, scale, named", [("x_mm", 1e-3, "metres rather than mm"),
                                                  ("z_mm", 1e-3, "metres rather than mm"),
                                                  ("a_deg", np.pi / 180, "radians rather than degrees")])
def test_checks_in_metres_or_radians_are_refused(tmp_path, column, scale, named):
    from errormap.diagnosis.chain_checks import load_chain_checks
    from errormap.io import InputError, write_csv
    from errormap.machine import load_machine
    machine = load_machine()
    assert main(["simulate", "--seed", "1", "--out", str(tmp_path / "sim"), "--checks", "40"]) == 0
    t = read_table(tmp_path / "sim" / "checks.csv")
    d = {c: t.float(c) for c in t.names}
    load_chain_checks(tmp_path / "sim" / "checks.csv", machine)  # as simulated: accepted
    d[column] = d[column] * scale
    write_csv(tmp_path / "c.csv", d)
    with pytest.raises(InputError, match=named) as exc:
        load_chain_checks(tmp_path / "c.csv", machine)
    assert f"column '{column}'" in str(exc.value)


def test_a_small_region_in_mm_is_not_taken_for_metres():
    from errormap.machine import load_machine
    from errormap.units import chain_axes_mistake
    m = load_machine()
    rng = np.random.default_rng(0)
    small = np.c_[100 + 0.5 * rng.random(40), 30 + 0.05 * rng.random(40), 360 * rng.random(40)]
    assert chain_axes_mistake(small, m, "volume") is None
    metres = small.copy()
    metres[:, 0] = 0.2 * rng.random(40)
    assert chain_axes_mistake(metres, m, "volume")[1] == 0


def test_a_small_a_range_in_degrees_is_not_taken_for_radians():
    """Checks over A = 0…4.5° (random) or on a 0…6° grid are degrees; a full turn in radians is refused."""
    from errormap.machine import load_machine
    from errormap.units import chain_axes_mistake
    m = load_machine()
    rng = np.random.default_rng(1)
    xz = np.c_[200 * rng.random(40), 60 * rng.random(40)]
    assert chain_axes_mistake(np.c_[xz, 4.5 * rng.random(40)], m, "volume") is None
    assert chain_axes_mistake(np.c_[xz, rng.integers(0, 7, 40).astype(float)], m, "volume") is None
    radians = np.c_[xz, np.radians(360 * rng.random(40))]
    assert chain_axes_mistake(radians, m, "volume")[1] == 2
