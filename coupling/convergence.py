"""Convergence measures of coupling data.

For one data in iteration ``k`` of a window let ``r_k`` be its residual
(``x̃_k - x_k`` for accelerated data; the change since the previous iteration
for the forward data of a serial scheme), ``x̃_k`` its newly written value
and ``‖·‖`` the Euclidean norm over all points and components.

* :class:`AbsoluteConvergence`: ``‖r_k‖ < limit``.
* :class:`RelativeConvergence`: ``‖r_k‖ / ‖x̃_k‖ < limit`` (``0/0 = 0``).
* :class:`ResidualRelativeConvergence`: ``‖r_k‖ / ‖r_1‖ < limit`` (``0/0 = 0``).

The iteration has converged when ``k >= min_iterations`` and every measure
is met, or one measure with ``suffices = true`` is met.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

__all__ = ["ConvergenceMeasure", "AbsoluteConvergence", "RelativeConvergence",
           "ResidualRelativeConvergence", "build_measure", "MeasureValue"]


def _ratio(numerator: float, denominator: float) -> float:
    if numerator == 0.0:
        return 0.0
    if denominator == 0.0 or not math.isfinite(denominator):
        return math.inf if math.isfinite(numerator) else math.nan
    return numerator / denominator


@dataclass(frozen=True)
class MeasureValue:
    """The value of one measure in one iteration.

    Attributes:
        data: Data name.
        kind: Measure type.
        value: The measured quantity.
        limit: Its threshold.
        met: ``value < limit``.
        suffices: Whether meeting it alone suffices.
    """

    data: str
    kind: str
    value: float
    limit: float
    met: bool
    suffices: bool

    @property
    def ratio(self) -> float:
        """``value / limit`` (how far from convergence; NaN counts as infinite)."""
        return math.inf if math.isnan(self.value) else self.value / self.limit


class ConvergenceMeasure(abc.ABC):
    """One convergence measure on one data.

    Args:
        data: Data name.
        limit: Threshold (> 0).
        suffices: Whether meeting this measure alone declares convergence.
    """

    kind = "base"

    def __init__(self, data: str, limit: float, suffices: bool = False):
        if not limit > 0.0:
            raise ValueError(f"convergence limit for {data!r} must be > 0, got {limit}")
        self.data = data
        self.limit = float(limit)
        self.suffices = bool(suffices)

    @abc.abstractmethod
    def value(self, residual_norm: float, value_norm: float, first_residual_norm: float) -> float:
        """The measured quantity from the norms of this iteration."""

    def evaluate(self, residual_norm: float, value_norm: float,
                 first_residual_norm: float) -> MeasureValue:
        """Evaluate the measure; see the module docstring for the formulas."""
        v = self.value(residual_norm, value_norm, first_residual_norm)
        return MeasureValue(self.data, self.kind, v, self.limit, bool(v < self.limit), self.suffices)


class AbsoluteConvergence(ConvergenceMeasure):
    """``‖r_k‖ < limit``."""

    kind = "absolute"

    def value(self, residual_norm: float, value_norm: float, first_residual_norm: float) -> float:
        return residual_norm


class RelativeConvergence(ConvergenceMeasure):
    """``‖r_k‖ / ‖x̃_k‖ < limit``."""

    kind = "relative"

    def value(self, residual_norm: float, value_norm: float, first_residual_norm: float) -> float:
        return _ratio(residual_norm, value_norm)


class ResidualRelativeConvergence(ConvergenceMeasure):
    """``‖r_k‖ / ‖r_1‖ < limit`` with ``r_1`` the window's first residual."""

    kind = "residual-relative"

    def value(self, residual_norm: float, value_norm: float, first_residual_norm: float) -> float:
        return _ratio(residual_norm, first_residual_norm)


_MEASURES = {"absolute": AbsoluteConvergence, "relative": RelativeConvergence,
             "residual-relative": ResidualRelativeConvergence}


def build_measure(kind: str, data: str, limit: float, suffices: bool = False) -> ConvergenceMeasure:
    """Create the measure of type ``kind`` (``"absolute"``, ``"relative"``, ``"residual-relative"``)."""
    if kind not in _MEASURES:
        raise ValueError(f"convergence type = {kind!r} is not allowed; allowed values: "
                         f"{', '.join(repr(k) for k in _MEASURES)}")
    return _MEASURES[kind](data, limit, suffices)
