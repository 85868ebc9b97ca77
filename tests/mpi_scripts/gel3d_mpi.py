"""The gel solver on a 3D box on N ranks: prints its interface outputs as JSON (rank 0, last line).

A box [0, 1] x [0, 0.5] x [0, 0.25] of tetrahedra: a fluid interface on top (nonuniform traction
and velocity with three components), a cell interface at x = 1 (nonuniform NODAL forces, the
owned-entry bookkeeping of Gamma2), bonded bottom, symmetry on x = 0 and on the z faces.  Two
time steps (backward Euler, then BDF2) with the given kinematics.

Usage: gel3d_mpi.py [small|finite]
"""

import json
import os
import sys

import numpy as np

from mpi4py import MPI

from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))     # tests/: gel_cases
from gel_cases import X0, X1, Y0, Y1, Z0, Z1, box_mesh  # noqa: E402

comm = MPI.COMM_WORLD
kinematics = sys.argv[1] if len(sys.argv) > 1 else "small"
params, amp = {"small": (GelParameters.viscous_units(phi_s0=0.2, xi=50.0, Ca=1e-6), 1.0),
               "finite": (GelParameters(phi_s0=0.2, xi=50.0, Ca=0.3), 0.02)}[kinematics]
msh, ft = box_mesh((0.0, 0.0, 0.0), (1.0, 0.5, 0.25), (6, 3, 2), comm)
gel = PoroelasticGelSolver(msh, ft, params, no_slip=Y0, symmetry=[(X0, 0), ((Z0, Z1), 2)], kinematics=kinematics,
                           fluid_interfaces={"Gamma1": Y1}, cell_interfaces={"Gamma2": X1}, transient=True)
Xt, Xc = gel.interface_points("Gamma1"), gel.interface_points("Gamma2")
T = amp * np.column_stack([0.3 * np.sin(np.pi * Xt[:, 0]), -1.0 - Xt[:, 0]**2, 0.1 * Xt[:, 2]])
V = np.column_stack([0.05 + 0 * Xt[:, 0], -0.02 * Xt[:, 0], 0.01 * Xt[:, 2]])
gel.set_interface_data("Gamma1", traction=T, velocity=V)
gel.set_interface_data("Gamma2", force=amp * 1e-3 * np.column_stack([np.cos(3 * Xc[:, 1]), Xc[:, 2], -Xc[:, 1]]))
gel.push_history()
for scheme in ("be", "bdf2"):
    gel.set_time_step(0.05, scheme)
    gel.solve()
    gel.push_history()
top, cell = gel.interface_data("Gamma1"), gel.interface_data("Gamma2")
result = {"interstitial": top["interstitial_velocity"].tolist(), "mixture": top["mixture_velocity"].tolist(),
          "pressure": top["pressure"].tolist(), "displacement": cell["displacement"].tolist(),
          "points": Xt.tolist(), "norms": gel.norms()}
if comm.rank == 0:
    print(json.dumps(result))
