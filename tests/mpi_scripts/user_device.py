"""Partitioned run of a device from a geometry file.

Prints the summary's scalars and per-cell values as JSON (rank 0).
"""
import json
import sys

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.post.quantities import flat_quantities
from gelcell.run.solve import solve_partitioned

path = sys.argv[1]
run = solve_partitioned(CaseParameters.from_dict({"geometry": {"file": path}}), verbose=False, checks=False)
out = flat_quantities(run.summary)
for cell in run.summary["cells"]:
    for key in ("centroid_displacement", "von_mises_strain", "von_mises_stress"):
        for i, v in enumerate(cell[key]):
            out[f"{cell['name']}.{key}[{i}]"] = v
out["iterations"] = run.summary["coupling"]["iterations"]
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(out))
