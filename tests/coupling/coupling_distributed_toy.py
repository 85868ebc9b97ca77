"""Toy participants in separate process groups, compared with the same problems in one process.

Run as ``mpirun -n 2 python tests/coupling/coupling_distributed_toy.py``:
prints (rank 0) one JSON line, :func:`compare` of every case, and whether a
failure in one group was reported on every rank with the same message.
"""

from __future__ import annotations

import json
import sys

import numpy as np

import coupling as cp
from coupling.parallel import SerialComm, default_comm
from coupling.toys import acceleration_options, chain_problem, transient_problem

#: (problem, distribution spec) of the compared cases
CASES = {"chain": (chain_problem, "A:1,B+C:*"), "transient": (transient_problem, "A:1,B:*")}


def _spec(spec: str, size: int) -> str:
    """``spec`` with its ``*`` (the remaining ranks) resolved for a world of ``size`` ranks."""
    return spec.replace(":*", f":{size - 1}")


def solve(problem, scheme: str, comm, spec: str | None = None):
    """``problem`` under the implicit ``scheme`` with IQN-ILS, distributed by ``spec`` (None: one process)."""
    participants, data = problem.build()
    config = {"scheme": f"{scheme}-implicit", "order": list(problem.order), "max_iterations": 100,
              "verbose": False, "check_replicated": True,
              "convergence": [{"data": "*", "type": "relative", "limit": 1e-11}],
              "acceleration": acceleration_options("iqn-ils", problem)}
    distribution = None
    if spec is not None:
        distribution = cp.Distribution(_spec(spec, comm.Get_size()), comm, names=problem.order)
        participants = [p for p in participants if distribution.is_local(p.name)]
    scheme_ = cp.build_scheme(config, participants, data, comm=None if distribution else comm,
                              distribution=distribution)
    result = scheme_.solve() if problem.transient is None else scheme_.run(*problem.transient)
    return scheme_, result


def compare(comm, case: str, scheme: str) -> dict:
    """Iterations and the largest relative data difference, distributed vs one process."""
    build, spec = CASES[case]
    problem = build()
    distributed, result = solve(problem, scheme, comm, spec)
    single, single_result = solve(problem, scheme, SerialComm())
    diff = max(float(np.max(np.abs(distributed.latest(n) - single.latest(n)))
                     / max(np.max(np.abs(single.latest(n))), 1e-300)) for n in single.data)
    return {"case": case, "scheme": scheme, "iterations": result.iterations,
            "single_iterations": single_result.iterations, "converged": bool(result.converged),
            "max_relative_difference": diff, "replicated": _replicated(comm, distributed)}


def _replicated(comm, scheme) -> bool:
    """Whether every rank holds the same data values."""
    mine = b"".join(scheme.latest(n).tobytes() for n in scheme.data)
    return len(set(comm.allgather(mine))) == 1


class FailingBar(cp.Participant):
    """Wraps a participant; raises in iteration ``fail_at`` of its solves."""

    def __init__(self, inner: cp.Participant, fail_at: int):
        self.inner, self.name, self.fail_at, self.calls = inner, inner.name, fail_at, 0

    def interface_points(self, mesh_name):
        return self.inner.interface_points(mesh_name)

    def solve(self, inputs):
        self.calls += 1
        if self.calls == self.fail_at:
            raise FloatingPointError("the bar's solver broke down")
        return self.inner.solve(inputs)


def failure_messages(comm, scheme: str) -> list[str | None]:
    """Every rank's CouplingDivergedError message when participant C fails in its 2nd solve."""
    problem = chain_problem()
    distribution = cp.Distribution(_spec("A:1,B+C:*", comm.Get_size()), comm, names=problem.order)
    participants, data = problem.build()
    participants = [FailingBar(p, 2) if p.name == "C" else p for p in participants
                    if distribution.is_local(p.name)]
    config = {"scheme": f"{scheme}-implicit", "order": list(problem.order), "verbose": False,
              "convergence": [{"type": "relative", "limit": 1e-11}],
              "acceleration": acceleration_options("iqn-ils", problem)}
    message = None
    try:
        cp.build_scheme(config, participants, data, distribution=distribution).solve()
    except cp.CouplingDivergedError as exc:
        message = str(exc)
    return comm.allgather(message)


def check_all(comm) -> dict:
    """Every comparison and the failure reports, as one record."""
    return {"ranks": comm.Get_size(),
            "cases": [compare(comm, case, scheme) for case in CASES for scheme in ("serial", "parallel")],
            "failures": {scheme: failure_messages(comm, scheme) for scheme in ("serial", "parallel")}}


def main() -> int:
    comm = default_comm()
    record = check_all(comm)
    if comm.Get_rank() == 0:
        print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
