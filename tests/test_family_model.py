"""One model file for every family: ``volcomp calibrate`` writes ``model.json`` (``volcomp-model/1``, key ``family``,
the calibration in its ``calibration`` section) for a serial arm and a parallel machine, and
:func:`compensation.model_file.read_model` reads it and the older bare ``calibration.json`` files
(``volcomp-arm-calibration/2`` … ``/4``, ``volcomp-pkm-calibration/1`` and before its format key) the same way:
predictions through the new file and the old one are equal to the bit; a garbled file is refused in one line
naming the file and the key."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import MAX_ERROR_CHARS, main
from compensation.calibration_models import calibration_model_document, calibration_section
from compensation.fields import ARM_FORMAT, MODEL_FORMAT
from compensation.model_file import read_model
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.io import InputError, read_table, write_json
from errormap.machine import load_machine

ROOT = Path(__file__).resolve().parents[1]
UR5_GRID = ROOT / ".." / "shared" / "data" / "serial-arms" / "ur5_grid.csv"
UR5_LO, UR5_HI = np.full(6, -170.0), np.full(6, 170.0)
NOISE_MM = 0.02


def _old_of(model_json: Path, out: Path) -> Path:
    """The bare calibration.json calibrate wrote before model.json: the ``calibration`` section with the verdict."""
    doc = json.loads(model_json.read_text(encoding="utf-8"))
    write_json(out, {**doc["calibration"], "verdict": doc["verdict"]})
    return out


def _numbers(csv: Path) -> dict:
    t = read_table(csv)
    return {c: t.float(c) for c in t.names}


def _same_csv(a: Path, b: Path):
    """Equal to the bit, column by column (the header names the model file, the only difference)."""
    na, nb = _numbers(a), _numbers(b)
    assert list(na) == list(nb)
    for c in na:
        assert np.array_equal(na[c], nb[c]), c
    body = [[ln for ln in p.read_text(encoding="utf-8").splitlines() if not ln.startswith("#")] for p in (a, b)]
    assert body[0] == body[1]


def _refused(argv, capsys, *words):
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and len(err) < MAX_ERROR_CHARS, err
    for w in words:
        assert w in err, (w, err)


# --- serial arm -------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def arm_files(tmp_path_factory):
    """A UR5's plain LSQ calibration of 60 simulated poses (fast) as the old bare files /4, /3, /2 and as model.json,
    and a 5-point joint program."""
    from errormap.arm_calibration import fit_plain_lsq
    ur5 = load_machine("ur5")
    d = tmp_path_factory.mktemp("armfamily")
    fit = measure(ur5, draw_truth(ur5, 7), random_joints(UR5_LO, UR5_HI, 60, [7, 0]), NOISE_MM, [7, 1])
    geo = fit_plain_lsq(ur5, fit)
    old = {"format": ARM_FORMAT, "machine": {"name": ur5.name, "joints": ur5.joint_columns},
           "kept_stage": "plain geometric LSQ", "geometric": geo.to_dict(), "plain_geometric": geo.to_dict(),
           "learned": None, "verdict": None}
    files = {}
    for fmt in (ARM_FORMAT, "volcomp-arm-calibration/3", "volcomp-arm-calibration/2"):
        files[fmt] = write_json(d / f"{fmt.rsplit('/', 1)[1]}.json", {**old, "format": fmt})
    files["model"] = write_json(d / "model.json", calibration_model_document("arm", ur5, old))
    prog = d / "prog.csv"
    qp = random_joints(UR5_LO + 5, UR5_HI - 5, 5, [7, 9])
    prog.write_text(",".join(ur5.joint_columns) + "\n" + "\n".join(",".join(f"{v:.10g}" for v in r) for r in qp))
    return ur5, files, prog, qp


def test_arm_model_json_and_every_older_arm_file_read_the_same(arm_files):
    ur5, files, _, qp = arm_files
    doc = json.loads(files["model"].read_text())
    assert doc["format"] == MODEL_FORMAT and doc["family"] == "arm" and doc["calibration"]["format"] == ARM_FORMAT
    new = read_model(files["model"], ur5, family="arm")
    assert new.family == "arm" and new.source.kind == "arm-model" and new.calibration.format == ARM_FORMAT
    want = new.calibration.geometric.predict(qp)
    for fmt in (ARM_FORMAT, "volcomp-arm-calibration/3", "volcomp-arm-calibration/2"):
        m = read_model(files[fmt], ur5, family="arm")
        assert m.source.kind == "arm-calibration" and m.calibration.format == fmt
        assert np.array_equal(m.calibration.geometric.predict(qp), want), fmt
    files_old = files["volcomp-arm-calibration/3"]
    with pytest.raises(InputError, match=r"3\.json: key 'format': 'volcomp-arm-calibration/3' predates"):
        read_model(files_old, ur5, family="arm").calibration.require_base_frame(files_old)


def test_arm_predict_and_compensate_through_model_json_equal_the_old_file(arm_files, tmp_path, capsys):
    _, files, prog, _ = arm_files
    for tag, f in (("new", files["model"]), ("old", files[ARM_FORMAT])):
        assert main(["predict", str(prog), "--machine", "ur5", "--model", str(f), "--out",
                     str(tmp_path / f"{tag}.csv")]) == 0
        assert main(["compensate", str(prog), "--machine", "ur5", "--model", str(f), "--out",
                     str(tmp_path / f"c{tag}")]) == 0
    _same_csv(tmp_path / "new.csv", tmp_path / "old.csv")
    _same_csv(tmp_path / "cnew" / prog.name, tmp_path / "cold" / prog.name)
    # an older file from before the base frame was kept apart: refused in one line, as before
    _refused(["predict", prog, "--machine", "ur5", "--model", files["volcomp-arm-calibration/3"], "--out",
              tmp_path / "x.csv"], capsys, "3.json", "key 'format'")


def test_garbled_arm_model_json_is_refused_naming_file_and_key(arm_files, tmp_path, capsys):
    _, files, prog, _ = arm_files
    good = json.loads(files["model"].read_text())
    cases = {"family": ({**good, "family": "robot"}, "key 'family'"),
             "calibration": ({**good, "calibration": [1, 2]}, "key 'calibration'"),
             "cformat": ({**good, "calibration": {**good["calibration"], "format": "volcomp-arm-calibration/9"}},
                         "key 'calibration.format'"),
             "geometric": ({**good, "calibration": {k: v for k, v in good["calibration"].items() if k != "geometric"}},
                           "key 'calibration.geometric'"),
             "machine": ({**good, "calibration": {**good["calibration"], "machine": {"name": "wam"}}},
                         "key 'calibration.machine'")}
    for name, (doc, key) in cases.items():
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps(doc))
        _refused(["predict", prog, "--machine", "ur5", "--model", p, "--out", tmp_path / "o.csv"], capsys, str(p), key)
    # a machine tool's model.json given to an arm, and an arm's to a machine tool: refused naming the key
    hexa = tmp_path / "hexa.json"
    hexa.write_text(json.dumps({**good, "family": "parallel"}))
    _refused(["predict", prog, "--machine", "ur5", "--model", hexa, "--out", tmp_path / "o.csv"], capsys,
             str(hexa), "key 'family'")


@pytest.mark.slow   # a real UR5 calibration with its learned stages: about 8 CPU s
@pytest.mark.skipif(not UR5_GRID.is_file(), reason="the real serial-arm data (../shared/data/serial-arms) is absent")
def test_real_ur5_calibration_predicts_the_same_through_model_json_and_the_old_file(tmp_path):
    """The first 120 poses of the real UR5 grid calibrated end to end (learned stages on); its predictions and
    compensated program through model.json and through the bare calibration.json it replaces: equal to the bit."""
    lines = UR5_GRID.read_text(encoding="utf-8").splitlines()
    (tmp_path / "ur5.csv").write_text("\n".join(lines[:121]) + "\n")
    assert main(["calibrate", str(tmp_path / "ur5.csv"), "--machine", "ur5", "--folds", "3", "--out",
                 str(tmp_path / "cal")]) == 0
    new = tmp_path / "cal" / "model.json"
    assert json.loads(new.read_text())["format"] == MODEL_FORMAT
    old = _old_of(new, tmp_path / "old.json")
    ur5 = load_machine("ur5")
    n, o = read_model(new, ur5, family="arm").calibration, read_model(old, ur5, family="arm").calibration
    assert n.band_scale == o.band_scale and (n.learner is None) == (o.learner is None)
    prog = tmp_path / "prog.csv"
    head = lines[0].split(",")
    joints = [head.index(f"joint_{i}") for i in range(1, 7)]
    prog.write_text(",".join(ur5.joint_columns) + "\n" + "\n".join(
        ",".join(ln.split(",")[j] for j in joints) for ln in lines[200:260]) + "\n")
    for tag, f in (("new", new), ("old", old)):
        assert main(["predict", str(prog), "--machine", "ur5", "--model", str(f), "--band", "95", "--out",
                     str(tmp_path / f"{tag}.csv")]) == 0
        assert main(["compensate", str(prog), "--machine", "ur5", "--model", str(f), "--out",
                     str(tmp_path / f"c{tag}")]) == 0
    _same_csv(tmp_path / "new.csv", tmp_path / "old.csv")
    _same_csv(tmp_path / "cnew" / prog.name, tmp_path / "cold" / prog.name)


# --- parallel machine --------------------------------------------------------------------------------------------
def test_hexapod_model_json_and_older_pkm_files_read_the_same(tmp_path):
    """A hexapod calibration section (its platform joints moved 0.1 %) as model.json, as the bare
    volcomp-pkm-calibration/1 file and as that file before its format key: the same identified machine to the bit;
    a garbled section refused naming the file and the key."""
    from errormap.pkm.calibration_file import CALIBRATION_FORMAT
    m = load_machine("hexapod")
    im = {"base_joints_mm": m.base_joints_mm.tolist(), "platform_joints_mm": (m.platform_joints_mm * 1.001).tolist(),
          "leg_offset_mm": np.asarray(m.leg_offset_mm).tolist(), "leg_scale": np.asarray(m.leg_scale).tolist()}
    sec = {"format": CALIBRATION_FORMAT, "kind": m.kind, "machine": {"name": m.name}, "identified_machine": im}
    files = {"new": write_json(tmp_path / "model.json", calibration_model_document("parallel", m, sec)),
             "old": write_json(tmp_path / "old.json", sec),
             "oldest": write_json(tmp_path / "oldest.json", {k: v for k, v in sec.items() if k != "format"})}
    got = {k: read_model(f, m, family="parallel") for k, f in files.items()}
    assert got["new"].source.kind == "pkm-model" and {got["old"].source.kind, got["oldest"].source.kind} == {"pkm-calibration"}
    for k in ("old", "oldest"):
        for a in ("base_joints_mm", "platform_joints_mm", "leg_offset_mm", "leg_scale"):
            assert np.array_equal(getattr(got[k].calibration, a), getattr(got["new"].calibration, a)), (k, a)
    assert np.array_equal(got["new"].calibration.platform_joints_mm, m.platform_joints_mm * 1.001)
    doc = json.loads(files["new"].read_text())
    for name, bad, key in (("im", {**sec, "identified_machine": {"leg_scale": [1]}}, "'calibration.identified_machine'"),
                           ("kind", {**sec, "kind": "tripod"}, "'calibration.kind'"),
                           ("fmt", {**sec, "format": "volcomp-pkm-calibration/7"}, "'calibration.format'")):
        p = write_json(tmp_path / f"{name}.json", {**doc, "calibration": bad})
        with pytest.raises(InputError, match=rf"{name}\.json: key {key}") as exc:
            read_model(p, m, family="parallel")
        assert len(str(exc.value)) < MAX_ERROR_CHARS and "\n" not in str(exc.value)


@pytest.mark.slow  # a hexapod calibration: over 5 CPU s
def test_hexapod_calibration_predicts_the_same_through_model_json_and_the_old_files(tmp_path, capsys):
    """A simulated hexapod calibrated (``--no-loop``: predict takes no leg terms); predict and interpolate through
    its model.json, the bare calibration.json it replaces, and that file without its format key (the oldest):
    equal to the bit. Garbled sections refused in one line naming the file and the key."""
    from errormap.io import write_csv
    from errormap.pkm.hexapod import forward_kinematics, rotation_to_angles
    from errormap.pkm.poses import read_poses
    m = load_machine("hexapod")
    assert main(["simulate", "--machine", "hexapod", "--seed", "0", "--poses", "60", "--checks", "40",
                 "--out", str(tmp_path / "sim")]) == 0
    assert main(["calibrate", str(tmp_path / "sim" / "poses.csv"), "--machine", "hexapod", "--no-loop", "--check",
                 str(tmp_path / "sim" / "checks.csv"), "--out", str(tmp_path / "cal")]) == 0
    new = tmp_path / "cal" / "model.json"
    doc = json.loads(new.read_text())
    assert doc["format"] == MODEL_FORMAT and doc["family"] == "parallel"
    old = _old_of(new, tmp_path / "old.json")
    oldest = write_json(tmp_path / "oldest.json", {k: v for k, v in calibration_section(old, "parallel")[0].items()
                                                   if k != "format"})
    chk = read_poses(tmp_path / "sim" / "checks.csv", m)
    nom = forward_kinematics(m, m.drive_to_legs(chk.q))
    a = rotation_to_angles(nom.platform2base)
    write_csv(tmp_path / "pts.csv", {"x_mm": nom.x[:, 0], "y_mm": nom.x[:, 1], "z_mm": nom.x[:, 2],
                                     "rx_deg": a[:, 0], "ry_deg": a[:, 1], "rz_deg": a[:, 2]})
    for tag, f in (("new", new), ("old", old), ("oldest", oldest), ("folder", tmp_path / "cal")):
        assert main(["predict", str(tmp_path / "pts.csv"), "--machine", "hexapod", "--model", str(f), "--out",
                     str(tmp_path / f"{tag}.csv")]) == 0
        assert main(["interpolate", "sphere", "--machine", "hexapod", "--calibration", str(f), "--out",
                     str(tmp_path / f"i{tag}.csv")]) == 0
    for tag in ("old", "oldest", "folder"):
        _same_csv(tmp_path / "new.csv", tmp_path / f"{tag}.csv")
        _same_csv(tmp_path / "inew.csv", tmp_path / f"i{tag}.csv")
    capsys.readouterr()
    sec = doc["calibration"]
    for name, bad, key in (("im", {**sec, "identified_machine": {"leg_scale": [1]}}, "key 'calibration.identified_machine'"),
                           ("kind", {**sec, "kind": "tripod"}, "key 'calibration.kind'"),
                           ("fmt", {**sec, "format": "volcomp-pkm-calibration/7"}, "key 'calibration.format'")):
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps({**doc, "calibration": bad}))
        _refused(["predict", tmp_path / "pts.csv", "--machine", "hexapod", "--model", p, "--out", tmp_path / "o.csv"],
                 capsys, str(p), key)
    _refused(["predict", tmp_path / "pts.csv", "--machine", "ur5", "--model", new, "--out", tmp_path / "o.csv"],
             capsys, str(new), "key 'family'")
    _refused(["report", tmp_path / "cal"], capsys, str(new), "key 'family'")
