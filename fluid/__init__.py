"""Steady Stokes flow of the perfusate (Taylor–Hood P2/P1).

``StokesSolver`` is the field solver (``femtools.solver.FieldSolver``);
``FluidInterface`` says which condition it enforces on an interface;
``fluid.forms`` holds the UFL forms shared with the monolithic reference.
"""

from fluid.solver import FluidInterface, StokesSolver

__all__ = ["FluidInterface", "StokesSolver"]
