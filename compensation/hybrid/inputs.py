"""The learned part's inputs and output frames: the features of a machine's axes (each rotary axis on the
circle), the work-frame input sets, the candidate families and the frames it can learn in (module doc of
:mod:`compensation.hybrid`)."""
from __future__ import annotations

import numpy as np

from errormap.field import GRINDER_AXES, is_rotary_column

LINEAR_SMOOTHERS = ("gp", "gp_matern52", "gp_matern32", "gp_sum", "gp_additive", "basis")
"""The learned families whose fitted mean is a linear smoother of the targets with a Gaussian
marginal (a Gaussian process, or the basis regression's Gaussian coefficients): the ones
:func:`condition_term_test` can use. The deep ensemble is not one."""

TAPER_FRAC = 0.1
"""Outside the checks' box the learned part falls from 1 to 0 over 10 % of each linear axis's
check range (a cubic smoothstep: value and slope continuous)."""

CV_BLOCKS = 10
"""The fitting checks are cut into 10 contiguous seq blocks (time blocks) for the regressor's
blocked cross-validation (5 folds of 2 blocks)."""

MIN_FIT_CHECKS = 50
"""Below 50 fitting checks (10 blocks of 5) a 4-input GP's cross-validation says nothing: not tried."""

MIN_HELD_CHECKS = 10
"""The held-out gate needs a standard error: at least 10 held-out checks."""

MAP_N = 11
"""Points per linear axis of the learned correction's map in diagnosis.json (11 × 11 over X–Z)."""

LEARNED_FAMILIES = ("gp", "ensemble", "gp_matern52", "gp_matern32", "gp_additive", "basis")
"""The learned families the stage cross-validates on the same blocked folds (:mod:`training.residual`,
:mod:`training.basis`); ``gp_sum`` is a candidate the stage can be given (``families``) but not a default. Why
this set: docs/decisions/008-learned-residual-measurements.md."""

CANDIDATE_FAMILIES = ()
"""Families measured beside the default set but not in it: none at present (the measured ones are in
:data:`LEARNED_FAMILIES`)."""


def axis_stem(column: str) -> str:
    """``"a_deg"`` → ``"a"``: the axis name without its unit."""
    return str(column).rsplit("_", 1)[0]


def axes_feature_names(columns) -> tuple:
    """The features of the ``axes`` input set of a machine whose axis columns are ``columns``: each
    linear axis its value (``x_mm``), each rotary axis the cosine and sine of its angle (``cos_a``,
    ``sin_a``: the learned part is periodic in it), in the machine's axis order."""
    out = []
    for c in columns:
        out += [f"cos_{axis_stem(c)}", f"sin_{axis_stem(c)}"] if is_rotary_column(c) else [str(c)]
    return tuple(out)


def axes_input_groups(columns) -> tuple:
    """The feature columns of :func:`axes_feature_names` that belong to one axis (a rotary axis's cos
    and sin are one input): a tuple of index tuples, one per axis."""
    groups, k = [], 0
    for c in columns:
        w = 2 if is_rotary_column(c) else 1
        groups.append(tuple(range(k, k + w)))
        k += w
    return tuple(groups)


def linear_columns(columns) -> tuple:
    """The indices of the linear axes in ``columns`` (the learned part's box and taper are over them)."""
    return tuple(j for j, c in enumerate(columns) if not is_rotary_column(c))


FEATURE_NAMES = axes_feature_names(GRINDER_AXES)
"""The grinder's ``axes`` features, ``(x_mm, z_mm, cos_a, sin_a)``: a learned residual file that names
no ``axes`` was written for the grinder (every other machine's file names its axis columns)."""

WORK_AXES = GRINDER_AXES
"""The work-frame input sets need a machine with two linear axes and one rotary axis whose tool point
turns about that axis at radius ``rho0_mm + z`` (the grinder: its ``rho0_mm``); on any other
machine only the ``axes`` set exists."""

INPUT_SETS = {"axes": FEATURE_NAMES,
              "work": ("x_mm", "wy_mm", "wz_mm"),
              "axes+work": FEATURE_NAMES + ("wy_mm", "wz_mm")}
"""What the learned part can take as inputs (:func:`input_features`), named for the grinder
(:func:`input_set_features` gives any machine's): ``axes`` (each rotary axis on the circle), ``work`` (``x``
and the tool point's ``(wy, wz) = ρ·(sin a, cos a)``, ``ρ = ρ0 + z``), ``axes+work`` (both; the work-frame
sets only on a machine of :data:`WORK_AXES` with a ``rho0_mm``). docs/reference/learned-stage.md."""

INPUT_GROUPS = {"axes": axes_input_groups(GRINDER_AXES),
                "work": ((0,), (1,), (2,)),
                "axes+work": axes_input_groups(GRINDER_AXES) + ((4,), (5,))}
"""The columns of each input set that belong to one input (``ResidualRegressor(input_groups=…)``), for the
grinder (:func:`input_set_groups` gives any machine's): cos a and sin a are one rotary axis."""

LEARNED_INPUTS = ("axes",)
"""The input sets the learned stage cross-validates by default; the work-frame sets can be given (``inputs``)
(docs/decisions/008-learned-residual-measurements.md, input and kernel variants)."""


OUTPUT_FRAMES = ("work", "machine")
"""The frames the learned part can learn the residual in: ``work`` (as measured) or ``machine`` (turned by the
work frame's nominal rotation, :class:`errormap.machine_tool.WorkRotation`, learned there and turned back:
``r_work = R(axes)ᵀ·g(axes)``); both are cross-validated where the work frame turns with an axis.
docs/reference/learned-stage.md."""

