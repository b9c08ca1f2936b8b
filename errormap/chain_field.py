"""The error field of any machine-tool chain (:class:`errormap.field.ErrorField` over its axes).

``ChainField(machine, elements)``: ``predict(axes (n, k)) -> (n, 3)`` μm, the exact spatial error of the tool
point in the workpiece frame; ``jacobian(axes) -> (n, 3, k)`` μm per mm / per deg; ``predict_and_jacobian``;
``error_jacobian(axes) -> (n, 3, P)`` μm per μm / per μrad (at the nominal chain). ``k`` =
``machine.axis_columns``, ``P`` = ``machine.slot_names``. Axis Jacobian:
``dE/dq = [J_q(q, e) − J_q(q, 0) + J_e(q, e)·de/dq] / 1e-3``, computed by the compiled kernel
(:mod:`errormap.chain_kernel`; tested against a readable numpy reference in ``tests/chain_reference.py``)."""
from __future__ import annotations

import numpy as np

from .field import JACOBIAN, PREDICT_AND_JACOBIAN, CalibratedVolume
from .machine_tool import MachineTool


class ChainField:
    """A machine-tool chain with its element set as an error field (module docstring).

    ``calibrated_volume``: per axis the stations' range (axes without component errors: their
    stroke). Declares ``jacobian`` and ``predict_and_jacobian``.
    """

    kind = "chain"

    def __init__(self, machine: MachineTool, elements):
        if elements.machine is not machine and elements.machine.slot_names != machine.slot_names:
            raise ValueError("the element set belongs to another machine")
        self.machine = machine
        self.elements = elements

    @property
    def capabilities(self) -> frozenset:
        return frozenset({JACOBIAN, PREDICT_AND_JACOBIAN})

    @property
    def calibrated_volume(self) -> CalibratedVolume:
        lo, hi = [], []
        for a in self.machine.axes:
            s = self.elements.stations.get(a.column)
            lo.append(float(s.min()) if s is not None else a.stroke[0])
            hi.append(float(s.max()) if s is not None else a.stroke[1])
        return CalibratedVolume(lo, hi, self.machine.axis_columns)

    def element_values(self, axes) -> np.ndarray:
        """The element values at ``axes``, shape (n, P)."""
        return self.elements.values(axes)

    def _axes(self, axes) -> np.ndarray:
        axes = np.atleast_2d(np.asarray(axes, dtype=float))
        if axes.ndim != 2 or axes.shape[1] != len(self.machine.axes):
            raise ValueError(f"expected axes of shape (n, {len(self.machine.axes)}) "
                             f"({', '.join(self.machine.axis_columns)}), got {np.shape(axes)}")
        return axes

    def _compiled(self):
        """The kernels' arrays, packed on first use and kept while the element set, its per-axis splines
        (rebuilt when a caller resets them after editing) and its constants are the same."""
        from .chain_kernel import CompiledChain
        el = self.elements
        key = (el, tuple(el.axis_spline(a.word) for a in self.machine.axes if self.machine.slots_of(a.word)),
               tuple(sorted(el.constants.items())))
        cached = self.__dict__.get("_packed")
        if (cached is None or cached[0][0] is not el or len(cached[0][1]) != len(key[1])
                or not all(x is y for x, y in zip(cached[0][1], key[1])) or cached[0][2] != key[2]):
            cached = self.__dict__["_packed"] = (key, CompiledChain(self.machine, el))
        return cached[1]

    def predict(self, axes) -> np.ndarray:
        """Spatial error (μm), shape (n, 3), at axes (n, k): one compiled pass per point
        (:mod:`errormap.chain_kernel`), equal to the numpy reference to round-off (tested)."""
        return self._compiled().predict(self._axes(axes))

    __call__ = predict

    def predict_and_jacobian(self, axes, dtype=np.float64):
        """``(E (n, 3) μm, dE/d(axes) (n, 3, k))``; float64 only."""
        if np.dtype(dtype) != np.float64:
            raise ValueError(f"Expected dtype float64 (ChainField declares no float32), got {np.dtype(dtype)}")
        return self._compiled().predict_and_jacobian(self._axes(axes))

    def jacobian(self, axes) -> np.ndarray:
        """dE/d(axes), shape (n, 3, k)."""
        return self.predict_and_jacobian(axes)[1]

    def error_jacobian(self, axes) -> np.ndarray:
        """∂E/∂(element values) at the nominal chain, shape (n, 3, P), μm per μm / per μrad
        (compiled, :func:`errormap.chain_kernel.error_jacobian`; the numpy form is
        :meth:`MachineTool.error_jacobian`)."""
        from .chain_kernel import error_jacobian
        return error_jacobian(self.machine, self._axes(axes))
