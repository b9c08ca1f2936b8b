"""The learned-residual stage on a diagnosis page (:func:`compensation.hybrid.learned_stage`): its CV table,
gate, backfitting and map figure, from ``diagnosis.json``'s ``learned_residual``."""
from __future__ import annotations

import numpy as np

from .figures import pyplot
from .toolkit import Figure, Table, figure

FIG_DPI = 90


FRAME_WORDS = {"work": "learned in the work frame, as measured",
               "machine": "learned in the machine frame (the residual turned by the work frame's nominal rotation, "
                          "and turned back)"}
"""How the report names the learned part's output frame (compensation.hybrid.OUTPUT_FRAMES)."""


def learned_summary(s) -> dict | None:
    """The learned-residual stage (compensation.hybrid): its CV table, gate and map figure."""
    lr = s.get("learned_residual")
    if not lr:
        return None
    rows = [[fam, r["cv_rms"], r["cv_rms_se"], r["gain_mean"], r["gain_se"],
             "" if r.get("coverage_95") is None else r["coverage_95"]] for fam, r in lr["cv_table"].items()]
    out = {"family": lr["family"], "family_name": lr.get("family_name", lr["family"]),
           "compared": ", ".join(lr.get("families_compared", [])), "rule": lr.get("selection_rule"),
           "shipped": (lr.get("shipped") or {}).get("note"),
           "kept": lr["kept"], "why": lr["why"], "inputs": ", ".join(lr["inputs"]),
           "cv": lr["cv"], "z": lr["held_out_gain_z"],
           "cover": lr.get("held_out_band95_cover_total") if lr.get("held_out_band95_cover_total") is not None
           else lr.get("held_out_band95_cover"),
           "cover_what": ("the hybrid's total band: learned ⊕ elements ⊕ measurement noise"
                          if lr.get("held_out_band95_cover_total") is not None else "learned band ⊕ measurement noise"),
           "replaced": ", ".join(f"{e['kind']} {e['axis']}" for e in s.get("effects_replaced_by_learned", [])),
           # the rule that replaced them, as the run recorded it (it changed between rounds: diagnosis.json says which)
           "replaced_rule": (lr.get("condition_terms_vs_static") or {}).get("rule"),
           "table": Table(["family", "CV RMS (μm)", "its SE (μm)", "mean gain over zero (μm²)", "its SE (μm²)",
                           "95 % band coverage"], rows), "figure": None,
           "frame": FRAME_WORDS.get(lr.get("output_frame", "work"), lr.get("output_frame")),
           "frames_table": None, "backfit": None}
    bf = lr.get("backfit")
    if bf:   # backfitted with the element update it sits on (compensation.hybrid.BACKFIT_ROUNDS)
        out["backfit"] = {"rounds": bf["rounds"], "rms": bf["held_out_sequential"]["rms_um"],
                          "z": bf["held_out_gain_z_sequential"],
                          "steps": ", ".join(f"{v:.3g}" for v in bf["step_rms_um"])}
    cands = lr.get("inputs_table") or {}
    if len(cands) > 1:   # more than one (input set, output frame) candidate: each one's chosen family and CV RMS
        out["frames_table"] = Table(
            ["input set", "output frame", "family chosen there", "CV RMS (μm)", "zero's CV RMS (μm)"],
            [[k.split("@")[0], v.get("output_frame", "work"), v["family"], v["cv_rms"], v["cv_rms_zero"]]
             for k, v in cands.items()])
    m = lr.get("map")
    if m:
        out["figure"] = learned_map_figure(m)
    return out


def map_axes(m: dict) -> tuple:
    """The two axis columns a learned map (:func:`compensation.hybrid.learned_map`) spans, in its order: its
    first two ``*_mm`` keys (the machine's first two linear axes: the grinder's x_mm, z_mm; a mill's x_mm,
    y_mm), and the ``<rotary columns>_averaged`` key or None."""
    lin = [k for k in m if k.endswith("_mm")][:2]
    if len(lin) != 2:
        raise ValueError(f"a learned map over two linear axes, got keys {list(m)}")
    return lin[0], lin[1], next((k for k in m if k.endswith("_averaged")), None)


def learned_map_figure(m: dict) -> Figure:
    """The learned correction's map (its norm and its band over the first two linear axes) as a figure; the
    axis names come from the map's keys (:func:`map_axes`)."""
    c1, c2, rot = map_axes(m)
    s1, s2 = c1.rsplit("_", 1)[0], c2.rsplit("_", 1)[0]
    fig, axs = pyplot().subplots(1, 2, figsize=(9, 3.6))
    ext = [m[c1][0], m[c1][-1], m[c2][0], m[c2][-1]]
    band_key, band_title = (("band95_total_um", "the hybrid's total 95 % band (μm)") if "band95_total_um" in m
                            else ("band95_um", "its 95 % band (μm)"))
    for ax, key, title in ((axs[0], "norm_um", "learned correction |Δ| (μm)"), (axs[1], band_key, band_title)):
        im = ax.imshow(np.array(m[key]), origin="lower", extent=ext, aspect="auto", cmap="viridis")
        ax.set_xlabel(f"{s1} (mm)")
        ax.set_ylabel(f"{s2} (mm)")
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax)
    if rot is not None and isinstance(m.get("rotary_deg"), dict) and m["rotary_deg"]:
        # the angles each rotary axis was at (a short stroke clips them: five-axis-ac's A [-120, 30])
        over = "averaged over " + "; ".join(f"{c.rsplit('_', 1)[0].upper()} = {', '.join(f'{a:g}' for a in v)}°"
                                            for c, v in m["rotary_deg"].items())
    elif rot is not None:   # a map written before rotary_deg: the positions asked for
        names = "/".join(c.rsplit("_", 1)[0].upper() for c in rot[:-len("_averaged")].split("+"))
        over = f"averaged over {names} = {', '.join(f'{a:g}' for a in m[rot])}°"
    else:
        over = "any further linear axis at mid-stroke"
    return figure(fig, "learned map", f"The learned correction over {s1.upper()}–{s2.upper()} (vector norm, {over}) "
                  "and the norm of its 95 % band: it is zero, and its band the prior's, where the checks do not reach",
                  dpi=FIG_DPI, tight_layout=True)
