"""Key numbers of the fluid force-balance case, printed as JSON (rank 0, last line).

Run by ``tests/test_fluid.py::test_same_answer_on_two_ranks`` on 1 and 2 ranks.
"""

import json
import os
import sys

import numpy as np

from mpi4py import MPI

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fluid_cases import balance_case  # noqa: E402

comm = MPI.COMM_WORLD
solver, results = balance_case(h=0.15)
out = {k: np.asarray(v).tolist() for k, v in results.items()}
out["ranks"] = comm.size
if comm.rank == 0:
    print(json.dumps(out))
