"""Mesh motion: the harmonic extension of a boundary displacement into a domain.

A domain that follows a moving boundary (the fluid above the gel) is mapped
from its reference mesh by x = X + u_m(X), where u_m is given on the moving
boundaries and extended into the domain by the Laplace problem

    int grad u_m : grad z dX = 0,

u_m = g on the moving boundaries (data), u_m[c] = 0 on the sliding ones (a
symmetry line or plane: its nodes slide along it) and u_m = 0 on every other boundary
(walls, inlets, outlets: the domain's outer shape is kept).  It reproduces an
affine motion exactly (a linear u_m is discrete harmonic), so a uniformly
stretched or sheared domain keeps straight-sided cells.  (A stiffness
1/|K| that keeps small cells more rigid would lose that: a piecewise constant
weight makes linear fields non-harmonic; at the strains of interest, ~10 %,
the plain Laplacian leaves the device's refinement bands well shaped.)  The
problem is linear with a fixed operator: it is assembled and factorised once,
each new boundary displacement costs one back-substitution.  u_m is in the
displacement unit of its data (e.g. d L0).  The same code runs in 2D and 3D
(vectors of gdim components).

The same residual (``harmonic_residual``) is what the monolithic reference
assembles, so both move the fluid mesh identically.
"""

from __future__ import annotations

import typing

import numpy as np

from petsc4py import PETSc

import ufl
from dolfinx import fem, mesh as dmesh

from femtools.functions import quadrature_measure
from femtools.interface import InterfaceNodes
from femtools.krylov import elasticity_solver, linear_solver_choice
from femtools.linalg import LinearSolver
from femtools.mesh import as_tags, settle_coordinate_element, tagged_facets

__all__ = ["harmonic_residual", "MeshMotion"]


def harmonic_residual(u_m, z, dx):
    """int grad u_m : grad z dX."""
    return ufl.inner(ufl.grad(u_m), ufl.grad(z)) * dx


class MeshMotion:
    """The harmonic extension of interface displacements on the P2 vector space ``V``.

    Args:
        V: a (collapsed) P2 vector space on the domain's mesh.
        facet_tags: its facet tags.
        moving: ``{name: tags}``: boundaries whose displacement is data
            (``set_displacement(name, values)`` with (N, gdim) nodal values on
            ``InterfaceNodes(V, facet_tags, tags)``).
        sliding: ``[(tags, component)]``: u_m[component] = 0 (symmetry lines or planes).
        name: solver name (PETSc prefixes).
        quadrature_degree: of the integral (the monolithic reference must use the same).
        petsc_options: options of its direct solver (``femtools.linalg.DirectSolver``), or of its
            Krylov solver with ``solver="iterative"`` (CG with GAMG, ``femtools.krylov.elasticity_solver``).
        solver: "direct" or "iterative".

    Every other exterior facet is held (u_m = 0).  Where boundaries meet,
    the sliding and held conditions win over the data.
    """

    def __init__(self, V: fem.FunctionSpace, facet_tags, moving: typing.Mapping[str, typing.Any],
                 sliding: typing.Sequence = (), name: str = "mesh_motion", quadrature_degree: int = 4,
                 petsc_options: dict | None = None, solver: str = "direct"):
        msh = settle_coordinate_element(V.mesh)      # before any form (femtools.mesh)
        fdim = msh.topology.dim - 1
        msh.topology.create_connectivity(fdim, msh.topology.dim)
        self.V, self.name = V, name
        self.displacement = fem.Function(V, name="mesh_displacement")
        self.nodes: dict[str, InterfaceNodes] = {}
        self._data: dict[str, fem.Function] = {}
        bcs = []
        used = []
        for key, tags in moving.items():
            tags = as_tags(tags, f"moving[{key!r}]")
            facets = tagged_facets(facet_tags, tags)
            used.append(facets)
            g = fem.Function(V, name=f"{key}_displacement")
            self._data[key] = g
            self.nodes[key] = InterfaceNodes(V, facet_tags, tags)
            bcs.append(fem.dirichletbc(g, fem.locate_dofs_topological(V, fdim, facets)))
        for tags, comp in sliding:
            tags = as_tags(tags, "sliding")
            facets = tagged_facets(facet_tags, tags)
            used.append(facets)
            Vc, _ = V.sub(int(comp)).collapse()
            dofs = fem.locate_dofs_topological((V.sub(int(comp)), Vc), fdim, facets)
            bcs.append(fem.dirichletbc(fem.Function(Vc), dofs, V.sub(int(comp))))
        held = np.setdiff1d(dmesh.exterior_facet_indices(msh.topology),
                            np.hstack(used) if used else np.empty(0, np.int32)).astype(np.int32)
        gdim = msh.geometry.dim
        bcs.append(fem.dirichletbc(np.zeros(gdim, dtype=PETSc.ScalarType),
                                   fem.locate_dofs_topological(V, fdim, held), V))
        u, z = ufl.TrialFunction(V), ufl.TestFunction(V)
        dx = quadrature_measure("dx", msh, degree=quadrature_degree)
        zero = fem.Constant(msh, PETSc.ScalarType((0.0,) * gdim))
        krylov = elasticity_solver(V, name, petsc_options) if linear_solver_choice(solver, name) else None
        self.solver = LinearSolver(harmonic_residual(u, z, dx), ufl.inner(zero, z) * dx,
                                   self.displacement, bcs, name=name, petsc_options=petsc_options,
                                   linear_solver=krylov)
        self.current = True     # the displacement is the extension of the current data

    def set_displacement(self, key: str, values: np.ndarray) -> None:
        """Nodal displacement (N, gdim) of the moving boundary ``key``."""
        self.nodes[key].to_function(values, self._data[key])
        self._data[key].x.scatter_forward()
        self.current = False

    def solve(self) -> fem.Function:
        if not self.current:
            self.solver.solve()
            self.current = True
        return self.displacement

    @property
    def stats(self) -> dict:
        return self.solver.stats
