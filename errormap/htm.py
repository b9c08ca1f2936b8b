"""The grinder's spatial error from its 23 elements by homogeneous transforms.

Where each element enters (every error transform is ``Trans(δ)·Rot(ε)`` with
``Rot(ε) = RotX(εx)·RotY(εy)·RotZ(εz)``, applied right after the nominal motion of its body,
at the body's reference point)::

    T_tool = RotZ(θ1)·Trans(l2,0,l1)·Trans(RotZ(-θ1)·z·(sin s_xz, 0, cos s_xz))
             ·E_z(z)·Trans(l3,0,l4)·Trans(0,0,-R)
             E_z = Trans(dx_z, dy_z, dz_z)·Rot(ex_z, ey_z, ez_z)        (Z carriage, frame {1-2})
    T_work = Trans(l5,0,l6)·Trans(x,0,0)·E_x(x)·Trans(l7,0,l8)·E_oa·RotX(a)·E_a(a)
             E_x  = Trans(dx_x, dy_x, dz_x)·Rot(ex_x, ey_x, ez_x)       (X carriage)
             E_oa = Trans(0, dy_oa, dz_oa)·Rot(0, ey_oa, ez_oa)          (A-axis line, before the rotation)
             E_a  = Trans(dx_a, dy_a, dz_a)·Rot(ex_a, ey_a, ez_a)       (A body, in the rotating frame)

Squareness ``s_xz`` tilts the Z direction about the machine Y axis (towards +X).
The spatial error is the actual tool point minus the nominal tool point, both in the
workpiece frame (WCS), in μm. Translations enter in μm, angles in μrad.

The first-order (small-error) form is linear in the elements: ``e ≈ J(axes) · v`` where
``J`` (shape (n, 3, 23), μm per μm or μm per μrad) is the error-transfer Jacobian.

One source for the kinematics: these chains are not written out here. They are the
built-in chain file ``errormap/machines/grinder-chain.toml`` with the grinder file's geometry,
strokes and targets (:func:`errormap.grinder_file.grinder_chain`, compiled once per file), evaluated
by the generic compiled kernels of :mod:`errormap.chain_kernel`: the field and its axis Jacobian
(:class:`~errormap.chain_kernel.CompiledChain`), the exact error for element values per point and
the error-transfer Jacobian (:class:`~errormap.chain_kernel.CompiledNominal`), and the numpy
reference chain (:meth:`errormap.machine_tool.MachineTool.tool_point`). A readable hand-written
reference of the chains above lives in the tests (``tests/test_htm_reference.py``).
"""
from __future__ import annotations

import numpy as np

from .elements import ELEMENT_NAMES, ElementSet
from .field import JACOBIAN, PREDICT_AND_JACOBIAN, CalibratedVolume
from .machine import Grinder
from .transforms import check_points

UM = 1e-3   # mm per μm
URAD = 1e-6  # rad per μrad
IDX = {k: i for i, k in enumerate(ELEMENT_NAMES)}


def _chain(machine: Grinder):
    """The grinder file's chain (:func:`errormap.grinder_file.grinder_chain`, cached)."""
    from .grinder_file import grinder_chain
    return grinder_chain(machine)


def _nominal(machine: Grinder):
    """The chain packed for the point-by-point kernels (:func:`errormap.chain_kernel.grinder_nominal`)."""
    from .chain_kernel import grinder_nominal
    return grinder_nominal(machine)


def _values(axes, values) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if values.shape != (axes.shape[0], len(ELEMENT_NAMES)):
        raise ValueError(f"Expected element values of shape ({axes.shape[0]}, {len(ELEMENT_NAMES)}), got {values.shape}")
    return values


def tool_point_actual(machine: Grinder, axes, values) -> np.ndarray:
    """Actual tool point in the WCS (mm) with exact transforms.

    ``axes`` shape (n, 3) (x_mm, z_mm, a_deg); ``values`` shape (n, 23) element values
    at those axes (μm / μrad, ELEMENT_NAMES order). Returns shape (n, 3). The chain's numpy
    reference (:meth:`errormap.machine_tool.MachineTool.tool_point`).
    """
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    return _chain(machine).tool_point(axes, _values(axes, values))


