"""Partitioned device run at a coarse mesh; prints the summary's scalars as JSON (rank 0)."""
import json
import sys

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.post.quantities import flat_quantities
from gelcell.run.solve import solve_partitioned

case, size = sys.argv[1], float(sys.argv[2])
run = solve_partitioned(CaseParameters.default(case, True).with_mesh_size(size), verbose=False, checks=False)
out = flat_quantities(run.summary)
out["iterations"] = run.summary["coupling"]["iterations"]
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(out))
