"""The serial chain as data (errormap/chain.py, errormap/chain_file.py): FK of the built-in arms
against the published targets, analytic Jacobians against finite differences, bad machine files."""
from pathlib import Path

import numpy as np
import pytest

from errormap.chain_file import parse_serial
from errormap.machine import MachineFileError, load_machine

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "serial-arms"
# the data README: targets equal nominal DH FK + the tool point "to ~0.01 mm"; issue 26 asks 0.02 mm RMS
UR5_TARGET_RMS_MM = 0.02
# the WAM's targets were written with more digits of its table: measured 0.0005 mm RMS; 0.002 leaves margin
WAM_TARGET_RMS_MM = 0.002
# central differences with h = 1e-6 on mm-sized arms: truncation + rounding well below 1e-5 mm per unit
FD_STEP = 1e-6
FD_TOL = 1e-5
FD_JOINT_STEP_DEG = 1e-5
FD_JOINT_TOL = 1e-6  # mm per deg


def _grid(name, n):
    f = SHARED / f"{name}_grid.csv"
    if not f.is_file():
        pytest.skip(f"{f} not present (the shared serial-arm data)")
    d = np.genfromtxt(f, delimiter=",", names=True)
    return np.stack([d[f"joint_{i + 1}"] for i in range(n)], 1), np.stack([d["x_t"], d["y_t"], d["z_t"]], 1)


@pytest.mark.parametrize("name,n,tol", [("ur5", 6, UR5_TARGET_RMS_MM), ("wam", 7, WAM_TARGET_RMS_MM)])
def test_builtin_fk_reproduces_published_targets(name, n, tol):
    chain = load_machine(name)
    assert chain.kind == "serial" and chain.n_joints == n
    q, target = _grid(name, n)
    rms = np.sqrt(np.mean(np.sum((chain.tool_point(q) - target) ** 2, axis=1)))
    assert rms <= tol


@pytest.mark.parametrize("name", ["ur5", "ur10", "wam"])
def test_jacobians_match_finite_differences(name):
    chain = load_machine(name)
    rng = np.random.default_rng(3)
    q = rng.uniform(np.maximum(chain.joint_lo, -170), np.minimum(chain.joint_hi, 170), (7, chain.n_joints))
    e0 = rng.normal(0, 1e-3, chain.n_params)
    J = chain.error_jacobian(q, e0)
    assert J.shape == (7, 3, chain.n_params)
    for k in range(chain.n_params):
        ep, em = e0.copy(), e0.copy()
        ep[k] += FD_STEP
        em[k] -= FD_STEP
        fd = (chain.tool_point(q, ep) - chain.tool_point(q, em)) / (2 * FD_STEP)
        assert np.abs(J[:, :, k] - fd).max() < FD_TOL, chain.param_names[k]
    Jq = chain.joint_jacobian(q, e0, orientation=True)
    R0 = chain.fk(q, e0)[:, :3, :3]
    for k in range(chain.n_joints):
        qp, qm = q.copy(), q.copy()
        qp[:, k] += FD_JOINT_STEP_DEG
        qm[:, k] -= FD_JOINT_STEP_DEG
        fd = (chain.tool_point(qp, e0) - chain.tool_point(qm, e0)) / (2 * FD_JOINT_STEP_DEG)
        assert np.abs(Jq[:, :3, k] - fd).max() < FD_JOINT_TOL
        dR = (chain.fk(qp, e0)[:, :3, :3] - chain.fk(qm, e0)[:, :3, :3]) / (2 * FD_JOINT_STEP_DEG)
        W = dR @ np.swapaxes(R0, 1, 2)  # skew(ω)
        w = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], 1)
        assert np.abs(Jq[:, 3:, k] - w).max() < FD_JOINT_TOL / 100


