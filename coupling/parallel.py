"""MPI helpers: replicated interface arrays from distributed participants.

The coupling library works on *replicated* arrays: every MPI rank holds the
full interface vectors and performs the same arithmetic on them.  A
participant whose interface degrees of freedom are distributed over ranks
assembles the replicated array with :func:`gather_rows` (each rank passes the
rows it owns together with their global row numbers) and extracts its own rows
from a replicated array with :func:`scatter_rows`.

mpi4py is optional, and neither ``import coupling`` nor a serial
``build_scheme`` imports it (importing it initialises MPI): without a
``comm``, a scheme runs on ``MPI.COMM_WORLD`` only if the application has
imported mpi4py already or an MPI launcher started more than one process
(:func:`default_comm`), else on the :class:`SerialComm` stand-in.
"""

from __future__ import annotations

import os
import sys
from typing import Any

import numpy as np

__all__ = ["SerialComm", "default_comm", "gather_rows", "scatter_rows"]


class SerialComm:
    """Minimal single-process stand-in for an ``mpi4py`` communicator.

    Implements exactly the collective operations the coupling library uses
    (``bcast``, ``Bcast``, ``allgather``, ``gather``, ``allreduce``,
    ``Barrier``) with the
    trivial one-rank semantics.
    """

    rank = 0
    size = 1

    def Get_rank(self) -> int:  # noqa: N802 (mpi4py spelling)
        """Return 0, the only rank."""
        return 0

    def Get_size(self) -> int:  # noqa: N802 (mpi4py spelling)
        """Return 1, the number of ranks."""
        return 1

    def bcast(self, obj: Any, root: int = 0) -> Any:
        """Return ``obj`` unchanged."""
        return obj

    def Bcast(self, buf: Any, root: int = 0) -> None:  # noqa: N802 (mpi4py spelling)
        """Do nothing: the buffer already holds the root's data."""

    def allgather(self, obj: Any) -> list:
        """Return ``[obj]``."""
        return [obj]

    def gather(self, obj: Any, root: int = 0) -> list:
        """Return ``[obj]``."""
        return [obj]

    def allreduce(self, obj: Any, op: Any = None) -> Any:
        """Return ``obj`` (the reduction over one rank)."""
        return obj

    def Barrier(self) -> None:  # noqa: N802 (mpi4py spelling)
        """Do nothing."""


#: the world size an MPI launcher gives each process (Open MPI, MPICH/Intel MPI's PMI, MVAPICH)
_LAUNCHER_SIZES = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "MV2_COMM_WORLD_SIZE")


def _launched_in_parallel() -> bool:
    """Whether an MPI launcher started this process as one of several."""
    for key in _LAUNCHER_SIZES:
        try:
            if int(os.environ.get(key, "1")) > 1:
                return True
        except ValueError:
            continue
    return False


def default_comm() -> Any:
    """``MPI.COMM_WORLD`` if mpi4py is imported already or the process is one of several MPI ranks, else a
    :class:`SerialComm` (so that a serial run neither imports nor initialises MPI)."""
    if "mpi4py.MPI" not in sys.modules and not _launched_in_parallel():
        return SerialComm()
    try:
        from mpi4py import MPI
    except ImportError:
        return SerialComm()
    return MPI.COMM_WORLD


def gather_rows(comm: Any, global_ids: np.ndarray, local_values: np.ndarray,
                n_global: int) -> np.ndarray:
    """Assemble a replicated ``(n_global, ...)`` array from rows owned by each rank.

    Every rank passes the rows it owns, ``local_values[i]`` being global row
    ``global_ids[i]``.  Every global row must be provided by at least one rank;
    a row provided several times (e.g. a shared vertex) takes the value of the
    lowest rank that provides it (its first occurrence there), so the result
    is the same on every rank.

    Args:
        comm: An mpi4py communicator (or :class:`SerialComm`).
        global_ids: Integer array ``(n_local,)`` of global row numbers in
            ``[0, n_global)``.
        local_values: Array ``(n_local,)`` or ``(n_local, k)`` of row values.
        n_global: Number of global rows.

    Returns:
        The replicated array of shape ``(n_global,) + local_values.shape[1:]``.

    Raises:
        ValueError: If shapes disagree, an id is out of range, or a global row
            is provided by no rank.
    """
    ids = np.asarray(global_ids, dtype=np.int64).reshape(-1)
    vals = np.asarray(local_values)
    if vals.shape[0] != ids.shape[0]:
        raise ValueError(f"gather_rows: {ids.shape[0]} global ids but {vals.shape[0]} local rows")
    if ids.size and (ids.min() < 0 or ids.max() >= n_global):
        raise ValueError(f"gather_rows: global ids must lie in [0, {n_global}), got "
                         f"[{ids.min()}, {ids.max()}]")
    pieces = comm.allgather((ids, vals))
    trailing = {p[1].shape[1:] for p in pieces if p[1].shape[0] > 0}
    if len(trailing) > 1:
        raise ValueError(f"gather_rows: ranks disagree on the row shape: {sorted(trailing)}")
    row_shape = trailing.pop() if trailing else vals.shape[1:]
    dtype = np.result_type(*[p[1].dtype for p in pieces])
    out = np.zeros((n_global,) + tuple(row_shape), dtype=dtype)
    filled = np.zeros(n_global, dtype=bool)
    for rank_ids, rank_vals in pieces:  # rank order: the lowest rank wins
        unique_ids, first = np.unique(rank_ids, return_index=True)  # first occurrence on a rank
        new = ~filled[unique_ids]
        out[unique_ids[new]] = rank_vals[first[new]]
        filled[unique_ids[new]] = True
    if not filled.all():
        missing = np.flatnonzero(~filled)
        raise ValueError(f"gather_rows: {missing.size} of {n_global} global rows were provided "
                         f"by no rank (first: {missing[:5].tolist()})")
    return out


def scatter_rows(comm: Any, global_ids: np.ndarray, global_values: np.ndarray) -> np.ndarray:
    """Extract this rank's rows from a replicated array.

    Args:
        comm: An mpi4py communicator (or :class:`SerialComm`); the array is
            replicated, so no communication happens.
        global_ids: Global row numbers owned by this rank.
        global_values: The replicated array ``(n_global, ...)``.

    Returns:
        ``global_values[global_ids]`` as a new array.
    """
    ids = np.asarray(global_ids, dtype=np.int64).reshape(-1)
    values = np.asarray(global_values)
    if ids.size and (ids.min() < 0 or ids.max() >= values.shape[0]):
        raise ValueError(f"scatter_rows: global ids must lie in [0, {values.shape[0]}), got "
                         f"[{ids.min()}, {ids.max()}]")
    return values[ids].copy()
