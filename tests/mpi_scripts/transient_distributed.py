"""A time-dependent run of the 2D shear device with a cell (mesh size 6, adaptive BDF2 over half a
consolidation time): with every field on every rank, distributed ("fluid:1,gel+cell:1") and distributed,
stopped in its 4th window and resumed from its checkpoint.  Prints (rank 0) the time series of the three
runs and the windows the checkpoint held, as JSON.

Arguments: DIR (shared by the ranks), where the three runs write.
"""
import json
import os
import sys

os.environ["GELCELL_PRIOR_CACHE"] = "0"

import h5py  # noqa: E402

from mpi4py import MPI  # noqa: E402

from coupling.serialization import load_npz  # noqa: E402
from gelcell.case import CaseParameters, OutputSettings, RunConfig, TimeSettings, time_scales  # noqa: E402
from gelcell.output.timeseries import COLUMNS  # noqa: E402
from gelcell.run.backends import PartitionedBackend  # noqa: E402
from gelcell.run.transient_case import run_transient_case  # noqa: E402

DISTRIBUTE = "fluid:1,gel+cell:1"
COMM = MPI.COMM_WORLD


class Interrupt(Exception):
    """The simulated crash in the 4th window."""


def config(distribute: str | None) -> RunConfig:
    params = CaseParameters.default("shear", True).with_mesh_size(6)
    tau = time_scales(params)["consolidation"]
    settings = TimeSettings(transient=True, dt=tau / 10, t_end=tau / 2, scheme="bdf2", adaptive=True,
                            time_tol=1e-2, output_every=2)
    return RunConfig(params, time=settings, output=OutputSettings(figures=False),
                     coupling={"distribute": distribute} if distribute else {})


def series(directory: str) -> dict:
    with h5py.File(os.path.join(directory, "timeseries.h5"), "r") as h5:
        return {c: h5[c][()].tolist() for c in COLUMNS}


def interrupted_then_resumed(out: str) -> int:
    """Run distributed, crash in the 4th window, resume; returns the windows its checkpoint held."""
    window, calls = PartitionedBackend.window, {"n": 0}

    def failing(self, t, dt):
        calls["n"] += 1
        if calls["n"] == 4:
            raise Interrupt("simulated crash")
        return window(self, t, dt)

    PartitionedBackend.window = failing
    try:
        run_transient_case(config(DISTRIBUTE), out, comm=COMM, fields=False)
    except Interrupt:
        pass
    finally:
        PartitionedBackend.window = window
    held = int(load_npz(os.path.join(out + ".partial", "checkpoint.npz"))["window"])
    COMM.Barrier()
    run_transient_case(config(DISTRIBUTE), out, comm=COMM, fields=False, resume=True)
    return held


def main() -> int:
    root = sys.argv[1]
    runs = {"plain": None, "distributed": DISTRIBUTE}
    for name, distribute in runs.items():
        run_transient_case(config(distribute), os.path.join(root, name), comm=COMM, fields=False)
    held = interrupted_then_resumed(os.path.join(root, "resumed"))
    if COMM.rank == 0:
        print(json.dumps({"ranks": COMM.size, "checkpoint_windows": held,
                          **{name: series(os.path.join(root, name)) for name in (*runs, "resumed")}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
