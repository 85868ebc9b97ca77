"""Partitioned device run at a coarse mesh; prints the summary's scalars as JSON (rank 0).

Arguments: CASE SIZE [HEIGHT [KINEMATICS]]: with HEIGHT the 3D device of that chip height.
"""
import dataclasses
import json
import sys

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.post.quantities import flat_quantities
from gelcell.run.solve import solve_partitioned

case, size = sys.argv[1], float(sys.argv[2])
params = CaseParameters.default(case, True).with_mesh_size(size)
if len(sys.argv) > 3:
    params = params.replace(geometry=dataclasses.replace(params.geometry, chip_height=float(sys.argv[3])))
if len(sys.argv) > 4:
    params = params.with_kinematics(sys.argv[4])
run = solve_partitioned(params, verbose=False, checks=False)
out = flat_quantities(run.summary)
out["iterations"] = run.summary["coupling"]["iterations"]
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(out))
