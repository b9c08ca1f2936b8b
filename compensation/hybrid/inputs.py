"""The learned part's inputs and output frames: the features of a machine's axes (each rotary axis on the
circle), the work-frame input sets, the candidate families and the frames it can learn in (module doc of
:mod:`compensation.hybrid`)."""
from __future__ import annotations

import numpy as np

from errormap.field import is_rotary_column

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


INPUT_SETS = ("axes", "work", "axes+work")
"""What the learned part can take as inputs (:func:`input_features`): ``axes`` (each rotary axis on the circle),
``work`` (the linear axis along the rotary axis that turns the work, and the tool point's two coordinates in the
work frame across it, ``ρ·(sin a, cos a)``, ``ρ = ρ0 + r``, ``r`` the radial linear axis), ``axes+work`` (both;
the work-frame sets only on a machine whose file gives that geometry, :func:`work_radius`).
docs/reference/learned-stage.md."""

WORK_CHECK_TOL_MM = 1e-9
"""The machine's nominal chain must put the tool point at ``ρ·(sin a, cos a)`` across the rotary axis within
1e-9 mm (round-off of the chain's products) at every corner of the strokes for the work-frame sets to exist."""


def work_columns_ok(columns) -> bool:
    """Whether axis ``columns`` are of the work-frame sets' form: (the linear axis along the rotary axis, the
    radial linear axis, a rotary axis A, B or C), in that order."""
    return (len(columns) == 3 and not is_rotary_column(columns[0]) and not is_rotary_column(columns[1])
            and is_rotary_column(columns[2]) and axis_stem(columns[2]) in ("a", "b", "c"))


def work_feature_names(columns) -> tuple:
    """The ``work`` set's features on axis ``columns`` (:func:`work_columns_ok`): the linear axis along the
    rotary one and the two work-frame coordinates across it (a rotary A, about x: ``wy_mm``, ``wz_mm``)."""
    i = "abc".index(axis_stem(columns[2]))
    return (str(columns[0]), f"w{'xyz'[(i + 1) % 3]}_mm", f"w{'xyz'[(i + 2) % 3]}_mm")


def work_radius(machine) -> float | None:
    """``ρ0`` (mm) of the work-frame sets read from ``machine``'s file: the radius of the nominal tool point about
    the rotary axis that turns the work with every axis at zero; None unless the machine has that geometry:
    axis columns of :func:`work_columns_ok`'s form, the rotary axis on the work side about the first linear
    axis' direction, and the tool point in the work frame at ``(ρ0 + r)·(sin a, cos a)`` across it at every
    corner of the strokes (:data:`WORK_CHECK_TOL_MM`)."""
    from errormap.chain_kernel import NominalChain
    cols, axes = tuple(machine.axis_columns), machine.axes
    if not work_columns_ok(cols) or axes[2].side != "work" or axes[2].along != axes[0].along:
        return None
    i = axes[2].along
    b, c = (i + 1) % 3, (i + 2) % 3
    chain = NominalChain(machine)
    rho0 = float(chain.forward(np.zeros((1, 3)))[0, c])
    corners = np.array([[x, r, a] for x in axes[0].stroke for r in axes[1].stroke for a in (0.0, 30.0, 90.0, 200.0)])
    p = chain.forward(corners)
    rho, ang = rho0 + corners[:, 1], np.deg2rad(corners[:, 2])
    if np.abs(p[:, b] - rho * np.sin(ang)).max() > WORK_CHECK_TOL_MM or \
            np.abs(p[:, c] - rho * np.cos(ang)).max() > WORK_CHECK_TOL_MM:
        return None
    return rho0


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


def input_set_features(inputs: str, columns) -> tuple:
    """The feature names of input set ``inputs`` on a machine whose axis columns are ``columns``."""
    if inputs == "axes":
        return axes_feature_names(columns)
    work = work_feature_names(columns)
    return work if inputs == "work" else axes_feature_names(columns) + work[1:]


def input_set_groups(inputs: str, columns) -> tuple:
    """The columns of each input of input set ``inputs`` on a machine of ``columns`` (``ResidualRegressor(input_groups=…)``):
    a rotary axis's cos and sin are one input."""
    axes = axes_input_groups(columns)
    if inputs == "axes":
        return axes
    if inputs == "work":
        return ((0,), (1,), (2,))
    d = sum(len(g) for g in axes)
    return axes + ((d,), (d + 1,))


def axis_features(axes, columns):
    """axes (n, k) in the machine's axis columns ``columns`` → the ``axes`` features (n, d)
    (:func:`axes_feature_names`: a linear axis its value, a rotary one cos and sin of its angle) and
    d(features)/d(axes) (n, d, k)."""
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
    """axes (n, 3) (along, radial, rotary: :func:`work_columns_ok`) → the nominal tool point in the work frame
    as (along, ρ sin a, ρ cos a) (n, 3) mm and its derivative in the axes (n, 3, 3), ``ρ = rho0_mm + r``
    (:func:`work_radius`: the radius about the rotary axis at zero, from the machine's file)."""
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


def check_input_set(inputs: str, rho0_mm: float | None, columns) -> float | None:
    """ValueError unless ``inputs`` is an input set (:data:`INPUT_SETS`) and, for the work-frame sets, the
    axis ``columns`` are of their form (:func:`work_columns_ok`) and ``rho0_mm`` a finite number (the
    machine's :func:`work_radius`); returns the ``rho0_mm`` the set uses (None for ``axes``)."""
    if inputs not in INPUT_SETS:
        raise ValueError(f"Expected inputs one of {sorted(INPUT_SETS)}, got {inputs!r}")
    if inputs == "axes":
        return None
    if not work_columns_ok(columns):
        raise ValueError(f"the input set {inputs!r} needs axes (linear along the rotary axis, radial linear, rotary "
                         f"A/B/C) (this machine has {', '.join(columns)}); only 'axes' exists here")
    if rho0_mm is None or not np.isfinite(rho0_mm):
        raise ValueError(f"the input set {inputs!r} needs the machine's rho0_mm (the tool point's radius about the "
                         "rotary axis at zero, from its file)")
    return float(rho0_mm)


def input_features(axes, inputs: str, rho0_mm: float | None, columns):
    """axes (n, k) in the axis columns ``columns`` → the features of input set ``inputs``
    (:data:`INPUT_SETS`) (n, d) and d(features)/d(axes) (n, d, k); ``rho0_mm`` needed for the
    work-frame sets (:func:`work_radius`)."""
    rho0_mm = check_input_set(inputs, rho0_mm, columns)
    if inputs == "axes":
        return axis_features(axes, columns)
    fw, Jw = work_features(axes, rho0_mm)
    if inputs == "work":
        return fw, Jw
    fa, Ja = axis_features(axes, columns)
    return np.concatenate([fa, fw[:, 1:]], axis=1), np.concatenate([Ja, Jw[:, 1:]], axis=1)