LEARNED_FRAMES = ("work", "machine")
"""The output frames the learned stage cross-validates by default (:data:`OUTPUT_FRAMES`); the measurements
that chose them: docs/decisions/008-learned-residual-measurements.md."""


def frame_key(inputs: str, frame: str) -> str:
    """The key of an (input set, output frame) candidate in the stage's ``inputs_table``: the input
    set's name in the work frame (as before there were frames), ``"<set>@machine"`` in the machine frame."""
    return inputs if frame == "work" else f"{inputs}@{frame}"


def split_frame_key(key: str) -> tuple:
    """:func:`frame_key`'s inverse: ``(input set, output frame)``."""
    inputs, _, frame = key.partition("@")
    return inputs, frame or "work"


def to_frame(r_um, R, frame: str):
    """``r_um`` (n, 3) (or (m, n, 3)) in the work frame → in ``frame`` (``R`` (n, 3, 3) base <- work at
    the same points; the work frame: unchanged)."""
    r_um = np.asarray(r_um, dtype=float)
    if frame == "work":
        return r_um
    return np.einsum("nij,...nj->...ni", R, r_um)


def input_set_features(inputs: str, columns=GRINDER_AXES) -> tuple:
    """The feature names of input set ``inputs`` on a machine whose axis columns are ``columns``."""
    if inputs == "axes":
        return axes_feature_names(columns)
    return INPUT_SETS[inputs]


def input_set_groups(inputs: str, columns=GRINDER_AXES) -> tuple:
    """The input groups (:data:`INPUT_GROUPS`) of input set ``inputs`` on a machine of ``columns``."""
    if inputs == "axes":
        return axes_input_groups(columns)
    return INPUT_GROUPS[inputs]


def axis_features(axes, columns=GRINDER_AXES):
    """axes (n, k) in the machine's axis columns ``columns`` (default the grinder's x_mm, z_mm,
    a_deg) → the ``axes`` features (n, d) (:func:`axes_feature_names`: a linear axis its value, a
    rotary one cos and sin of its angle) and d(features)/d(axes) (n, d, k)."""
    axes = np.asarray(axes, dtype=float)
    cols, Jcols = [], []
    n, k = axes.shape[0], len(columns)
    for j, c in enumerate(columns):
        if is_rotary_column(c):
            a = np.deg2rad(axes[:, j])
            cols += [np.cos(a), np.sin(a)]
            Jcols += [(j, -np.sin(a) * np.pi / 180.0), (j, np.cos(a) * np.pi / 180.0)]
        else:
            cols.append(axes[:, j])
            Jcols.append((j, 1.0))
    f = np.stack(cols, axis=1)
    J = np.zeros((n, len(cols), k))
    for i, (j, v) in enumerate(Jcols):
        J[:, i, j] = v
    return f, J


def work_features(axes, rho0_mm: float):
    """axes (n, 3) → the nominal tool point in the work frame as (x_mm, wy_mm, wz_mm) (n, 3) and its
    derivative in the axes (n, 3, 3): ``wy = ρ sin a``, ``wz = ρ cos a``, ``ρ = rho0_mm + z``
    (the machine's radius of the tool point about the A axis at z = 0)."""
    axes = np.asarray(axes, dtype=float)
    a = np.deg2rad(axes[:, 2])
    rho = float(rho0_mm) + axes[:, 1]
    s, c = np.sin(a), np.cos(a)
    f = np.stack([axes[:, 0], rho * s, rho * c], axis=1)
    J = np.zeros((axes.shape[0], 3, 3))
    J[:, 0, 0] = 1.0
    J[:, 1, 1] = s
    J[:, 2, 1] = c
    J[:, 1, 2] = rho * c * np.pi / 180.0
    J[:, 2, 2] = -rho * s * np.pi / 180.0
    return f, J


def check_input_set(inputs: str, rho0_mm: float | None = None, columns=GRINDER_AXES) -> float | None:
    """ValueError unless ``inputs`` is an input set (:data:`INPUT_SETS`) and, for the work-frame sets, the
    machine's axis columns are :data:`WORK_AXES` and ``rho0_mm`` a finite number; returns the
    ``rho0_mm`` the set uses (None for ``axes``)."""
    if inputs not in INPUT_SETS:
        raise ValueError(f"Expected inputs one of {sorted(INPUT_SETS)}, got {inputs!r}")
    if inputs == "axes":
        return None
    if tuple(columns) != WORK_AXES:
        raise ValueError(f"the input set {inputs!r} needs a machine of axes {', '.join(WORK_AXES)} "
                         f"(this one has {', '.join(columns)}); only 'axes' exists here")
    if rho0_mm is None or not np.isfinite(rho0_mm):
        raise ValueError(f"the input set {inputs!r} needs the machine's rho0_mm")
    return float(rho0_mm)


def input_features(axes, inputs: str = "axes", rho0_mm: float | None = None, columns=GRINDER_AXES):
    """axes (n, k) in the axis columns ``columns`` → the features of input set ``inputs``
    (:data:`INPUT_SETS`) (n, d) and d(features)/d(axes) (n, d, k); ``rho0_mm`` needed for the
    work-frame sets (grinder only: :data:`WORK_AXES`)."""
    rho0_mm = check_input_set(inputs, rho0_mm, columns)
    if inputs == "axes":
        return axis_features(axes, columns)
    fw, Jw = work_features(axes, rho0_mm)
    if inputs == "work":
        return fw, Jw
    fa, Ja = axis_features(axes, columns)
    return np.concatenate([fa, fw[:, 1:]], axis=1), np.concatenate([Ja, Jw[:, 1:]], axis=1)