def nominal_frames(machine: Grinder, axes):
    """Nominal frames of the grinder's chain at ``axes`` (n, 3): ``{"p": nominal tool point in
    the WCS (n, 3) mm, "tool": (R, t) machine <- tool point (n, 3, 3), (n, 3), "work": (R, t)
    machine <- workpiece (A body), "X"/"Z"/"A": (R, t) machine <- each moving body}`` (the chain
    file's frames, :meth:`errormap.machine_tool.MachineTool.side_frames` / ``body_frames``)."""
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    mt = _chain(machine)
    out = {"p": _nominal(machine).tool_points(axes), "tool": mt.side_frames("tool", axes),
           "work": mt.side_frames("work", axes)}
    for w in mt.axis_words:
        out[w] = mt.body_frames(w, axes)
    return out


def error_jacobian(machine: Grinder, axes) -> np.ndarray:
    """Error-transfer Jacobian ∂(spatial error μm)/∂(element value), shape (n, 3, 23).

    Columns in ELEMENT_NAMES order; translation columns are μm/μm, angle columns μm/μrad.
    At the nominal chain, compiled (:func:`errormap.chain_kernel.error_jac_kernel`): each element's
    transform moves the tool point along its axis (translation) or by ``axis × (p − origin)``
    (rotation), i.e. ``E⁻¹·q ≈ q - δ - ε×q`` pushed through the rest of the chain.
    """
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    return _nominal(machine).error_jacobian(axes)


def spatial_error_exact_chain(machine: Grinder, axes, values, chunk: int = 50_000) -> np.ndarray:
    """The exact spatial error (μm) through the numpy matrix chain :func:`tool_point_actual`;
    shapes as :func:`spatial_error_exact`. The readable reference the compiled form is tested
    against (and the benchmark's baseline); several times slower."""
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    return _chain(machine).spatial_error(axes, _values(axes, values), chunk=min(chunk, 4096))


def spatial_error_exact(machine: Grinder, axes, values, chunk: int = 50_000) -> np.ndarray:
    """Spatial error (μm) with exact transforms; ``values`` shape (n, 23) -> (n, 3).

    The grinder's chain compiled once and evaluated point by point
    (:func:`errormap.chain_kernel.values_kernel`): float64 throughout, no small-angle step — the
    same exact transforms as :func:`spatial_error_exact_chain`, equal to it to round-off
    (tested), with no (n, 3, 3) temporaries. ``chunk`` is kept for the API (the kernel
    allocates nothing per point).
    """
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    return _nominal(machine).spatial_error(axes, _values(axes, values))


def spatial_error_first_order(machine: Grinder, axes, values) -> np.ndarray:
    """Spatial error (μm) in the first-order form ``J · v``; shapes as the exact form."""
    return np.einsum("nij,nj->ni", error_jacobian(machine, axes), np.asarray(values, dtype=float))


