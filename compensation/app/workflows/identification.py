"""Identifying a machine tool's error elements from tracker sweep files (``volcomp identify``, the fleet's identify
step, the chain benchmark): one path for every machine tool, a ``kind = "grinder"`` file through its chain.

:func:`identify_chain_files` fits :class:`errormap.estimators.Identification` and writes the element set, its
covariance (``OUT.cov.npz``, :func:`errormap.chain_covariance.save_chain_covariance`) and the identification report
(JSON: the result's residuals and conditioning, the ``uncertainty`` block of :mod:`errormap.uncertainty`, the ISO
230-1 names of the machine file's slots).
"""
from __future__ import annotations

from pathlib import Path

from errormap.io import companion_path, write_json


def identify_chain_files(machine, sweep_files, out, report=None, noise_um=None, n_boot: int | None = None,
                         seed: int = 0, gauge: str = "station-mean", smooth: bool = True, sweeps=None) -> tuple:
    """Identify from the sweep file(s) of one tracker set-up in ``gauge``; write the element set (smoothed by
    :func:`errormap.identification.smooth_chain` unless ``smooth=False``), ``OUT.cov.npz`` (Gauss–Newton's
    σ̂²·(JᵀJ)⁻¹, σ̂ the known tracker σ ``noise_um`` when given, or with ``n_boot`` the residual bootstrap's,
    :func:`errormap.identification.bootstrap_covariance`; through the smoother when smoothed) and ``report``
    (default ``OUT.report.json``). ``sweeps``: the files already read (else read here).
    → ``(result, elements path, covariance path, report path)``."""
    from errormap.chain_covariance import save_chain_covariance
    from errormap.estimators import Identification
    from errormap.sweeps import read_sweeps
    from errormap.uncertainty import uncertainty_report
    sweeps = read_sweeps(sweep_files, machine) if sweeps is None else sweeps
    res = Identification(machine, noise_um=noise_um, gauge=gauge, smooth=smooth, n_boot=n_boot,
                         seed=seed).fit(sweeps).result_
    cov_path = save_chain_covariance(res, companion_path(out, ".cov.npz"))
    report = Path(report) if report else companion_path(out, ".report.json")
    info = res.to_dict()
    info.update({"sweeps": [str(s) for s in sweep_files], "machine": machine.name, "machine_file": machine.path,
                 "machine_sha256": machine.sha256, "elements_file": str(out), "covariance_file": str(cov_path),
                 "iso230_names": dict(zip(machine.slot_names, machine.iso_names)),
                 "uncertainty": uncertainty_report(res)})
    write_json(report, info)
    el_path = res.elements_.save(out)
    return res, el_path, cov_path, report
