"""The page of a machine-tool chain's diagnose run (``volcomp report RUN`` on a ``diagnose --machine`` folder).

Read from the run folder (``diagnosis.json``, ``model.json``, ``updated_elements.json``) and the identified
element set it names: the closed loop's stages (held-out MEASURED residual beside the fitting one and the plain
baselines), the held-out residual against the noise floor, the effects named and rejected, and per axis the
component elements of the chain's own slots (identified and updated, over the stations) with its constant slots.
Nothing is recomputed: the page shows what the diagnosis measured.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.io import InputError, read_json_object

from .learned import learned_summary
from .figures import pyplot
from .toolkit import Figure, Table, figure, kv_table, render_page, write_page

FIG_DPI = 90
ELEMENT_COLUMNS = 3
"""Subplots per row of an axis' element figure (a linear axis has six component slots: two rows)."""
DIAGNOSIS_KEYS = ("stages", "kept_stage", "kept_why", "effects", "n_fit", "n_held_out", "held_out_rms_um")
"""Keys a chain diagnose run's ``diagnosis.json`` has (the folder is recognised by them and ``model.json``'s format)."""
STAGE_NOTE = {"identified": "the sweeps' element set", "updated": "Gaussian update of the elements from the checks",
              "baseline_ols_update": "baseline: unregularised least-squares update",
              "baseline_ols_linear": "baseline: OLS on the axes", "updated_plus_effects": "update + named effects",
              "learned_residual": "learned residual of the axes on what the loop leaves (kept only if it beats the "
                                  "loop on the held-out checks)"}


def check_chain_diagnosis(doc: dict, path) -> None:
    """Refuse a ``diagnosis.json`` that is not a chain diagnose run's, naming the first missing key."""
    for k in DIAGNOSIS_KEYS:
        if k not in doc:
            raise InputError(f"{path}: key {k!r} missing: not the diagnosis.json of volcomp diagnose")
    if not isinstance(doc["stages"], dict) or doc["kept_stage"] not in doc["stages"]:
        raise InputError(f"{path}: key 'kept_stage': {doc['kept_stage']!r} is not one of its stages")


