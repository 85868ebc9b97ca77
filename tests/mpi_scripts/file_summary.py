"""Partitioned run of a geometry file's device; prints the summary's scalars as JSON (rank 0).

Arguments: PATH SIZE KINEMATICS.
"""
import json
import sys

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.case.devices import FileGeometry
from gelcell.post.quantities import flat_quantities
from gelcell.run.solve import solve_partitioned

path, size, kinematics = sys.argv[1], float(sys.argv[2]), sys.argv[3]
params = CaseParameters.default("shear").replace(case="file", geometry=FileGeometry(file=path))
params = params.with_mesh_size(size).with_kinematics(kinematics)
run = solve_partitioned(params, verbose=False, checks=False)
out = flat_quantities(run.summary)
out["iterations"] = run.summary["coupling"]["iterations"]
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(out))
