"""A distributed PETSc AIJ matrix from a dense numpy array (tests of the linear-algebra helpers)."""

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc


def aij(dense: np.ndarray, comm: MPI.Comm = MPI.COMM_WORLD) -> PETSc.Mat:
    """The nonzeros of ``dense`` (replicated on every rank) as an AIJ matrix; each rank sets its own rows."""
    n = dense.shape[0]
    A = PETSc.Mat().createAIJ([n, n], comm=comm)
    A.setUp()
    start, end = A.getOwnershipRange()
    for i in range(start, end):
        cols = np.flatnonzero(dense[i]).astype(PETSc.IntType)
        A.setValues([i], cols, dense[i, cols])
    A.assemble()
    return A
