"""JSON and TOML inputs (element sets, model files, machine files, fleet files, covariance companions)
are sized before they are read: past :data:`errormap.io.MAX_DOCUMENT_BYTES` they are refused with one
line naming the file, unread. The over-size files are sparse: they take no disk space and are never read."""
from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from compensation.app.cli import MAX_ERROR_CHARS, main
from errormap.io import MAX_DOCUMENT_BYTES, InputError, read_json

LIMIT_MIB = MAX_DOCUMENT_BYTES >> 20


def _huge(path: Path) -> Path:
    """A sparse file one byte over the limit (no content is ever read from it)."""
    with open(path, "wb") as fh:
        fh.truncate(MAX_DOCUMENT_BYTES + 1)
    return path


def run_cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def refused_naming(rc, err, path):
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert rc == 2 and "Traceback" not in err and len(lines) == 1, (rc, err)
    assert len(lines[0]) <= MAX_ERROR_CHARS and str(path) in lines[0] and f"{LIMIT_MIB} MiB" in lines[0], lines[0]


def test_the_bound_is_far_above_any_real_document():
    """64 MiB: over 600x the largest document volcomp writes (~100 kB) and well under the memory a
    parser needs for it (~10x its size)."""
    assert MAX_DOCUMENT_BYTES == 64 * 2**20


@pytest.fixture
def points(tmp_path):
    p = tmp_path / "pts.csv"
    p.write_text("x_mm,z_mm,a_deg\n10,20,30\n")
    return p


def test_a_huge_model_file_is_refused_unread(tmp_path, points):
    big = _huge(tmp_path / "elements.json")
    rc, _, err = run_cli(["predict", "--model", big, points, "--out", tmp_path / "p.csv"])
    refused_naming(rc, err, big)


def test_a_huge_machine_file_is_refused_unread(tmp_path, points):
    big = _huge(tmp_path / "machine.toml")
    rc, _, err = run_cli(["predict", "--machine", big, "--model", tmp_path / "m.json", points,
                          "--out", tmp_path / "p.csv"])
    refused_naming(rc, err, big)


def test_every_reader_sizes_first(tmp_path):
    """The loaders behind the commands, each given an over-size file: one InputError naming it."""
    from compensation.app.workflows.fleet import read_fleet
    from errormap.diagnosis.drift_models import DriftModel
    from errormap.chain_elements import ChainElementSet
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    from errormap.chain_covariance import read_chain_covariance
    grinder = load_machine("grinder")
    el = make_chain_truth(grinder, 3).elements
    loaders = {"elements.json": lambda p: ChainElementSet.load(p, grinder), "drift.json": DriftModel.load, "fleet.toml": read_fleet,
               "diag.json": read_json, "e.cov.npz": lambda p: read_chain_covariance(p, el)}
    for name, load in loaders.items():
        big = _huge(tmp_path / name)
        with pytest.raises(InputError, match=f"{big.name}: .* exceeds the limit of {LIMIT_MIB} MiB"):
            load(big)


def test_read_json_names_row_and_column(tmp_path):
    p = tmp_path / "d.json"
    p.write_text('{"a": 1,\n "b": }\n')
    with pytest.raises(InputError, match=r"d\.json: row 2: column 7: not JSON"):
        read_json(p)
