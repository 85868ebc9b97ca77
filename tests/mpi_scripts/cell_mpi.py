"""Cell solver on the current number of ranks; prints the key numbers as JSON (rank 0).

Three problems: a disk with a non-uniform finite-strain displacement on its
whole boundary (Gamma2), a half disk on a symmetry line, and an annulus under
inner pressure with the rigid modes removed (pure traction).  Run by
``tests/test_cell.py`` on 1 and 2 ranks; the numbers must agree.
"""

import json

import numpy as np

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from dolfinx import fem

from cell import NeoHookeanCellSolver, meshes
from cell_summary import record

comm = MPI.COMM_WORLD
out = {"ranks": comm.size}



def boundary_displacement(X, centre, radius):
    """A non-uniform displacement of a few per cent strain, in units of L0."""
    x, y = (X[:, 0] - centre[0]) / radius, (X[:, 1] - centre[1]) / radius
    return radius * np.column_stack([-0.05 * x + 0.02 * y**2, 0.03 * y + 0.02 * x * y])


centre, radius = (2.0, -0.2), 0.03
for half in (False, True):
    msh, ft = meshes.disk(radius, radius / 6, centre=centre, half=half)
    d = 1e-3
    s = NeoHookeanCellSolver(msh, ft, mu=0.01, lmbda=0.01, stress_scale=1e-4, displacement_scale=d,
                             interfaces={"Gamma2": meshes.BOUNDARY},
                             symmetry=[(meshes.FLAT, 1)] if half else ())
    g = boundary_displacement(s.interface_points("Gamma2"), centre, radius)
    if half:
        g[:, 1] *= (s.interface_points("Gamma2")[:, 1] - centre[1]) / radius   # u_y = 0 on the line
    s.set_interface_data("Gamma2", displacement=g / d)
    s.solve()
    prefix = "half" if half else "disk"
    out[f"{prefix}_force"] = s.interface_data("Gamma2")["force"].tolist()
    if half:
        out["half_flat_force"] = s.boundary_force(meshes.FLAT).tolist()   # the symmetry reaction
    record(out, prefix, s)

msh, ft = meshes.annulus(1.0, 2.0, 0.3)
p = fem.Constant(msh, PETSc.ScalarType(0.05))
s = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, tractions=[(meshes.INNER, -p * ufl.FacetNormal(msh))],
                         remove_rigid_modes=True)
s.solve()
record(out, "annulus", s)

if comm.rank == 0:
    print(json.dumps(out))
