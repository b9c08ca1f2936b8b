"""The hybrid error field on a machine-tool chain: the chain loop's model plus its learned residual.

When ``volcomp diagnose --machine M`` keeps the learned residual
(:func:`compensation.hybrid.learned_stage`), its ``model.json`` carries it under ``learned_residual``
(:data:`errormap.diagnosis.loop_model.LEARNED_KEY`), and :func:`compensation.model_file.read_model` wraps
the loop's :class:`~errormap.diagnosis.loop_model.ChainModelField` in a :class:`ChainHybridField`: a
:class:`compensation.hybrid.HybridField` that also carries the loop model's conditions (``needs``,
``with_conditions``)."""
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
