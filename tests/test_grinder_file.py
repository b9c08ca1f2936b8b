"""A ``kind = "grinder"`` file read as its machine-tool chain (errormap/grinder_file.py): the older
built-in grinder file read through the adapter equals the built-in grinder (a chain file, also named
grinder-chain); a user's grinder file with other geometry, strokes and
targets equals the hand-written HTM chains (tests/test_htm_reference.py); a grinder element-set file
loads into the adapted chain and predicts the same field; names and columns are the grinder's."""
import tomllib
from pathlib import Path

import numpy as np
import pytest

from errormap.elements import ELEMENT_NAMES
from errormap.grinder_file import (ELEMENT_SLOTS, GRINDER_STROKE_KEYS, adapter_line, grinder_chain_document,
                                   parse_grinder_file, read_grinder)
from errormap.chain_field import ChainField
from errormap.machine import MachineFileError, load_machine
from errormap.chain_elements import ChainElementSet
from tests.test_htm_reference import (random_axes, random_elements, reference_error_jacobian,
                                      reference_field_and_jacobian, reference_tool_point)


def _on(machine, el):
    """The element set ``el``'s values on ``machine`` (another chain with the grinder's 23 slots)."""
    return ChainElementSet(machine, el.stations, el.functions, el.constants)


TOL_UM = 1e-9
"""The issue's bound: two exact evaluations of the same transforms, tool points of ~0.5 m (one ulp
of 500 mm is 5.7e-11 μm); observed 2.8e-10 μm on the grinder with ±60 μm / μrad elements."""
TOL_JAC = 1e-9
"""Axis Jacobians (μm per mm / per deg, entries up to ~2e2): round-off of two exact forms (the
reference's complex step has no truncation error; observed ~4e-12)."""
TOL_EJAC = 1e-12
"""Error-transfer Jacobian, O(1) μm per μm and O(1e-3·lever mm) μm per μrad: round-off (observed 1e-16)."""
TOL_KIN_MM = 1e-10
"""Nominal tool points in mm (~500 mm): a few ulps (observed 9e-14 mm)."""
OLD_GRINDER = Path(__file__).parent / "data" / "machines" / "grinder_kind_grinder.toml"
"""The built-in grinder's file as it was before it became a chain file (``kind = "grinder"``)."""
N_POINTS = 3_000
"""Seeded random points per check (multi-turn A); the complex-step reference keeps (n, 4, 4) complex."""

USER_EDITS = (("l1 = 420.0", "l1 = 455.5"), ("l2 = 160.0", "l2 = 171.25"), ("l4 = -95.0", "l4 = -88.0"),
              ("l7 = 40.0", "l7 = 52.25"), ("l8 = 119.9", "l8 = 101.0"), ("theta1_deg = 30.0", "theta1_deg = 12.5"),
              ("R = 25.0", "R = 31.0"), ("x_mm = [0.0, 200.0]", "x_mm = [-20.0, 150.0]"),
              ("z_mm = [0.0, 60.0]", "z_mm = [5.0, 95.0]"), ("a_deg = [0.0, 360.0]", "a_deg = [-90.0, 270.0]"),
              ("X = [[0.0, -60.0, 40.0]", "X = [[5.0, -66.0, 41.5]"), ("A = [[10.0, 45.0, 0.0]", "A = [[12.0, 47.0, 3.0]"))


@pytest.fixture(scope="module")
def user_grinder_text():
    text = OLD_GRINDER.read_text(encoding="utf-8")
    for old, new in USER_EDITS:
        assert old in text, old
        text = text.replace(old, new)
    return text


@pytest.fixture(scope="module")
def user_grinder(tmp_path_factory, user_grinder_text):
    p = tmp_path_factory.mktemp("grinder") / "my-grinder.toml"
    p.write_text(user_grinder_text, encoding="utf-8")
    return load_machine(p)


def test_old_grinder_file_adapts_to_the_builtin_grinder():
    mt, ref = load_machine(OLD_GRINDER), load_machine()
    assert load_machine("grinder-chain").path == ref.path and ref.kind == "machine-tool" and not ref.read_as
    assert mt.name == ref.name and mt.path == str(OLD_GRINDER) and mt.read_as == adapter_line(OLD_GRINDER)
    g = mt
    assert mt.work_ets == ref.work_ets and mt.tool_ets == ref.tool_ets and mt.slots == ref.slots
    assert mt.axes == ref.axes and mt.geometry == ref.geometry and mt.body_index == ref.body_index
    for w in ("X", "Z", "A"):
        np.testing.assert_array_equal(mt.targets[w], ref.targets[w])
    ax = random_axes(g, N_POINTS, 101)
    assert np.abs(mt.nominal(ax) - ref.nominal(ax)).max() < TOL_KIN_MM
    assert np.abs(mt.error_jacobian(ax) - ref.error_jacobian(ax)).max() < TOL_EJAC
    el = random_elements(g, 102)
    f_mt = ChainField(mt, _on(mt, el))
    f_ref = ChainField(ref, _on(ref, el))
    E0, J0 = f_ref.predict_and_jacobian(ax)
    E1, J1 = f_mt.predict_and_jacobian(ax)
    assert np.abs(E0).max() > 100.0  # a real field, not zeros
    assert np.abs(E1 - E0).max() < TOL_UM and np.abs(J1 - J0).max() < TOL_JAC
    assert np.abs(f_mt.error_jacobian(ax) - f_ref.error_jacobian(ax)).max() < TOL_EJAC


