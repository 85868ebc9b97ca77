"""MPI: replicated interface arrays from distributed participants; rank-count independence.

These tests run in serial and under ``mpirun -n 2 python -m pytest``; in serial,
one test also launches the distributed toy under ``mpirun -n 2`` itself.
"""

from __future__ import annotations

import importlib.util
import json
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest

import coupling as cp
from coupling.parallel import SerialComm, gather_rows, scatter_rows

HERE = pathlib.Path(__file__).resolve().parent
spec = importlib.util.spec_from_file_location("coupling_mpi_toy", HERE / "coupling_mpi_toy.py")
mpi_toy = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mpi_toy)


def test_gather_and_scatter_rows(comm):
    n = 17
    rank, size = comm.Get_rank(), comm.Get_size()
    owned = np.random.default_rng(rank).permutation(np.arange(n)[rank::size])
    values = np.column_stack([owned ** 2, -owned]).astype(float)
    full = gather_rows(comm, owned, values, n)
    np.testing.assert_array_equal(full, np.column_stack([np.arange(n) ** 2, -np.arange(n)]))
    np.testing.assert_array_equal(scatter_rows(comm, owned, full), values)
    # a row given several times takes the value of the lowest rank (first occurrence there)
    shared = gather_rows(comm, np.concatenate([owned, [0]]),
                         np.concatenate([values, [[100.0 + rank, 0.0]]]), n)
    assert shared[0, 0] == 0.0  # rank 0 owns row 0 and lists it first
    with pytest.raises(ValueError, match="provided by no rank"):
        gather_rows(comm, owned[owned != 3], values[owned != 3], n)
    with pytest.raises(ValueError, match=r"global ids must lie in \[0, 17\)"):
        gather_rows(comm, owned + 100, values, n)


def test_serial_comm_stand_in():
    comm = SerialComm()
    assert comm.Get_rank() == 0 and comm.Get_size() == 1
    assert comm.allgather(3) == [3] and comm.bcast(4) == 4 and comm.gather(5) == [5]
    full = gather_rows(comm, np.array([2, 0, 1]), np.array([[2.0], [0.0], [1.0]]), 3)
    np.testing.assert_array_equal(full.ravel(), [0.0, 1.0, 2.0])


@pytest.mark.mpi
def test_distributed_participant_gives_the_serial_answer(comm):
    distributed, result = mpi_toy.solve(comm)
    serial, serial_result = mpi_toy.solve(SerialComm())
    assert result.converged and serial_result.converged
    assert result.iterations == serial_result.iterations
    for name in ("y", "z"):
        np.testing.assert_allclose(distributed.latest(name), serial.latest(name), rtol=1e-12, atol=1e-14)
    # every rank holds the same replicated answer
    gathered = comm.allgather(distributed.latest("z"))
    for other in gathered:
        np.testing.assert_array_equal(other, gathered[0])


class RankDependent(cp.Participant):
    def __init__(self, name, comm, read, write):
        self.name, self.comm, self.read, self.write = name, comm, read, write

    def interface_points(self, mesh_name):
        return np.arange(3.0)[:, None]

    def solve(self, inputs):
        return {self.write: 0.5 * inputs[self.read] + self.comm.Get_rank()}


def test_check_replicated_catches_rank_dependent_outputs(comm):
    if comm.Get_size() == 1:
        pytest.skip("needs several ranks")
    participants = [RankDependent("A", comm, "b", "a"), RankDependent("B", comm, "a", "b")]
    data = [cp.Data("a", "m", 1, "A", ("B",)), cp.Data("b", "m", 1, "B", ("A",))]
    scheme = cp.build_scheme({"verbose": False, "check_replicated": True,
                              "convergence": [{"type": "relative", "limit": 1e-8}]},
                             participants, data, comm=comm)
    with pytest.raises(RuntimeError, match="returned different values of 'a' on different MPI ranks"):
        scheme.solve()


def test_mpirun_two_ranks_matches_serial(comm):
    if comm.Get_size() > 1 or "OMPI_COMM_WORLD_SIZE" in os.environ:
        pytest.skip("already running under mpirun")
    if shutil.which("mpirun") is None:
        pytest.skip("mpirun not available")
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", PYTHONUNBUFFERED="1")
    cmd = ["mpirun", "-n", "2", sys.executable, str(HERE / "coupling_mpi_toy.py")]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300,
                          cwd=str(HERE.parents[1]))
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    record = json.loads([ln for ln in proc.stdout.splitlines() if ln.strip()][-1])
    assert record["ranks"] == 2
    assert record["iterations"] == record["serial_iterations"]
    assert record["max_difference"] <= 1e-12 * max(1.0, np.max(np.abs(record["z"])))
    serial, _ = mpi_toy.solve(SerialComm())
    np.testing.assert_allclose(np.array(record["z"]), serial.latest("z").ravel(), rtol=1e-12, atol=1e-14)
