"""``gelcell run`` in this process (run it under mpirun); prints (rank 0) its exit code, its ranks and
the summary.json it wrote, as JSON.

Arguments: the command line after ``gelcell``, with ``--out DIR``.  The linearized prior is computed,
not read from the disk cache, so that two runs of one case report the same ``prior_source``.
"""
import json
import os
import sys

os.environ["GELCELL_PRIOR_CACHE"] = "0"

from mpi4py import MPI  # noqa: E402

from gelcell.cli import main  # noqa: E402

argv = sys.argv[1:]
rc = main(argv)
out = argv[argv.index("--out") + 1]
if MPI.COMM_WORLD.rank == 0:
    with open(os.path.join(out, "summary.json"), encoding="utf-8") as f:
        print(json.dumps({"rc": rc, "ranks": MPI.COMM_WORLD.size, "summary": json.load(f)}))