def test_user_grinder_file_equals_the_hand_written_chains(user_grinder, user_grinder_text):
    g = mt = user_grinder
    assert mt.strokes == {"x_mm": (-20.0, 150.0), "z_mm": (5.0, 95.0), "a_deg": (-90.0, 270.0)}
    assert mt.geometry["theta1_deg"] == 12.5 and mt.sha256 and mt.kind == "machine-tool"
    np.testing.assert_array_equal(mt.targets["X"][0], [5.0, -66.0, 41.5])
    # the parsed TOML document gives the same chain as the loaded file
    same = parse_grinder_file(tomllib.loads(user_grinder_text), g.path, g.sha256)
    assert same.work_ets == mt.work_ets and same.tool_ets == mt.tool_ets
    el = random_elements(g, 111)   # stations over the user's strokes
    ax = random_axes(g, N_POINTS, 112)
    zero = np.zeros((len(ax), len(ELEMENT_NAMES)))
    assert np.abs(mt.nominal(ax) - reference_tool_point(g, ax, zero)).max() < TOL_KIN_MM
    assert np.abs(mt.error_jacobian(ax[:1000]) - reference_error_jacobian(g, ax[:1000])).max() < TOL_EJAC
    E0, J0 = reference_field_and_jacobian(g, el, ax)
    E1, J1 = ChainField(mt, _on(mt, el)).predict_and_jacobian(ax)
    assert np.abs(E0).max() > 100.0
    assert np.abs(E1 - E0).max() < TOL_UM and np.abs(J1 - J0).max() < TOL_JAC
    # the default grinder's chain is another machine at these points (the edits took effect)
    assert np.abs(load_machine().nominal(ax) - mt.nominal(ax)).max() > 1.0


def test_grinder_element_file_loads_into_the_adapted_chain(user_grinder, tmp_path):
    g = mt = user_grinder
    el = random_elements(g, 121)
    path = el.save(tmp_path / "elements.json")
    ce = ChainElementSet.load(path, mt)
    ax = random_axes(g, N_POINTS, 122)
    np.testing.assert_array_equal(ce.values(ax), el.values(ax))
    E_chain = ChainField(mt, ce).predict(ax)
    assert np.abs(E_chain - reference_field_and_jacobian(g, el, ax)[0]).max() < TOL_UM
    # and back: the chain's element file is the grinder's, byte for byte
    back = ce.save(tmp_path / "back.json")
    assert back.read_bytes() == path.read_bytes()
    np.testing.assert_array_equal(ChainElementSet.load(back, g).values(ax), el.values(ax))


def test_names_and_columns_are_the_grinders(user_grinder):
    mt = user_grinder
    assert tuple(g for g, _ in ELEMENT_SLOTS) == ELEMENT_NAMES
    assert mt.slot_names == ELEMENT_NAMES and mt.iso_names == tuple(iso for _, iso in ELEMENT_SLOTS)
    assert mt.axis_columns == GRINDER_STROKE_KEYS == ("x_mm", "z_mm", "a_deg")
    assert mt.function_slots == ELEMENT_NAMES[:18] and mt.constant_slots == ELEMENT_NAMES[18:]
    d = ChainElementSet.zeros(mt).to_dict()
    assert list(d["stations"]) == ["x_mm", "z_mm", "a_deg"] and tuple(d["units"]) == ELEMENT_NAMES
    line = user_grinder.read_as
    assert "\n" not in line and user_grinder.path in line and 'kind = "grinder"' in line


def test_unmapped_names_and_other_kinds_are_refused(user_grinder):
    g = mt = user_grinder
    el = random_elements(g, 131)
    with pytest.raises(ValueError, match=r"got unknown \['dx_y'\]"):   # one name outside the grinder's 23
        ChainElementSet(mt, el.stations, {**el.functions, "dx_y": el.functions["dx_x"]}, el.constants)
    mill = load_machine("mill-xyz")
    with pytest.raises(ValueError, match="Expected stations for y_mm"):
        ChainElementSet(mill, el.stations, el.functions, el.constants)
    doc = tomllib.loads(Path(load_machine("grinder-chain").path).read_text(encoding="utf-8"))
    with pytest.raises(MachineFileError, match="expected 'grinder' here, got 'machine-tool'"):
        parse_grinder_file(doc, "chain.toml")
    bad = tomllib.loads(Path(g.path).read_text(encoding="utf-8"))
    doc = grinder_chain_document(read_grinder(bad, g.path))
    del bad["geometry"]["l8"]
    with pytest.raises(MachineFileError, match="my-grinder.toml.*geometry.l8"):
        parse_grinder_file(bad, g.path)
    assert doc["geometry"]["l8"] == g.geometry["l8"] == 101.0
    with pytest.raises(MachineFileError, match="expected the grinder's chain here"):
        load_machine("mill-xyz", expect_kind="grinder")


def test_models_of_the_former_builtin_file_are_the_builtin_grinders(tmp_path):
    """An element set recorded with the built-in grinder's earlier file (kind = "grinder", before it became its
    chain file) is the built-in grinder's; another machine's, or an unknown file's, is refused by name."""
    from compensation.export.sources import load_elements
    from errormap.io import InputError
    from errormap.machine import FORMER_SHA256, made_on
    g, former = load_machine(), FORMER_SHA256["grinder"][0]
    assert made_on(g, g.sha256) and made_on(g, former) and not made_on(load_machine("mill-xyz"), former)
    el = random_elements(g, 141)
    el.machine_sha256 = former
    ax = random_axes(g, 50, 142)
    np.testing.assert_array_equal(load_elements(el.save(tmp_path / "old.json"), g).values(ax), el.values(ax))
    el.machine_sha256 = "0" * 64
    with pytest.raises(InputError, match="machine_sha256"):
        load_elements(el.save(tmp_path / "other.json"), g)
