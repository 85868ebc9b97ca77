"""The cell field solver: a neo-Hookean solid, plane strain or 3D (model.md sections 2, 5, 6, 10).

``NeoHookeanCellSolver`` takes the displacement on the gel-cell interface Gamma2
(Dirichlet) and returns the consistent nodal forces on the cell; with traction
loads and the rigid-body modes removed it also solves pure traction problems.
The weak form lives in ``cell.forms`` (shared with the monolithic reference);
``cell.meshes`` builds small verification meshes.
"""

from cell.solver import NeoHookeanCellSolver

__all__ = ["NeoHookeanCellSolver"]
