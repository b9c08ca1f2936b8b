"""Identifying a grinder file's 23 error elements from tracker sweeps (``volcomp identify``), with uncertainty.

:func:`identify_elements` runs :func:`errormap.uncertainty.smooth_identify` (the one identification of every
machine tool, on the grinder file's chain) and writes the grinder's element set, its covariance
(``E.cov.npz``, the chain's, :func:`errormap.chain_covariance.save_chain_covariance`) and the identification
report (JSON).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from errormap.io import companion_path, write_json
from errormap.iso230 import ISO_NAME
from errormap.sweeps import read_sweeps


@dataclass
class Identification:
    """The smoothed identification ``smooth`` (its ``raw`` result carries the elements) and the
    files written."""

    smooth: object
    elements_path: Path
    covariance_path: Path
    report_path: Path

    @property
    def result(self):
        return self.smooth.raw

    def summary_lines(self) -> list:
        return self.smooth.raw.summary_lines() + self.smooth.summary_lines()


def identify_elements(machine, sweep_files, out, report=None, noise_um=None, n_boot: int | None = None, seed: int = 0,
                      smooth: bool = True, gauge: str = "station-mean", sweeps=None) -> Identification:
    """Identify from ``sweep_files`` and write ``out`` (element set), its covariance and ``report``
    (default ``OUT.report.json``). ``sweeps``: the files already read (else read here)."""
    from errormap.chain_covariance import covariance_path, save_chain_covariance
    from errormap.uncertainty import smooth_identify
    sweeps = read_sweeps(sweep_files, machine) if sweeps is None else sweeps
    sm = smooth_identify(sweeps, machine, noise_um=noise_um, n_boot=n_boot, seed=seed, smooth=smooth, gauge=gauge)
    res = sm.raw
    res.elements_ = sm.elements_
    report = Path(report) if report else companion_path(out, ".report.json")
    info = res.to_dict()
    info["iso230_names"] = dict(ISO_NAME)
    cov_path = covariance_path(out)
    info.update({"sweeps": [str(s) for s in sweep_files], "machine_file": machine.path,
                 "machine_sha256": machine.sha256, "elements_file": str(out),
                 "uncertainty": sm.report_dict(), "covariance_file": str(cov_path)})
    save_chain_covariance(sm.result, cov_path)
    write_json(report, info)
    el_path = res.elements_.save(out)
    return Identification(sm, el_path, cov_path, report)
