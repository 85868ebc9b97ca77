"""The failures of femtools that a caller may want to tell apart (no dolfinx import here).

* :class:`OutputError`: an output directory refused or not writable (``femtools.io``);
* :class:`SingularSystemError`: a factorised operator has null pivots (``femtools.linalg``);
* :class:`NewtonError`: Newton's method failed (``femtools.linalg``);
* :class:`LinearSolveError`: an iterative linear solve did not converge (``femtools.krylov``).
"""

from __future__ import annotations

__all__ = ["OutputError", "SingularSystemError", "NewtonError", "LinearSolveError"]


class OutputError(Exception):
    """An output directory that gelcell refuses to replace or cannot write."""


class SingularSystemError(RuntimeError):
    """A factorised operator is singular: a boundary condition is missing.

    ``solver`` names the system, ``null_pivots`` is the number of null pivots
    MUMPS found (INFOG(28)), ``hint`` what the owner of the system says is the
    likely missing condition (see :meth:`add_hint`).
    """

    def __init__(self, solver: str, null_pivots: int, hint: str = ""):
        self.solver, self.null_pivots, self.hint = solver, int(null_pivots), hint
        super().__init__(self._text())

    def _text(self) -> str:
        text = (f"{self.solver}: the linear system is singular (MUMPS found {self.null_pivots} null "
                f"pivot{'s' if self.null_pivots != 1 else ''})")
        return text + (f": {self.hint}" if self.hint else ": a boundary condition is missing")

    def add_hint(self, hint: str) -> "SingularSystemError":
        """Name the likely missing condition (kept if one was given already)."""
        if hint and not self.hint:
            self.hint = hint
            self.args = (self._text(),)
        return self


class NewtonError(RuntimeError):
    """Newton's method failed: ``solver`` names the system, ``reason`` what went wrong."""

    def __init__(self, solver: str, reason: str, history: list[float]):
        self.solver, self.reason, self.history = solver, reason, list(history)
        super().__init__(f"{solver}: Newton's method failed: {reason}; relative corrections "
                         f"{['%.2e' % h for h in self.history]}")


class LinearSolveError(RuntimeError):
    """A Krylov solve failed: ``solver`` names the field, ``reason`` PETSc's converged reason
    (e.g. ``DIVERGED_ITS``), ``iterations`` the iterations it took."""

    def __init__(self, solver: str, reason: str, iterations: int):
        self.solver, self.reason, self.iterations = solver, str(reason), int(iterations)
        super().__init__(f"{solver}: the iterative linear solve failed: PETSc KSP reason {self.reason} "
                         f"after {self.iterations} iterations")
