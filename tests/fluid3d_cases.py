"""Tetrahedral channels for the 3D Stokes tests (``tests/test_fluid_3d.py``, ``benchmarks/fluid_duct_3d.py``).

Channels along x: 0 < x < L, 0 < y < W, 0 < z < Z on structured tetrahedral
meshes (each cube cut into the six Kuhn tetrahedra around its diagonal),
viscosity MU, driven by the pressure drop DP = P(0) - P(L): the inlet x = 0 is
an interface with a prescribed normal traction (t.n = -DP, n = -e_x) and no
tangential velocity, the outlet x = L has V_y = V_z = 0 and t_x = 0 (P = 0
there), so dP/dx = -G, G = DP / L.  The builders are collective.
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import fem, mesh as dmesh

from femtools.functions import integrate
from femtools.mesh import PARTITIONER
from fluid import FluidInterface, StokesSolver

__all__ = ["INLET", "OUTLET", "FRONT", "BACK", "FLOOR", "LID", "PIPE_WALL", "MU", "DP", "box_mesh", "pipe_mesh",
           "channel", "relative_errors"]

#: facet tags of the box: x = 0, x = L, y = 0, y = W, z = 0, z = Z
INLET, OUTLET, FRONT, BACK, FLOOR, LID = 1, 2, 3, 4, 5, 6
#: facet tag of the curved wall of :func:`pipe_mesh` (its ends are INLET and OUTLET)
PIPE_WALL = 7
MU, DP = 0.7, 2.0
#: the six tetrahedra of a unit cube: paths from corner (0,0,0) to (1,1,1), one axis per step
_KUHN = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]


# --------------------------------------------------------------------------- meshes and solvers
def _box_cells(n, mirror):
    """Kuhn tetrahedra of an (nx, ny, nz) grid of cubes; with ``mirror``, 2 nz layers, the upper nz
    the mirror images of the lower ones (the mesh is symmetric about the mid-plane)."""
    nx, ny, nz = n
    layers = 2 * nz if mirror else nz
    I, J, K = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(layers), indexing="ij"))
    flip = K >= nz if mirror else np.zeros(K.shape, dtype=bool)
    cells = []
    for path in _KUHN:
        corner, vertices = np.zeros((I.size, 3), dtype=np.int64), []
        for step in range(4):
            if step:
                corner[:, path[step - 1]] += 1
            kz = np.where(flip, 1 - corner[:, 2], corner[:, 2])
            vertices.append(((I + corner[:, 0]) * (ny + 1) + J + corner[:, 1]) * (layers + 1) + K + kz)
        cells.append(np.column_stack(vertices))
    return np.vstack(cells), layers


def box_mesh(lengths, n, mirror=False, comm: MPI.Comm = MPI.COMM_WORLD):
    """Tetrahedra on [0, L] x [0, W] x [0, Z] (Z doubled with ``mirror``), built on rank 0 and
    distributed; facet tags INLET, OUTLET, FRONT, BACK, FLOOR, LID."""
    L, W, Z = lengths
    cells, layers = _box_cells(n, mirror)
    top = 2 * Z if mirror else Z
    grid = np.meshgrid(np.linspace(0, L, n[0] + 1), np.linspace(0, W, n[1] + 1), np.linspace(0, top, layers + 1),
                       indexing="ij")
    x = np.column_stack([g.ravel() for g in grid])
    if comm.rank != 0:
        cells, x = np.empty((0, 4), dtype=np.int64), np.empty((0, 3))
    domain = ufl.Mesh(ufl.VectorElement(ufl.FiniteElement("Lagrange", ufl.tetrahedron, 1, variant="equispaced")))
    msh = dmesh.create_mesh(comm, cells, x, domain, partitioner=PARTITIONER)
    tol = 1e-10 * max(L, W, top)
    idx, val = [], []
    for tag, axis, c in ((INLET, 0, 0.0), (OUTLET, 0, L), (FRONT, 1, 0.0), (BACK, 1, W), (FLOOR, 2, 0.0),
                         (LID, 2, top)):
        facets = dmesh.locate_entities_boundary(msh, 2, lambda X, a=axis, c=c: np.abs(X[a] - c) <= tol)
        idx.append(facets)
        val.append(np.full(facets.size, tag, dtype=np.int32))
    idx, val = np.hstack(idx), np.hstack(val)
    order = np.argsort(idx)
    return msh, dmesh.meshtags(msh, 2, idx[order].astype(np.int32), val[order])


def pipe_mesh(length: float, radius: float, h: float, comm: MPI.Comm = MPI.COMM_WORLD):
    """A circular pipe along x (gmsh, unstructured P2 tetrahedra with curved faces, size h): facet tags
    INLET (x = 0), OUTLET (x = length), PIPE_WALL."""
    import gmsh
    from femtools.mesh import model_to_mesh
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        if comm.rank == 0:
            occ = gmsh.model.occ
            volume = occ.addCylinder(0, 0, 0, length, 0, 0, radius)
            occ.synchronize()
            gmsh.model.addPhysicalGroup(3, [volume], 1)
            for _, surface in gmsh.model.getEntities(2):
                x = occ.getCenterOfMass(2, surface)[0]
                tag = INLET if abs(x) < 1e-9 else OUTLET if abs(x - length) < 1e-9 else PIPE_WALL
                gmsh.model.addPhysicalGroup(2, [surface], tag)
            for option, value in (("MeshSizeMin", h), ("MeshSizeMax", h), ("MeshSizeFromCurvature", 0),
                                  ("MeshSizeFromPoints", 0)):
                gmsh.option.setNumber(f"Mesh.{option}", value)
            gmsh.model.mesh.generate(3)
            gmsh.model.mesh.setOrder(2)
        msh, _, ft = model_to_mesh(gmsh.model, comm, 0, gdim=3)
    finally:
        gmsh.finalize()
    return msh, ft


def channel(msh, ft, walls, symmetric=()):
    """Pressure-driven channel (module docstring): no slip on ``walls``, V_z = 0 on ``symmetric``."""
    inlet = FluidInterface(INLET, normal="robin", tangential="dirichlet")
    solver = StokesSolver(msh, ft, viscosity=MU, velocity_bcs=[(walls, (0.0, 0.0, 0.0))] if walls else [],
                          component_bcs=[(OUTLET, 1, 0.0), (OUTLET, 2, 0.0)]
                          + ([(symmetric, 2, 0.0)] if symmetric else []),
                          interfaces={"inlet": inlet})
    n = len(solver.interface_points("inlet"))
    # t.n = 2 mu dV_x/dx - P = -DP with n = -e_x: g_N = -DP n
    solver.set_interface_data("inlet", robin_normal=np.tile([DP, 0.0, 0.0], (n, 1)))
    solver.solve()
    return solver


def relative_errors(solver, axial, L):
    """Relative L2 errors of V against axial(y, z) e_x (interpolated in P4) and of P against G (L - x)."""
    msh = solver.mesh
    exact = fem.Function(fem.VectorFunctionSpace(msh, ("Lagrange", 4)))
    exact.interpolate(lambda x: np.vstack([axial(x[1], x[2]), 0 * x[0], 0 * x[0]]))
    P_exact = DP / L * (L - ufl.SpatialCoordinate(msh)[0])
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 8})
    e = solver.velocity - exact
    eV = np.sqrt(integrate(ufl.inner(e, e), dx) / integrate(ufl.inner(exact, exact), dx))
    eP = np.sqrt(integrate((solver.pressure - P_exact) ** 2, dx) / integrate(P_exact ** 2, dx))
    return eV, eP
