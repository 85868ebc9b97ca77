"""Exceptions raised by coupling schemes.

Both failure exceptions carry the full records of the run so far in
``.result`` (a :class:`coupling.records.CouplingResult`), so a caller can write
or inspect them after catching the error.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    from coupling.records import CouplingResult

__all__ = ["CouplingError", "CouplingDivergedError", "CouplingNotConvergedError"]


class CouplingError(RuntimeError):
    """Base class of coupling failures; ``result`` holds the records so far."""

    def __init__(self, message: str, result: "CouplingResult"):
        super().__init__(message)
        self.result = result


class CouplingDivergedError(CouplingError):
    """A residual became NaN/Inf or grew by more than ``divergence_factor``."""


class CouplingNotConvergedError(CouplingError):
    """``max_iterations`` were reached without meeting the convergence measures."""
