"""A distributed toy participant, and a script comparing it with its serial twin.

Run as ``mpirun -n 2 python tests/coupling/coupling_mpi_toy.py``: prints (rank 0)
one JSON line with the converged data, the iteration count and the largest
difference to the same problem solved serially with undistributed participants.
"""

from __future__ import annotations

import json
import sys

import numpy as np

import coupling as cp
from coupling.parallel import SerialComm, default_comm, gather_rows

N = 24


class DistributedAffine(cp.Participant):
    """``out = M x + b + γ Σ_i x_i`` with rows (and points) distributed over ranks.

    Each rank owns the global rows ``rank::size`` (in a rank-dependent shuffled
    order), computes them, and the replicated result is assembled with
    :func:`coupling.parallel.gather_rows`; ``Σ x`` is an allreduce of local sums.
    """

    def __init__(self, name, comm, read, write, matrix, offset, gamma, reverse_points=False):
        self.name = name
        self.comm = comm
        self.read, self.write = read, write
        self.matrix, self.offset, self.gamma = matrix, offset, gamma
        rank, size = comm.Get_rank(), comm.Get_size()
        owned = np.arange(N)[rank::size]
        self.owned = np.random.default_rng(rank).permutation(owned)
        ids = np.arange(N)[::-1] if reverse_points else np.arange(N)
        self.global_points = np.column_stack([np.cos(ids / N * np.pi), np.sin(ids / N * np.pi)])

    def interface_points(self, mesh_name):
        return gather_rows(self.comm, self.owned, self.global_points[self.owned], N)

    def solve(self, inputs):
        x = inputs[self.read].reshape(N)
        local_sum = float(np.sum(x[self.owned]))
        total = self.comm.allreduce(local_sum) if self.comm.Get_size() > 1 else local_sum
        local = self.matrix[self.owned] @ x + self.offset[self.owned] + self.gamma * total
        return {self.write: gather_rows(self.comm, self.owned, local[:, None], N)}


def problem(comm):
    """Two distributed participants (point sets in opposite orders, matching mapping)."""
    rng = np.random.default_rng(42)
    m_a = 0.8 * rng.standard_normal((N, N)) / np.sqrt(N)
    m_b = -1.5 * np.eye(N) + 0.3 * rng.standard_normal((N, N)) / np.sqrt(N)
    a = DistributedAffine("A", comm, "y", "z", m_a, rng.standard_normal(N), 0.01)
    b = DistributedAffine("B", comm, "z", "y", m_b, rng.standard_normal(N), -0.02, reverse_points=True)
    data = [cp.Data("z", "Gamma", 1, "A", ("B",)), cp.Data("y", "Gamma", 1, "B", ("A",))]
    return [a, b], data


CONFIG = {"verbose": False, "max_iterations": 100,
          "convergence": [{"type": "relative", "limit": 1e-12}],
          "acceleration": {"type": "iqn-ils", "initial_relaxation": 0.3,
                           "preconditioner": {"type": "residual-sum"}}}


def solve(comm):
    participants, data = problem(comm)
    scheme = cp.build_scheme({**CONFIG, "check_replicated": True}, participants, data, comm=comm)
    result = scheme.solve()
    return scheme, result


def main() -> int:
    comm = default_comm()
    distributed, result = solve(comm)
    serial, serial_result = solve(SerialComm())
    diff = max(float(np.max(np.abs(distributed.latest(n) - serial.latest(n)))) for n in ("y", "z"))
    if comm.Get_rank() == 0:
        print(json.dumps({"ranks": comm.Get_size(), "iterations": result.iterations,
                          "serial_iterations": serial_result.iterations, "max_difference": diff,
                          "z": distributed.latest("z").ravel().tolist()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
