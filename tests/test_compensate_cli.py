"""``volcomp compensate``: batch CSV / G-code compensation from the command line."""
import json

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.nc_state import MACHINE, read_work_offsets
from compensation.pathio import write_axes_gcode
from compensation.toolpath import flute_path
from path_files import read_as_compensate, write_targets_csv
from errormap.chain_field import ChainField
from errormap.chain_truth import make_chain_truth
from errormap.io import read_table

MCS = read_work_offsets(MACHINE)
"""The G-code programs here are written in machine coordinates (the grinder's axes): read with
--work-offsets machine (a program is never read at an assumed zero)."""
MCS_NOTE = "(volcomp: work offsets taken as machine zero [--work-offsets machine])"
"""The first line every compensated G-code output here starts with: the frame the user gave."""

TOL_MM = 2e-6            # written with 6 decimals
TOL_MODEL_RESIDUAL_UM = 1e-3


@pytest.fixture(scope="module")
def setup(tmp_path_factory, grinder):
    d = tmp_path_factory.mktemp("comp")
    truth = make_chain_truth(grinder, 7)
    el = truth.elements.save(d / "elements.json")
    f = flute_path(turns=1, points_per_turn=40)
    nc = write_axes_gcode(d / "in" / "flute.nc", f.axes(grinder), header=["flute test"])
    csv = write_targets_csv(d / "in" / "flute.csv", f.targets_mm)
    return d, el, nc, csv, ChainField(grinder, truth.elements)


