"""Poroelastic two-phase gel: weak forms (``gel.forms``) and the field solver (``gel.solver``)."""

from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver

__all__ = ["GelParameters", "PoroelasticGelSolver"]
