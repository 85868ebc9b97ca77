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

The three are preCICE's measures, and preCICE's names
(``"relative-convergence-measure"``, ...) are accepted for them.  A name
another framework gives another meaning is refused with the measure of that
meaning (:func:`measure_type`): CoCoNuT's ``relative_norm`` is
``"residual-relative"`` here, not ``"relative"``.
"""

from __future__ import annotations

import abc
import difflib
import math
from dataclasses import dataclass

__all__ = ["ConvergenceMeasure", "AbsoluteConvergence", "RelativeConvergence",
           "ResidualRelativeConvergence", "build_measure", "MeasureValue", "MEASURE_FORMULAS",
           "MEASURE_ALIASES", "measure_type"]

#: the measures and what each is met by (``r_1``: the window's first residual)
MEASURE_FORMULAS = {"absolute": "‖r_k‖ < limit", "relative": "‖r_k‖ / ‖x̃_k‖ < limit",
                    "residual-relative": "‖r_k‖ / ‖r_1‖ < limit"}

#: preCICE's names of the same measures (its ``<...-convergence-measure>`` tags; same formulas)
MEASURE_ALIASES = {
    "absolute-convergence-measure": "absolute",
    "relative-convergence-measure": "relative",
    "residual-relative-convergence-measure": "residual-relative",
}

#: what a name another framework uses means here (a suggestion by meaning, not by spelling)
_MEASURE_MEANINGS = {
    "relative_norm": "CoCoNuT's relative_norm is ‖r_k‖ / ‖r_1‖ (the residual relative to the first "
                     "one of the window): here 'residual-relative'",
    "absolute_norm": "CoCoNuT's absolute_norm is ‖r_k‖_p < tolerance: here 'absolute' (the 2-norm)",
    "iteration_limit": "CoCoNuT's iteration_limit is not a measure here: set coupling.max_iterations "
                       "(with on_max_iterations = 'continue' to accept the window)",
    "min-iteration-convergence-measure": "preCICE's min-iteration measure is not a measure here: set "
                                         "coupling.min_iterations",
    "absolute-or-relative-convergence-measure": "preCICE's absolute-or-relative measure is met when either "
                                                "limit is: give an 'absolute' and a 'relative' measure, each "
                                                "with suffices = true",
    "drop": "preCICE's 'Drop' column is its residual-relative measure: here 'residual-relative'",
    "relative_residual": "a 'relative residual' is ‖r_k‖ / ‖r_1‖ in CoCoNuT and PETSc's rtol, but "
                         "‖r_k‖ / ‖x̃_k‖ in preCICE's 'relative': name the one meant, 'residual-relative' "
                         "or 'relative'",
}


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


def measure_type(kind: object, where: str = "convergence") -> str:
    """The measure named ``kind``: one of ``MEASURE_FORMULAS`` or a preCICE name of one.

    Raises:
        ValueError: For any other name, naming the measure of the same meaning
            when the name is another framework's (never a look-alike spelling).
    """
    if isinstance(kind, str) and kind in MEASURE_FORMULAS:
        return kind
    if isinstance(kind, str) and kind in MEASURE_ALIASES:
        return MEASURE_ALIASES[kind]
    hint = ""
    if isinstance(kind, str):
        key = kind.strip().lower()
        for prefix in ("convergence_criteria.", "convergence_criterion."):    # CoCoNuT's type paths
            key = key[len(prefix):] if key.startswith(prefix) else key
        spelled = key.replace("_", "-").replace(" ", "-")
        meanings = {k.replace("_", "-"): v for k, v in _MEASURE_MEANINGS.items()}
        typo = difflib.get_close_matches(kind, tuple(MEASURE_FORMULAS), n=1, cutoff=0.85)
        if spelled in meanings:
            hint = f" ({meanings[spelled]})"
        elif spelled in MEASURE_FORMULAS or spelled in MEASURE_ALIASES:
            hint = f" (the same measure is written {MEASURE_ALIASES.get(spelled, spelled)!r})"
        elif typo:      # a near typo only: a look-alike of another meaning is no hint
            hint = f" (did you mean {typo[0]!r}?)"
    allowed = "; ".join(f"{k!r}: {f}" for k, f in MEASURE_FORMULAS.items())
    raise ValueError(f"{where}.type = {kind!r} is not allowed{hint}; allowed values: {allowed} "
                     f"(r = x̃ - x, r_1 the window's first residual; preCICE's names "
                     f"{', '.join(repr(a) for a in MEASURE_ALIASES)} are accepted too)")


def build_measure(kind: str, data: str, limit: float, suffices: bool = False) -> ConvergenceMeasure:
    """Create the measure of type ``kind`` (``"absolute"``, ``"relative"``, ``"residual-relative"``,
    or its preCICE name, see :func:`measure_type`)."""
    return _MEASURES[measure_type(kind)](data, limit, suffices)