# -- figures ----------------------------------------------------------------------------------------
def _stage_figure(doc) -> Figure:
    plt = pyplot()
    names = [k for k, v in doc["stages"].items() if "held_out" in v]
    held = [doc["stages"][k]["held_out"]["rms_um"] for k in names]
    fit = [doc["stages"][k]["fitting"]["rms_um"] for k in names]
    fig, ax = plt.subplots(figsize=(9, 3.6))
    y = np.arange(len(names))
    ax.barh(y + 0.2, held, 0.4, label="held-out (measured)", color="tab:blue")
    ax.barh(y - 0.2, fit, 0.4, label="fitting", color="tab:gray", alpha=0.6)
    floor = doc.get("noise_floor_um")
    if floor is not None:
        ax.axvline(floor, color="tab:red", ls="--", lw=1.2, label=f"noise floor {floor:.3g} μm")
    ax.set_yticks(y, [n + (" (kept)" if n == doc["kept_stage"] else "") for n in names])
    ax.set_xscale("log")
    ax.set_xlabel("RMS of |measured − predicted| (μm, log scale)")
    ax.grid(True, axis="x", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    return figure(fig, "stages", "Held-out and fitting MEASURED residual per stage of the loop against the noise "
                  "floor (what the check noise alone would leave).", FIG_DPI, tight_layout=True)


def _element_figures(machine, updated, identified) -> list[Figure]:
    plt = pyplot()
    out = []
    for a in machine.axes:
        slots = [s for s in machine.slots if s.is_function and s.axis == a.word]
        if not slots:
            continue
        ncol = min(ELEMENT_COLUMNS, len(slots))
        nrow = -(-len(slots) // ncol)
        fig, axs = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 2.6 * nrow), squeeze=False)
        for ax in axs.flat[len(slots):]:
            ax.set_visible(False)
        for ax, s in zip(axs.flat, slots):
            st = updated.stations[a.column]
            if identified is not None:
                ax.plot(identified.stations[a.column], identified.functions[s.name], "-", lw=1, color="tab:gray",
                        label="identified")
            ax.plot(st, updated.functions[s.name], ".-", lw=1, ms=3, color="tab:blue", label="updated")
            ax.set_title(f"{s.name} ({s.iso})", fontsize=9)
            ax.set_xlabel(f"{a.word} ({a.column.rsplit('_', 1)[-1]})", fontsize=8)
            ax.set_ylabel("μm" if s.unit == "um" else "μrad", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(True, alpha=0.3)
        axs[0, 0].legend(fontsize=7)
        out.append(figure(fig, f"elements of axis {a.word}",
                          f"Component elements of axis {a.word} (the chain's slots, ISO 230 names): the sweeps' "
                          "identification and the loop's update over the stations.", FIG_DPI, tight_layout=True))
    return out


# -- page -------------------------------------------------------------------------------------------
def _stage_table(doc) -> Table:
    rows, classes = [], []
    for k, v in doc["stages"].items():
        if "held_out" not in v:
            rows.append([k, None, None, None, None, None, None, None, str(v.get("failed", "not run"))])
        else:
            h, f = v["held_out"], v["fitting"]
            rows.append([k, h["rms_um"], h["max_um"], h["p95_um"], h["dx_um"]["rms_um"], h["dy_um"]["rms_um"],
                         h["dz_um"]["rms_um"], f["rms_um"], STAGE_NOTE.get(k, "")])
        classes.append("kept" if k == doc["kept_stage"] else "")
    return Table(["stage", "held-out RMS (μm)", "held-out max (μm)", "held-out p95 (μm)", "dx RMS (μm)",
                  "dy RMS (μm)", "dz RMS (μm)", "fitting RMS (μm)", "what"], rows, row_classes=classes)


def _effect_tables(doc, machine) -> tuple:
    iso = dict(zip(machine.slot_names, machine.iso_names))
    acc = Table(["kind", "axis", "element", "coefficients (the element's unit)", "held-out gain z"],
                [[e["kind"], e["axis"], f"{e['element']} ({iso.get(e['element'], '?')})",
                  ", ".join(f"{c:.4g}" for c in e.get("coefficients", [])), e.get("held_out_gain_z")]
                 for e in doc["effects"]])
    rej = Table(["kind", "axis", "held-out gain z"],
                [[e.get("kind"), e.get("axis"), e.get("held_out_gain_z")] for e in doc.get("effects_rejected", [])])
    return acc, rej


def _constants_table(machine, updated, identified) -> Table:
    rows = []
    for s in machine.slots:
        if s.is_function:
            continue
        u = updated.constants.get(s.name)
        i = identified.constants.get(s.name) if identified is not None else None
        rows.append([s.name, s.iso, "μm" if s.unit == "um" else "μrad", i, u, None if i is None else u - i])
    return Table(["slot", "ISO 230", "unit", "identified", "updated", "change"], rows, left=3)


def _verdict(v) -> str:
    """The run's verdict in words (``diagnosis.json`` ``verdict``; none in a run written before verdicts)."""
    if v is None:
        return "not recorded"
    return "passed" if v["status"] == "passed" else "FAILED: " + "; ".join(v["reasons"])


def chain_diagnosis_page(run_dir, machine) -> str:
    """The page of the diagnose run in ``run_dir`` (module doc) on ``machine``; InputError naming the file and
    key when the folder is not such a run. ``machine``: a chain, or a grinder file (its chain)."""
    from errormap.diagnosis.loop_model import load_chain_model_file
    from errormap.chain_elements import ChainElementSet
    run_dir = Path(run_dir)
    doc = read_json_object(run_dir / "diagnosis.json", "diagnosis of volcomp diagnose")
    check_chain_diagnosis(doc, run_dir / "diagnosis.json")
    model = load_chain_model_file(run_dir / "model.json", machine, learned="ignore")   # its elements only
    updated = model.elements
    ident_path = Path(str(doc.get("model") or ""))
    identified, ident_note = None, f"the identified set ({ident_path}) is not readable: the updated set alone"
    if ident_path.is_file():
        try:
            identified, ident_note = ChainElementSet.load(ident_path, machine), str(ident_path)
        except InputError as exc:
            ident_note = f"the identified set is not shown ({exc})"
    acc, rej = _effect_tables(doc, machine)
    floor, ratio = doc.get("noise_floor_um"), doc.get("held_out_over_floor")
    summary = kv_table({
        "machine": f"{machine.name} ({machine.path})", "checks": str(doc.get("checks", "?")),
        "identified model": ident_note, "split": f"{doc.get('split', '?')} ({doc['n_fit']} fit, "
                                                 f"{doc['n_held_out']} held out)",
        "kept stage": f"{doc['kept_stage']} — {doc['kept_why']}",
        "held-out MEASURED RMS of the kept stage (μm)": doc["held_out_rms_um"],
        "noise floor (μm)": floor, "held-out / floor": ratio,
        "check noise σ (μm)": f"{doc.get('noise_sigma_um')} ({doc.get('noise_sigma_source', '?')})",
        "verdict": _verdict(doc.get("verdict")),
        "model handed on": str(run_dir / "model.json")})
    return render_page("chain_diagnose.html", title=f"Closed loop on {machine.name}: diagnosis of the checks",
                       summary=summary, stages=_stage_table(doc), stage_figure=_stage_figure(doc), effects=acc,
                       rejected=rej, element_figures=_element_figures(machine, updated, identified),
                       constants=_constants_table(machine, updated, identified), kept=doc["kept_stage"],
                       ratio=ratio, floor=floor, learned=learned_summary(doc), verdict_failed=verdict_failure(doc))


def verdict_failure(doc) -> str | None:
    """The reasons of a run whose verdict failed (``diagnosis.json`` ``verdict``), joined; None when it passed or
    records none. The page puts them in its banner and ``report RUN`` prints them: a failed run is shown, not
    refused (the page is how its user sees why)."""
    v = doc.get("verdict")
    if not isinstance(v, dict) or v.get("status") != "failed":
        return None
    return "; ".join(str(r) for r in v.get("reasons") or []) or "no reasons recorded"


def write_chain_diagnosis_page(run_dir, machine, out=None) -> Path:
    """Write :func:`chain_diagnosis_page` to ``out`` (default ``run_dir/report.html``), atomically; ``out``'s
    folder is made only once the page is built (a refused run leaves nothing)."""
    page = chain_diagnosis_page(run_dir, machine)
    out = Path(out) if out is not None else Path(run_dir) / "report.html"
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_page(out, page)