def test_names_are_derived_from_the_chain():
    c = load_machine("ur5")
    assert c.param_names[:6] == ("base.x_mm", "base.y_mm", "base.z_mm", "base.rz_rad", "base.ry_rad", "base.rx_rad")
    assert c.param_names[-3:] == ("tool.x_mm", "tool.y_mm", "tool.z_mm")
    # Hayati β exactly on the links whose consecutive axes are parallel (α = 0: links 2, 3, 6)
    assert [n for n in c.param_names if "beta" in n] == ["link2.beta_rad", "link3.beta_rad", "link6.beta_rad"]
    assert c.joint_columns == [f"q{i}_deg" for i in range(1, 7)]


def test_mdh_and_et_conventions_give_the_same_arm():
    """A two-link planar arm written three ways has the same tool point."""
    links = [{"joint": "q1", "dh": [300.0, 0.0, 0.0, 0.0], "limits": [-180.0, 180.0]},
             {"joint": "q2", "dh": [200.0, 0.0, 0.0, 0.0], "limits": [-180.0, 180.0]}]
    dh = parse_serial({"machine": {"kind": "serial", "convention": "dh"}, "link": links, "tool": {"xyz_mm": [0, 0, 0]}}, "x")
    mdh_links = [{"joint": "q1", "dh": [0.0, 0.0, 0.0, 0.0], "limits": [-180.0, 180.0]},
                 {"joint": "q2", "dh": [300.0, 0.0, 0.0, 0.0], "limits": [-180.0, 180.0]}]
    mdh = parse_serial({"machine": {"kind": "serial", "convention": "mdh"}, "link": mdh_links,
                        "tool": {"xyz_mm": [200, 0, 0]}}, "x")
    ets = [{"type": "rz", "joint": "q1", "limits": [-180.0, 180.0]}, {"type": "tx", "value": 300.0},
           {"type": "rz", "joint": "q2", "limits": [-180.0, 180.0]}, {"type": "tx", "value": 200.0}]
    etc = parse_serial({"machine": {"kind": "serial", "convention": "et"}, "et": ets, "tool": {"xyz_mm": [0, 0, 0]}}, "x")
    q = np.array([[30.0, -45.0], [120.0, 10.0]])
    want = np.array([[300 * np.cos(np.radians(a)) + 200 * np.cos(np.radians(a + b)),
                      300 * np.sin(np.radians(a)) + 200 * np.sin(np.radians(a + b)), 0.0] for a, b in q])
    for c in (dh, mdh, etc):
        assert np.allclose(c.tool_point(q), want, atol=1e-9)


def _ur5_doc():
    import tomllib
    return tomllib.loads((Path(load_machine("ur5").path)).read_text())


def _assert_refused(doc, edit, words):
    """``edit(doc)`` makes the file bad: one line naming the file and every word of ``words``."""
    edit(doc)
    with pytest.raises(MachineFileError) as ei:
        parse_serial(doc, "bad.toml")
    msg = str(ei.value)
    assert msg.startswith("bad.toml: ") and "\n" not in msg
    for w in words:
        assert w in msg, msg


@pytest.mark.parametrize("edit,words", [
    (lambda d: d["link"][1].update(dh=[-425.0, 0.0, 0.0]), ["link[1].dh", "4 columns"]),
    (lambda d: d["link"][2].update(limits=[10.0, 10.0]), ["link[2].limits", "inverted"]),
    (lambda d: d["link"][2].update(limits=[-3.1, 3.1]), ["link[2].limits", "radians"]),
    (lambda d: d["link"][0].update(dh=[0.0, 1.5708, 89.159, 0.0]), ["link[0].dh", "radians"]),
    (lambda d: d.update(base={"rotation": [[1, 0, 0], [0, 1, 0.1], [0, 0, 1]]}), ["base.rotation", "orthonormal"]),
    (lambda d: d["link"][3].update(type="spherical"), ["link[3].type"]),
    (lambda d: d["link"][4].update(joint="q1"), ["link[4].joint", "duplicate"]),
    (lambda d: d["machine"].update(schema=2), ["machine.schema"]),
])
def test_bad_machine_files_name_table_and_key(edit, words):
    _assert_refused(_ur5_doc(), edit, words)


