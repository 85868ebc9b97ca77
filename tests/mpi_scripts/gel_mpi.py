"""Gel solver on N ranks: prints the interface outputs as JSON (rank 0, last line).

A 2D chamber with a fluid interface on top (nonuniform traction and
velocity), a cell interface at the bottom (nonuniform NODAL forces: the
Gamma2 path whose owned-entry bookkeeping is the delicate part in
parallel), no slip on the left and symmetry on the right.  Two coupling
iterations with changed data check that the factorisation is reused.

Usage: gel_mpi.py [nx] [viscous|paper].  Inputs are defined in the viscous
units (s = d = Ca) and converted to the solver's units; outputs are converted
back, so the two unit choices must print the same numbers.
"""

import json
import os
import sys
import time

import numpy as np

from mpi4py import MPI

from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, rectangle_mesh
from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))     # tests/: gel_cases
from gel_cases import line_weights  # noqa: E402

comm = MPI.COMM_WORLD
nx = int(sys.argv[1]) if len(sys.argv) > 1 else 12
units = sys.argv[2] if len(sys.argv) > 2 else "viscous"
params = {"viscous": GelParameters.viscous_units(), "paper": GelParameters()}[units]
to_solver = params.Ca / params.stress_scale                  # viscous stress unit -> solver's
msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 0.5, nx, nx // 2, comm)
gel = PoroelasticGelSolver(msh, ft, params, no_slip=LEFT, symmetry=[(RIGHT, 0)],
                           fluid_interfaces={"Gamma1": TOP}, cell_interfaces={"Gamma2": BOTTOM})
Xt, Xb = gel.interface_points("Gamma1"), gel.interface_points("Gamma2")
w = line_weights(Xb, 0)
times = []
for k in range(2):
    T = np.column_stack([0.3 * np.sin(np.pi * Xt[:, 0]) + 0.1 * k, -1.0 - Xt[:, 0]**2])
    gel.set_interface_data("Gamma1", traction=to_solver * T,
                           velocity=np.column_stack([0.05 + 0 * Xt[:, 0], -0.02 * Xt[:, 0]]))
    gel.set_interface_data("Gamma2", force=to_solver * np.column_stack([w * np.cos(3 * Xb[:, 0]),
                                                                       -(1 + k) * w * Xb[:, 0]]))
    t0 = time.perf_counter()
    gel.solve()
    times.append(time.perf_counter() - t0)
factorizations = gel.newton.stats["factorizations"]     # over the coupling iterations
# one more solve with a forced refactorisation, for the timing comparison
gel.newton.invalidate_jacobian()
t0 = time.perf_counter()
gel.solve()
t_refactor = time.perf_counter() - t0

top, bottom = gel.interface_data("Gamma1"), gel.interface_data("Gamma2")
norms = gel.norms()
u_scale = params.displacement_scale / params.Ca               # solver's displacement unit -> viscous
result = {"flux": top["superficial_velocity"].tolist(), "interstitial": top["interstitial_velocity"].tolist(),
          "pressure": (top["pressure"].ravel() / to_solver).tolist(),
          "displacement": (u_scale * bottom["displacement"]).tolist(),
          "norm_v_f": norms["w"], "norm_u": u_scale * norms["u"], "norm_p": norms["p"] / to_solver,
          "factorizations": factorizations,
          "solve_times": times, "refactor_time": t_refactor, "dofs": gel.W.dofmap.index_map.size_global,
          "ranks": comm.size, "units": units, "stats": dict(gel.newton.stats)}
if comm.rank == 0:
    print(json.dumps(result))
