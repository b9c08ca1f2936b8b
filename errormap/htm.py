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

These chains are not written out here: they are the grinder's chain file
(``errormap/machines/grinder.toml``), evaluated by the generic compiled kernels of
:mod:`errormap.chain_kernel` (the field and its axis Jacobian, :class:`~errormap.chain_kernel.CompiledChain`;
the exact error for slot values per point, the error-transfer Jacobian and the nominal kinematics,
:func:`~errormap.chain_kernel.spatial_error`, :func:`~errormap.chain_kernel.error_jacobian`,
:func:`~errormap.chain_kernel.forward`, :func:`~errormap.chain_kernel.inverse`) and the numpy reference
chain (:meth:`errormap.machine_tool.MachineTool.tool_point`). A readable hand-written
reference of the chains above lives in the tests (``tests/test_htm_reference.py``).
"""
from __future__ import annotations

import numpy as np

from .elements import ElementSet
from .field import JACOBIAN, PREDICT_AND_JACOBIAN, CalibratedVolume
from .machine_tool import MachineTool
from .transforms import check_points

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

    def __init__(self, machine: MachineTool, elements: ElementSet, exact: bool = True, chunk: int = 50_000):
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
        mt = self.machine
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
        from .chain_kernel import error_jacobian
        out = np.empty((axes.shape[0], 3))
        for s in range(0, axes.shape[0], self.chunk):
            sl = slice(s, s + self.chunk)
            out[sl] = np.einsum("nij,nj->ni", error_jacobian(self.machine, axes[sl]), self.elements.values(axes[sl]))
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