class HTMField:
    """The 23-element homogeneous-transform model as an error field (:class:`errormap.field.ErrorField`).

    ``predict(axes)`` maps axes (x_mm, z_mm, a_deg), shape (n, 3), to the spatial
    error (dx_um, dy_um, dz_um), shape (n, 3). ``exact=False`` uses the first-order form.
    Calibrated volume: the range of the element set's stations per axis. The exact form
    declares ``jacobian`` and ``predict_and_jacobian`` (the chain's geometric Jacobian,
    :func:`errormap.chain_kernel.field_jac_kernel`); the first-order form declares nothing.
    Both evaluate the grinder's chain file (module docstring), packed once per field
    (:meth:`compiled`).
    """

    kind = "htm"

    def __init__(self, machine: Grinder, elements: ElementSet, exact: bool = True, chunk: int = 50_000):
        self.machine = machine
        self.elements = elements
        self.exact = exact
        self.chunk = chunk

    @property
    def capabilities(self) -> frozenset:
        """``{jacobian, predict_and_jacobian}`` for the exact form, none for the first-order form."""
        return frozenset({JACOBIAN, PREDICT_AND_JACOBIAN}) if self.exact else frozenset()

    @property
    def calibrated_volume(self) -> CalibratedVolume:
        """Where the elements were measured: per axis, the smallest to the largest station."""
        return CalibratedVolume.from_stations(self.elements.stations)

    def element_values(self, axes) -> np.ndarray:
        """The 23 element values at ``axes``, shape (n, 23)."""
        return self.elements.values(check_points(axes, "axes (x_mm, z_mm, a_deg)"))

    def compiled(self):
        """The grinder's chain with this field's element set packed for the kernels
        (:class:`errormap.chain_kernel.CompiledChain`): built on first use and kept while the
        machine, the element set, its per-axis splines (:meth:`ElementSet._axis_spline`, rebuilt
        when a caller resets them after editing) and its constants are the same. The element
        set's own splines are handed to the chain's element set, so the element values are the
        same numbers as :meth:`ElementSet.values`."""
        el = self.elements
        splines = tuple(el._axis_spline(c) for c in ("x_mm", "z_mm", "a_deg"))
        key = (self.machine, el, splines, tuple(sorted(el.constants.items())))
        cached = self.__dict__.get("_compiled")
        if (cached is not None and cached[0][0] is self.machine and cached[0][1] is el
                and all(a is b for a, b in zip(cached[0][2], splines)) and cached[0][3] == key[3]):
            return cached[1]
        from .chain_elements import ChainElementSet
        from .chain_kernel import CompiledChain
        mt = _chain(self.machine)
        ce = ChainElementSet.from_element_set(mt, el)
        for a in mt.axes:
            ce._splines[a.word] = el._axis_spline(a.column)
        cc = CompiledChain(mt, ce)
        self.__dict__["_compiled"] = (key, cc)
        return cc

    def predict(self, axes) -> np.ndarray:
        """Spatial error (μm), shape (n, 3), at axes shape (n, 3).

        Exact: one compiled pass per point (the 18 function elements from the element set's
        per-axis vector splines, then the chain's ops, :func:`errormap.chain_kernel.field_kernel`),
        no (n, 23) or (n, 3, 3) arrays; equal to the element values pushed through
        :func:`spatial_error_exact_chain` to round-off (tested). First order: the chain's
        error-transfer Jacobian times the element values, in chunks of ``chunk`` points.
        """
        axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
        if self.exact:
            return self.compiled().predict(axes)
        out = np.empty((axes.shape[0], 3))
        for s in range(0, axes.shape[0], self.chunk):
            sl = slice(s, s + self.chunk)
            out[sl] = spatial_error_first_order(self.machine, axes[sl], self.elements.values(axes[sl]))
        return out

    __call__ = predict

    def predict_and_jacobian(self, axes, dtype=np.float64):
        """``(E (n, 3) μm, dE/d(axes) (n, 3, 3))`` in one compiled pass (exact form only).

        Rows of the Jacobian are the error components, columns μm per mm, μm per mm, μm per
        deg. Geometric and exact (:func:`errormap.chain_kernel.field_jac_kernel`: each transform
        that depends on an axis adds its slope times its column), float64; the values equal
        :meth:`predict`'s, the Jacobian matches finite differences (tested).
        Float64 only (the field declares no ``float32``).
        """
        if not self.exact:
            raise TypeError("HTMField(exact=False) has no Jacobian (it declares no capabilities)")
        if np.dtype(dtype) != np.float64:
            raise ValueError(f"Expected dtype float64 (HTMField declares no float32), got {np.dtype(dtype)}")
        axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
        return self.compiled().predict_and_jacobian(axes)

    def jacobian(self, axes) -> np.ndarray:
        """dE/d(axes), shape (n, 3, 3) (:meth:`predict_and_jacobian`)."""
        return self.predict_and_jacobian(axes)[1]
