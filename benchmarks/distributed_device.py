"""Wall time per coupling iteration of the shear device: every field on every rank, or one group per field.

    .venv/bin/python benchmarks/distributed_device.py single                    # 1 rank
    mpirun -n 2 .venv/bin/python benchmarks/distributed_device.py replicated    # every field on both ranks
    mpirun -n 2 .venv/bin/python benchmarks/distributed_device.py distributed   # fluid:1,gel+cell:1

The 2D shear device with its cell (``--mesh-size``, default 1), parallel-implicit,
the device's default acceleration (IQN-ILS with the linearized prior, read
from the disk cache after the first run).  Printed (rank 0), never asserted:
the iterations, the wall time of the scheme's solve (the iterations, without
building the device and its scheme) per iteration, and each
participant's mean solve time per iteration (its group's, distributed).  From
those, a rank per participant: a parallel iteration takes about the slowest
participant's solve plus the exchange; docs/coupling-study.md has the numbers.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from mpi4py import MPI

import coupling as cp
from gelcell.case import CaseParameters
from gelcell.coupled.defaults import partitioned_config
from gelcell.coupled.device import Device

#: the distribution of the ``distributed`` mode
DISTRIBUTE = "fluid:1,gel+cell:1"


def _timed_scheme_solves() -> list[float]:
    """Make every ``CouplingScheme.solve`` record its wall time (max over ranks) in the returned list:
    the iterations alone, without the device's scheme construction and prior loading."""
    times: list[float] = []
    untimed = cp.CouplingScheme.solve

    def solve(scheme):
        scheme.comm.Barrier()
        start = time.perf_counter()
        result = untimed(scheme)
        times.append(scheme.comm.allreduce(time.perf_counter() - start, op=MPI.MAX))
        return result
    cp.CouplingScheme.solve = solve
    return times


def measure(mode: str, mesh_size: float, repeats: int) -> dict:
    """Solve ``repeats`` times (a fresh device each, from rest); the best time per iteration."""
    params = CaseParameters.default("shear", True).with_mesh_size(mesh_size)
    table = {"scheme": "parallel-implicit", **({"distribute": DISTRIBUTE} if mode == "distributed" else {})}
    config = partitioned_config(params, table)
    comm = MPI.COMM_WORLD
    best = None
    times = _timed_scheme_solves()
    for _ in range(repeats):
        device = Device(params, comm, distribute=config.get("distribute"))
        result = device.solve(config, verbose=False)
        elapsed = times[-1]
        records = [r for w in device.scheme.history for r in w.records]
        solves = {name: float(np.mean([r.solve_time[name] for r in records])) for name in device.scheme.order}
        run = {"iterations": result.iterations, "seconds_per_iteration": elapsed / result.iterations,
               "solve_seconds": solves, "prior": device.prior_source}
        if best is None or run["seconds_per_iteration"] < best["seconds_per_iteration"]:
            best = run
    return {"mode": mode, "ranks": comm.size, "mesh_size": mesh_size, **best}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("single", "replicated", "distributed"))
    parser.add_argument("--mesh-size", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    record = measure(args.mode, args.mesh_size, args.repeats)
    if MPI.COMM_WORLD.rank == 0:
        print(json.dumps(record))


if __name__ == "__main__":
    main()
