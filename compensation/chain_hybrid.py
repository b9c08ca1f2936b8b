"""The hybrid error field on a machine-tool chain: the chain loop's model plus its learned residual.

``volcomp diagnose --machine M`` runs the learned-residual stage (:func:`compensation.hybrid.learned_stage`)
after the chain loop's effect search (``compensation/app/workflows/measurement.py``); when it is kept, the
``model.json`` (``volcomp-model/1``) carries it under ``learned_residual``
(:data:`errormap.diagnosis.loop_model.LEARNED_KEY`) beside the elements and the effect terms.

:func:`compensation.model_file.read_model` reads such a file whole: the loop's
:class:`~errormap.diagnosis.loop_model.ChainModelField` (elements + terms), wrapped in a :class:`ChainHybridField`
when a learned residual is kept.
:class:`ChainHybridField` is a :class:`compensation.hybrid.HybridField` (value and Jacobian: the chain's
plus the learned part's in closed form; the calibrated volume narrowed to the checks' box in the linear
axes) that also carries the loop model's conditions (``needs``, ``with_conditions``), so ``predict`` and
``compensate`` give its effect terms their conditions as for the loop's model alone.
"""
from __future__ import annotations

from errormap.diagnosis.loop_model import ChainModelField

from .hybrid import HybridField, LearnedResidual


class ChainHybridField(HybridField):
    """``base`` (a :class:`~errormap.diagnosis.loop_model.ChainModelField`) + ``learned``
    (:class:`~compensation.hybrid.LearnedResidual` over the machine's axis columns): the chain loop's
    hybrid model; the base's conditions pass through (:attr:`needs`, :meth:`with_conditions`)."""

    def __init__(self, base: ChainModelField, learned: LearnedResidual):
        if tuple(learned.axes) != tuple(base.machine.axis_columns):
            raise ValueError(f"the learned residual is over the axes {list(learned.axes)}, not the machine's "
                             f"{list(base.machine.axis_columns)}")
        super().__init__(base, learned)

    @property
    def needs(self) -> tuple:
        return self.base.needs

    @property
    def conditions(self) -> dict:
        return self.base.conditions

    @property
    def terms(self) -> list:
        return self.base.terms

    @property
    def elements(self):
        return self.base.elements

    def with_conditions(self, conditions: dict) -> "ChainHybridField":
        return ChainHybridField(self.base.with_conditions(conditions), self.learned)
