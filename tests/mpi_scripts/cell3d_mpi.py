"""The 3D cell solver on the current number of ranks; prints the key numbers as JSON (rank 0).

A ball (the spherical cell) with a non-uniform finite-strain displacement on its surface
(Gamma2), a half ball on the symmetry plane z = z_c, and a hollow sphere under internal
pressure with the six rigid modes removed.  Run by ``tests/test_cell_3d.py`` on 1 and 2
ranks; the numbers must agree.
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



centre, radius = np.array([2.0, -0.2, 0.2]), 0.03
for half in (False, True):
    msh, ft = meshes.ball(radius, radius / 3, centre=centre, planes=(2,) if half else ())
    d = 1e-3
    s = NeoHookeanCellSolver(msh, ft, mu=0.01, lmbda=0.01, stress_scale=1e-4, displacement_scale=d,
                             interfaces={"Gamma2": meshes.BOUNDARY},
                             symmetry=[(meshes.PLANE_Z, 2)] if half else ())
    x, y, z = ((s.interface_points("Gamma2") - centre) / radius).T
    g = radius * np.column_stack([-0.05 * x + 0.02 * y**2, 0.03 * y + 0.02 * x * z, 0.04 * z * (1 + 0.5 * x)])
    s.set_interface_data("Gamma2", displacement=g / d)
    s.solve()
    prefix = "half" if half else "ball"
    out[f"{prefix}_force"] = s.interface_data("Gamma2")["force"].tolist()
    if half:
        out["half_plane_force"] = s.boundary_force(meshes.PLANE_Z).tolist()
    record(out, prefix, s)

msh, ft = meshes.shell(1.0, 1.5, 0.5)
p = fem.Constant(msh, PETSc.ScalarType(1e-4))   # small: a dead load on a pinned body balances to O(strain)
s = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, tractions=[(meshes.INNER, -p * ufl.FacetNormal(msh))],
                         remove_rigid_modes=True)
s.solve()
record(out, "shell", s)
out["shell_pins"] = [s.rigid_mode_reaction["relative"] < 1e-10]

if comm.rank == 0:
    print(json.dumps(out))
