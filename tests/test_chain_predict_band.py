"""``volcomp predict --band`` on machine-tool chains: the identification's covariance (``E.cov.npz`` of
``identify --machine``) through the chain's parameter Jacobian, J Σ Jᵀ per point."""
from __future__ import annotations

import numpy as np

from compensation.app.cli import main
from errormap.io import read_table, write_csv
from errormap.machine import load_machine
from errormap.identification import COV_FORMAT
from errormap.chain_truth import make_chain_truth

FD_STEP = 1e-3
"""Central-difference step on each element parameter (μm or μrad): the tool-point error is linear in the
parameters up to products of μrad-sized angles (relative 1e-10), far below the comparison tolerance."""
FD_REL_TOL = 1e-5
"""Band from the finite-difference Jacobian vs the command's (written with 9 significant digits): 1e-5 relative."""
# The band's coverage of the hidden truth through the user's path (8 seeds of mill-xyz) is a sweep over seeds:
# mt_band_coverage in benchmarks/suite/statistical.py, its first seed in the suite's quick run.


def _random_covariance(n, seed):
    """An SPD (n, n) covariance with standard deviations 0.5–3 (μm / μrad) and random correlations."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n)) / np.sqrt(n)
    d = rng.uniform(0.5, 3.0, n)
    C = A @ A.T + 0.1 * np.eye(n)
    s = np.sqrt(np.diagonal(C))
    return C / np.outer(s, s) * np.outer(d, d)


def _parameters(machine, el):
    slots, stations = [], []
    for s in machine.slots:
        if s.is_function:
            a = next(a for a in machine.axes if a.word == s.axis)
            n = len(el.stations[a.column])
            slots += [s.name] * n
            stations += list(range(n))
        else:
            slots.append(s.name)
            stations.append(-1)
    return slots, np.array(stations)


def _save_cov(path, slots, stations, C):
    with open(path, "wb") as fh:
        np.savez(fh, format=np.array(COV_FORMAT), slot=np.array(slots), station=stations, cov=C)


def _points_csv(path, machine, el, n, seed):
    from compensation.export import volume_points as check_points
    q = check_points(el, n, seed)
    write_csv(path, {a.column: q[:, j] for j, a in enumerate(machine.axes)})
    return q


def test_band_is_the_finite_difference_jacobian_through_the_covariance(tmp_path):
    """Independent of the parameter Jacobian's code: central differences of the tool-point error over every
    element parameter (nominal-free: the element set's own spatial error), Σ of random correlations."""
    from errormap.diagnosis.chain_loop import apply_parameters
    m = load_machine("mill-xyz")
    el = make_chain_truth(m, 3).elements
    slots, stations = _parameters(m, el)
    rng = np.random.default_rng(4)   # Σ over a subset (every constant, 2 stations of every slot) keeps it fast
    sub = np.sort(np.concatenate([np.flatnonzero(stations < 0)] + [
        rng.choice(np.flatnonzero(np.array(slots) == s.name), 2, replace=False) for s in m.slots if s.is_function]))
    C = np.zeros((len(slots), len(slots)))
    C[np.ix_(sub, sub)] = _random_covariance(len(sub), 1)
    el.save(tmp_path / "E.json")
    _save_cov(tmp_path / "E.cov.npz", slots, stations, C)
    q = _points_csv(tmp_path / "p.csv", m, el, 40, 2)
    assert main(["predict", "--machine", "mill-xyz", "--model", str(tmp_path / "E.json"), str(tmp_path / "p.csv"),
                 "--band", "1sigma", "--out", str(tmp_path / "pred.csv")]) == 0
    t = read_table(tmp_path / "pred.csv")
    got = np.stack([t.float(f"{c}_band1sigma_um") for c in ("dx", "dy", "dz")], axis=1)
    J = np.zeros((len(q), 3, len(slots)))
    for j in sub:
        d = np.zeros(len(slots))
        d[j] = FD_STEP
        hi, lo = (apply_parameters(el, slots, stations, s * d) for s in (1, -1))
        J[:, :, j] = (m.spatial_error(q, hi.values(q)) - m.spatial_error(q, lo.values(q))) / (2 * FD_STEP)
    want = np.sqrt(np.einsum("nij,jk,nik->ni", J, C, J))
    assert np.max(np.abs(got - want) / want) <= FD_REL_TOL


def test_refusals_are_one_line(tmp_path, capsys):
    m = load_machine("mill-xyz")
    el = make_chain_truth(m, 0).elements
    el.save(tmp_path / "E.json")
    _points_csv(tmp_path / "p.csv", m, el, 5, 0)
    base = ["predict", "--machine", "mill-xyz", str(tmp_path / "p.csv"), "--band", "95"]

    def refused(model, word):
        assert main([*base, "--model", str(model), "--out", str(tmp_path / "o.csv")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and word in err[0], err
        assert not (tmp_path / "o.csv").exists()
    refused(tmp_path / "E.json", "E.cov.npz")                                   # no covariance beside it
    slots, stations = _parameters(m, el)
    _save_cov(tmp_path / "E.cov.npz", slots, stations + 5, np.eye(len(slots)))   # another identification's stations
    refused(tmp_path / "E.json", "key 'station'")
    _save_cov(tmp_path / "E.cov.npz", ["dx_q"] + slots[1:], stations, np.eye(len(slots)))
    refused(tmp_path / "E.json", "key 'slot'")