def _builtin_doc(name):
    import tomllib
    return tomllib.loads((Path(load_machine(name).path)).read_text())


def _swap_a_alpha(d):
    """Every row typed [alpha, a, d, theta]: the a and alpha columns exchanged."""
    for link in d["link"]:
        link["dh"][0], link["dh"][1] = link["dh"][1], link["dh"][0]


def _in_metres(d):
    for link in d["link"]:
        link["dh"][0] /= 1000
        link["dh"][2] /= 1000
    d["tool"]["xyz_mm"] = [v / 1000 for v in d["tool"]["xyz_mm"]]


@pytest.mark.parametrize("name,edit,words", [
    # the WAM's α column (±90) typed in the a column: a = -90, 90, -90, … (its a column holds ±45 mm)
    ("wam", _swap_a_alpha, ["link[0].dh", "a_mm", "right angle", "degrees where lengths in mm"]),
    # the UR5's a column (-425 mm) typed in the α column: an angle beyond ±360°
    ("ur5", _swap_a_alpha, ["link[1].dh", "alpha_deg", "-425", "a length in mm where an angle"]),
    ("ur5", lambda d: d["tool"].update(xyz_mm=[0.0, 0.00009, 0.031]), ["tool.xyz_mm", "metres rather than mm"]),
    ("ur5", _in_metres, ["link[1].dh", "a_mm", "adds up to", "metres rather than mm"]),
    # the d column holding 90° wherever the UR5 has an offset
    ("ur5", lambda d: [lk.update(dh=[lk["dh"][0], lk["dh"][1], 90.0 if lk["dh"][2] else 0.0, lk["dh"][3]])
                       for lk in d["link"]], ["link[0].dh", "d_mm", "right angle"]),
])
def test_lengths_in_degrees_or_metres_refused(name, edit, words):
    """Units by content: degrees in a length column, an angle column holding a length, a file or a tool point in
    metres. One line naming file, table and key."""
    _assert_refused(_builtin_doc(name), edit, words)


def test_plausible_lengths_are_not_refused():
    """One 90 mm and one 180 mm link in different columns (real arms have such lengths), a tool at the flange
    ([0, 0, 0]) and a sub-mm tool offset on a short chain are lengths, not degrees or metres."""
    links = [{"joint": "q1", "dh": [90.0, 90.0, 180.0, 0.0], "limits": [-170.0, 170.0]},
             {"joint": "q2", "dh": [300.0, 0.0, 0.0, 0.0], "limits": [-170.0, 170.0]}]
    for tool in ([0.0, 0.0, 0.0], [0.0, 0.0, 0.8]):
        c = parse_serial({"machine": {"kind": "serial", "convention": "dh"}, "link": links, "tool": {"xyz_mm": tool}}, "x")
        assert c.n_joints == 2


def test_error_slot_on_fixed_transform_refused():
    d = {"machine": {"kind": "serial", "convention": "et"}, "tool": {"xyz_mm": [0, 0, 0]},
         "et": [{"type": "rz", "joint": "q1", "limits": [-180.0, 180.0]}, {"type": "tx", "value": 3.0, "error": "da"}]}
    with pytest.raises(MachineFileError, match=r"et\[1\]\.error.*fixed transform"):
        parse_serial(d, "bad.toml")


def test_machine_by_name_and_cli_exit_2(tmp_path):
    import subprocess
    import sys
    bad = tmp_path / "arm.toml"
    bad.write_text(Path(load_machine("ur5").path).read_text().replace("dh = [-425.0, 0.0, 0.0, 0.0]",
                                                                      "dh = [-425.0, 0.0, 0.0]"))
    r = subprocess.run([sys.executable, "-m", "compensation.app.cli", "calibrate", "x.csv", "--machine", str(bad),
                        "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2 and "link[1].dh" in r.stderr and len(r.stderr.strip().splitlines()) == 1
