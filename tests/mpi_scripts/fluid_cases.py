"""Meshes and small Stokes cases shared by ``tests/test_fluid.py`` and ``fluid_parallel.py``.

Every mesh comes from gmsh (OCC, unstructured) and is built on rank 0, then
distributed; the builders are collective.
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

import gmsh
import ufl

from femtools.functions import integrate, quadrature_measure
from femtools.mesh import model_to_mesh
from fluid import FluidInterface, StokesSolver

# facet tags of the channel
INLET, OUTLET, BOTTOM, TOP = 1, 2, 3, 4
# facet tags of the plate with a hole
OUTER, HOLE = 11, 12


def _start():
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)


def channel_mesh(length: float, height: float, h: float, comm: MPI.Comm = MPI.COMM_WORLD):
    """Unstructured triangles on [0, L] x [0, H]; facet tags INLET, OUTLET, BOTTOM, TOP."""
    _start()
    try:
        if comm.rank == 0:
            occ = gmsh.model.occ
            r = occ.addRectangle(0, 0, 0, length, height)
            occ.synchronize()
            gmsh.model.addPhysicalGroup(2, [r], 1)
            for _, c in gmsh.model.getEntities(1):
                x, y, _ = occ.getCenterOfMass(1, c)
                tag = (INLET if abs(x) < 1e-9 else OUTLET if abs(x - length) < 1e-9
                       else BOTTOM if abs(y) < 1e-9 else TOP)
                gmsh.model.addPhysicalGroup(1, [c], tag)
            gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
            gmsh.option.setNumber("Mesh.Algorithm", 6)          # Frontal-Delaunay: unstructured
            gmsh.model.mesh.generate(2)
        msh, _, ft = model_to_mesh(gmsh.model, comm, 0, gdim=2)
    finally:
        gmsh.finalize()
    return msh, ft


def plate_with_hole_mesh(h: float, comm: MPI.Comm = MPI.COMM_WORLD, centre=(1.0, 0.5), radius=0.25):
    """[0, 2] x [0, 1] minus a disk, curved P2 geometry; facet tags OUTER (4 sides), HOLE."""
    _start()
    try:
        if comm.rank == 0:
            occ = gmsh.model.occ
            r = occ.addRectangle(0, 0, 0, 2.0, 1.0)
            d = occ.addDisk(centre[0], centre[1], 0, radius, radius)
            out, _ = occ.cut([(2, r)], [(2, d)])
            occ.synchronize()
            gmsh.model.addPhysicalGroup(2, [t for _, t in out], 1)
            outer, hole = [], []
            for _, c in gmsh.model.getEntities(1):
                x, y, _ = occ.getCenterOfMass(1, c)
                (hole if np.hypot(x - centre[0], y - centre[1]) < radius + 1e-9 else outer).append(c)
            gmsh.model.addPhysicalGroup(1, outer, OUTER)
            gmsh.model.addPhysicalGroup(1, hole, HOLE)
            gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
            gmsh.model.mesh.generate(2)
            gmsh.model.mesh.setOrder(2)
        msh, _, ft = model_to_mesh(gmsh.model, comm, 0, gdim=2)
    finally:
        gmsh.finalize()
    return msh, ft


# --------------------------------------------------------------------------- force-balance case
BALANCE = dict(mu=0.8, alpha_n=2.0, alpha_t=1.5, f=(0.5, -1.0))


def outer_velocity(X):
    """Dirichlet data on the outer boundary (rows = points)."""
    return np.column_stack((1.0 + 0.3 * X[:, 1], 0.2 * np.sin(X[:, 0])))


def hole_robin(X):
    """(g_N, g_T) Robin data on the hole (rows = points)."""
    gN = np.column_stack((np.cos(X[:, 0]), X[:, 1] ** 2))
    gT = np.column_stack((0.5 * X[:, 1], -0.4 + X[:, 0]))
    return gN, gT


def balance_case(h: float, comm: MPI.Comm = MPI.COMM_WORLD):
    """Plate with a hole: Dirichlet data on the outer boundary, Robin on the hole, body force.

    Returns the solver (solved) and a dict of the key numbers.
    """
    msh, ft = plate_with_hole_mesh(h, comm)
    c = BALANCE
    solver = StokesSolver(
        msh, ft, viscosity=c["mu"], body_force=c["f"],
        interfaces={"outer": FluidInterface(OUTER, "dirichlet", "dirichlet"),
                    "hole": FluidInterface(HOLE, alpha_n=c["alpha_n"], alpha_t=c["alpha_t"])})
    solver.set_interface_data("outer", velocity=outer_velocity(solver.interface_points("outer")))
    gN, gT = hole_robin(solver.interface_points("hole"))
    solver.set_interface_data("hole", robin_normal=gN, robin_tangential=gT)
    solver.solve()
    dx = quadrature_measure("dx", msh, degree=solver.quadrature_degree)
    body = np.array([integrate(fc * ufl.as_ufl(1.0), dx) for fc in c["f"]])
    results = {"F_outer": solver.interface_force("outer"), "F_hole": solver.interface_force("hole"),
               "body": body}
    for name in ("outer", "hole"):
        d = solver.interface_data(name)
        for key, values in d.items():
            results[f"{name}_{key}_norm"] = float(np.linalg.norm(values))
            results[f"{name}_{key}_0"] = values[0].tolist()
    V, P = solver.velocity, solver.pressure
    results["V_L2sq"] = integrate(ufl.inner(V, V), dx)
    results["P_mean"] = integrate(P, dx)
    results["P_L2sq"] = integrate(P * P, dx)
    return solver, results