@pytest.mark.slow  # over 5 CPU s in the fresh-clone CI run of 2026-11-24 (tier rule)
def test_batch_writes_each_file_and_summary(setup, grinder, capsys):
    d, el, nc, csv, field = setup
    before = (nc.read_bytes(), csv.read_bytes())
    out = d / "out"
    rc = main(["compensate", "--work-offsets", "machine",
               str(nc), str(csv), "--model", str(el), "--method", "exact", "--out", str(out),
               "--max-segment-mm", "none"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "flute.nc: 40 points" in printed and "model residual max" in printed and str(out) in printed
    assert (nc.read_bytes(), csv.read_bytes()) == before  # inputs untouched
    summary = json.loads((out / "compensate_summary.json").read_text())
    assert [e["points"] for e in summary["files"]] == [40, 40]
    assert all(e["model_max_um"] < TOL_MODEL_RESIDUAL_UM for e in summary["files"])
    # the written commands land on the targets under the model: E(axes) cancels the correction
    src = read_as_compensate(nc, grinder, work_offsets=MCS)
    res = read_as_compensate(out / "flute.nc", grinder, work_offsets=MCS)
    from errormap.chain_kernel import forward
    reached = forward(grinder, res.axes) + 1e-3 * field.predict(res.axes)
    assert np.abs(reached - forward(grinder, src.axes)).max() < 1e-3 * TOL_MODEL_RESIDUAL_UM + TOL_MM
    assert np.abs(res.axes[:, 2] - src.axes[:, 2]).max() < 180.0  # A stays on its turn
    # a targets CSV comes back as compensated WCS commands p_r
    assert read_as_compensate(out / "flute.csv", grinder).kind == "csv-targets"


def test_refuses_to_overwrite_inputs(setup, capsys):
    d, el, nc, csv, _ = setup
    rc = main(["compensate", "--work-offsets", "machine",
               str(nc), "--model", str(el), "--method", "traditional", "--out", str(nc.parent)])
    assert rc == 2
    assert "overwrite" in capsys.readouterr().err


def test_bad_file_names_line_and_writes_nothing(setup, capsys):
    d, el, nc, _, _ = setup
    bad = d / "bad" / "bad.nc"
    bad.parent.mkdir(exist_ok=True)
    bad.write_text("G21 G90\nG1 X10 Z1 A0\nG1 X#3\n")
    out = d / "out_bad"
    rc = main(["compensate", "--work-offsets", "machine",
               str(nc), str(bad), "--model", str(el), "--method", "traditional", "--out", str(out)])
    assert rc == 2
    err = capsys.readouterr().err
    assert "bad.nc: line 3" in err
    assert not out.exists()  # inputs are all read before any output


def _edge_file(d):
    src = d / "edge" / "edge.nc"
    src.parent.mkdir(exist_ok=True)
    # X = -0.5 mm is outside the X stroke by more than the 250 um search ball
    src.write_text("G21 G90\nG1 X10 Z1 A0\nG1 X-0.5 Z1 A10\nG1 X20 Z1 A20\nG1 X-0.6 Z1 A30\nM30\n")
    return src


def test_guard_refusal_reaches_the_cli_and_allow_overrides(setup, capsys):
    d, el, _, _, _ = setup
    src = _edge_file(d)
    out = d / "out_edge"
    rc = main(["compensate", "--work-offsets", "machine",
               str(src), "--model", str(el), "--method", "traditional", "--out", str(out)])
    assert rc != 0
    err = capsys.readouterr().err
    assert "refused" in err and "stroke" in err and "(line 3)" in err and "(line 5)" in err
    assert "(line 4)" not in err
    assert not (out / "edge.nc").exists()
    rc = main(["compensate", "--work-offsets", "machine",
               str(src), "--model", str(el), "--method", "traditional", "--out", str(out), "--allow"])
    assert rc == 2 and "--force" in capsys.readouterr().err  # DIR holds the previous run's summary
    rc = main(["compensate", "--work-offsets", "machine",
               str(src), "--model", str(el), "--method", "traditional", "--out", str(out), "--allow",
               "--force"])
    assert rc == 0
    assert (out / "edge.nc").exists()
    summary = json.loads((out / "compensate_summary.json").read_text())
    assert summary["files"][0]["guard_violations"]["stroke"] >= 2


def test_allow_names_guards(setup, capsys):
    d, el, _, _, _ = setup
    src = _edge_file(d)
    out = d / "out_edge2"
    base = ["compensate", "--work-offsets", "machine",
            str(src), "--model", str(el), "--method", "traditional", "--out", str(out), "--force"]
    assert main(base + ["--allow", "ball"]) == 3          # the stroke guard still refuses
    assert "stroke" in capsys.readouterr().err
    assert main(base + ["--allow", "stroke,volume"]) == 0
    assert main(base + ["--allow", "nonsense"]) == 2


def test_interrupted_batch_leaves_whole_files_only(setup, grinder, monkeypatch, capsys):
    import compensation.batch as cmd  # where every chunk of a batch is solved
    d, el, nc, csv, _ = setup
    real = cmd.solve
    calls = []

    def interrupt_second(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(cmd, "solve", interrupt_second)
    out = d / "out_int"
    rc = main(["compensate", "--work-offsets", "machine",
               str(nc), str(csv), "--model", str(el), "--method", "traditional", "--out", str(out)])
    assert rc == 130 and "interrupted" in capsys.readouterr().err
    # every input is solved before the first output is written: nothing at all in DIR
    assert not out.exists() or not any(out.iterdir())


def test_traditional_passes_the_guards_on_its_targets(setup, capsys):
    d, el, _, _, _ = setup
    src = d / "z" / "plunge.nc"
    src.parent.mkdir(exist_ok=True)
    src.write_text("G21 G90\nG1 X10 Z1 A0 F100\nG1 Z-0.1 A10\nG1 Z1 A20\nM30\n")  # Z = -0.1: outside the stroke
    out = d / "out_z"
    rc = main(["compensate", "--work-offsets", "machine",
               str(src), "--model", str(el), "--method", "traditional", "--out", str(out),
               "--max-segment-mm", "none"])
    err = capsys.readouterr().err
    assert rc == 3 and "point 1 (line 3)" in err and "target z_mm = -0.1 outside stroke" in err
    assert not (out / "plunge.nc").exists()


def test_override_is_written_into_the_files(setup, capsys):
    d, el, _, _, _ = setup
    src = _edge_file(d)
    csv = d / "edge" / "edge.csv"
    csv.write_text("x_mm,z_mm,a_deg\n10,1,0\n-0.5,1,10\n")
    out = d / "out_override"
    assert main(["compensate", "--work-offsets", "machine",
                 str(src), str(csv), "--model", str(el), "--method", "exact", "--out", str(out),
                 "--allow", "stroke,volume"]) == 0
    note, head = (out / "edge.nc").read_text().splitlines()[:2]
    assert note == MCS_NOTE and head.startswith("(volcomp compensate: GUARDS OVERRIDDEN [--allow stroke,volume]")
    assert "stroke 2" in head
    csv_lines = read_table(out / "edge.csv").comments   # a plain CSV: the note is in its provenance sidecar
    assert any(ln.startswith("volcomp compensate: GUARDS OVERRIDDEN (--allow stroke,volume)") for ln in csv_lines)
    summary = json.loads((out / "compensate_summary.json").read_text())
    assert summary["files"][0]["overridden"] == {"stroke": 2, "volume": 2}


def test_rerun_leaves_no_stale_output(setup, capsys):
    d, el, nc, _, _ = setup
    src = _edge_file(d)
    ok = d / "edge" / "ok.nc"
    ok.write_text("G21 G90\nG1 X10 Z1 A0 F100\nG1 X20 A10\nM30\n")
    out = d / "out_stale"
    base = ["compensate", "--work-offsets", "machine",
            str(src), str(ok), "--model", str(el), "--method", "traditional", "--out", str(out)]
    assert main(base + ["--allow"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["compensate_summary.json", "edge.nc", "ok.nc"]
    assert main(base) == 2 and "--force" in capsys.readouterr().err  # DIR holds files: refused without --force
    assert main(base + ["--force"]) == 3  # edge.nc is refused this time: its old output is removed
    assert sorted(p.name for p in out.iterdir()) == ["compensate_summary.json", "ok.nc"]
    summary = json.loads((out / "compensate_summary.json").read_text())
    assert [e["output"] for e in summary["files"]] == [None, str(out / "ok.nc")]
    assert summary["removed_stale"] == [str(out / "edge.nc")]
    # a third run with only ok.nc: nothing of the earlier runs but its own output remains
    assert main(["compensate", "--work-offsets", "machine",
                 str(ok), "--model", str(el), "--method", "traditional", "--out", str(out),
                 "--force"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["compensate_summary.json", "ok.nc"]


def test_rapids_and_block_delete_options(setup, grinder, capsys):
    d, el, _, _, _ = setup
    src = d / "edge" / "rapid.nc"
    src.parent.mkdir(exist_ok=True)  # under xdist this test may run before the one that made it
    src.write_text("G21 G90\nG0 X10 Z30 A0\nG1 Z1 F100\nG1 X20 A10\n/G1 X25\nG0 Z30\nM30\n")
    out = d / "out_rapids"
    base = ["compensate", "--work-offsets", "machine",
            str(src), "--model", str(el), "--method", "exact", "--max-segment-mm", "none", "--force"]
    assert main(base + ["--out", str(out)]) == 2
    assert "line 5, column 1: block delete" in capsys.readouterr().err
    assert main(base + ["--out", str(out), "--block-delete", "on"]) == 0
    note, *lines = (out / "rapid.nc").read_text().splitlines()
    assert note == MCS_NOTE and lines[1] == "G0 X10 Z30 A0" and lines[5] == "G0 Z30" and lines[4] == "/G1 X25"  # kept as written
    assert main(base + ["--out", str(out), "--block-delete", "off", "--rapids", "compensate"]) == 0
    note, *lines = (out / "rapid.nc").read_text().splitlines()
    assert note == MCS_NOTE and lines[1].startswith("G0 X") and lines[1] != "G0 X10 Z30 A0" and lines[4].startswith("/G1 X")
    assert len(read_as_compensate(out / "rapid.nc", grinder, rapids="compensate", block_delete="off",
                                  work_offsets=MCS)) == 5


def test_kept_rapid_outside_the_strokes_is_refused(setup, capsys):
    d, el, _, _, _ = setup
    src = d / "edge" / "rapid_out.nc"
    src.parent.mkdir(exist_ok=True)  # under xdist this test may run before the one that made it
    src.write_text("G21 G90\nG0 X10 Z70 A0\nG1 Z1 F100\nG1 X20 A10\nM30\n")
    rc = main(["compensate", "--work-offsets", "machine",
               str(src), "--model", str(el), "--method", "exact", "--out", str(d / "out_ro")])
    assert rc == 3 and "line 2: stroke: kept rapid z_mm = 70" in capsys.readouterr().err


def test_output_set_is_all_or_nothing(setup, grinder, tmp_path):
    """An error while compensate's set is being written leaves no output and no temporary file."""
    from compensation.app.workflows.compensate import write_outputs
    from path_files import outcome, read_as_compensate
    d, el, nc, csv, _ = setup
    a, b = (read_as_compensate(p, grinder, work_offsets=MCS) for p in (nc, csv))
    out = tmp_path / "set"
    items = [outcome(a, out / "flute.nc", grinder, a.axes),
             outcome(b, out / "flute.csv", grinder, b.axes, b.targets_mm)]
    items[1].text = 12345  # the second cannot be encoded
    with pytest.raises(AttributeError):
        write_outputs(items)
    assert list(out.iterdir()) == []  # the first file, complete on disk, was not renamed into place
    write_outputs(items[:1])
    assert sorted(p.name for p in out.iterdir()) == ["flute.nc"]


def test_allow_ball_overrides_a_correction_beyond_the_ball(setup, monkeypatch, capsys):
    import compensation.model_file as model_file  # compensate reads its model through model_file.read_model
    from tests.test_guards import ConstantField
    d, el, _, _, _ = setup
    src = d / "edge" / "ball.nc"
    src.parent.mkdir(exist_ok=True)
    src.write_text("G21 G90\nG1 X10 Z1 A0 F100\nG1 X20 A10\nM30\n")
    monkeypatch.setattr(model_file, "read_model", lambda spec, machine, uri, source=None: model_file.Model(
        ConstantField(machine, [0.0, 300.0, 200.0]), source, "a constant field"))
    base = ["compensate", "--work-offsets", "machine",
            str(src), "--model", str(el), "--method", "exact", "--max-segment-mm", "none"]
    assert main(base + ["--out", str(d / "out_ball1")]) == 3
    err = capsys.readouterr().err
    assert "refused by guard(s) ball" in err and "convergence" not in err
    assert main(base + ["--out", str(d / "out_ball2"), "--allow", "ball"]) == 0
    note, head = (d / "out_ball2" / "ball.nc").read_text().splitlines()[:2]
    assert note == MCS_NOTE and head.startswith("(volcomp compensate: GUARDS OVERRIDDEN [--allow ball]")
