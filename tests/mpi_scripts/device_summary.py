"""Partitioned device run at a coarse mesh; prints the summary's scalars as JSON (rank 0)."""
import json
import sys

from mpi4py import MPI

from gelcell.parameters import CaseParameters
from gelcell.runner import solve_partitioned

case, size = sys.argv[1], float(sys.argv[2])
run = solve_partitioned(CaseParameters.default(case, True).with_mesh_size(size), verbose=False, checks=False)
out = {}
for block in ("gel", "cell"):
    for key, value in run.summary[block].items():
        if key.endswith("_location"):
            continue
        if isinstance(value, dict):
            out.update({f"{block}.{key}.{k}": v for k, v in value.items()})
        elif isinstance(value, (list, tuple)):
            out.update({f"{block}.{key}[{i}]": v for i, v in enumerate(value)})
        else:
            out[f"{block}.{key}"] = value
out["iterations"] = run.summary["coupling"]["iterations"]
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(out))
