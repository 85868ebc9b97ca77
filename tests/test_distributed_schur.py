"""The distributed condensation and sub-matrix gathers of ``femtools.linalg`` (on 1 and 2 ranks).

References: numpy's dense formula S = K_kk - K_kr K_rr^-1 K_rk and the dense matrix itself;
the instrumentation hook ``femtools.linalg.GATHERED`` shows that only the small objects travel.
"""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from femtools import linalg
from dense_aij import aij
from femtools.errors import SingularSystemError

COMM = MPI.COMM_WORLD


def _matrix(n: int, symmetric: bool) -> np.ndarray:
    rng = np.random.default_rng(5)
    M = np.where(rng.random((n, n)) < 0.05, rng.standard_normal((n, n)), 0.0)
    M = M + M.T if symmetric else M
    return M + np.diag(np.full(n, 6.0))


@pytest.mark.parametrize("symmetric", [False, True])
def test_distributed_schur_complement_is_the_condensed_matrix(monkeypatch, symmetric):
    """S of a sparse matrix onto kept indices in any order (more than one block of columns; kept
    rows on both ranks) equals the dense formula to 1e-12, and only S (nk x nk) is gathered."""
    n = 150
    dense = _matrix(n, symmetric)
    keep = np.array([7, 3, 90, 41, 149, 0, 75, 76, 120, 11])
    rest = np.setdiff1d(np.arange(n), keep)
    expected = dense[np.ix_(keep, keep)] - dense[np.ix_(keep, rest)] @ np.linalg.solve(
        dense[np.ix_(rest, rest)], dense[np.ix_(rest, keep)])
    monkeypatch.setattr(linalg, "SCHUR_BLOCK", 4)
    monkeypatch.setattr(linalg, "GATHERED", [])
    A = aij(dense)
    S = linalg.distributed_schur_complement(A, keep)
    assert np.abs(S - expected).max() <= 1e-12 * np.abs(expected).max()
    assert linalg.GATHERED == [("schur", keep.size, keep.size, keep.size ** 2)]
    assert linalg.distributed_schur_complement(A, np.empty(0, dtype=int)).shape == (0, 0)


def test_distributed_schur_complement_refuses_a_singular_eliminated_block():
    """A_rr singular (a row coupled to kept columns only) raises instead of a garbage S."""
    n = 40
    dense = _matrix(n, True)
    dense[5, :] = 0.0
    dense[:, 5] = 0.0
    dense[5, 6] = dense[6, 5] = 1.0
    with pytest.raises(SingularSystemError):
        linalg.distributed_schur_complement(aij(dense), np.array([6, 20]))


def test_gather_submatrix_and_entries_are_the_selected_part_only(monkeypatch):
    """A[rows][:, cols] and x[dofs] for rows/columns in any order equal the dense selection; the
    gathered objects are of the selection's size."""
    n = 60
    dense = _matrix(n, False)
    rows, cols = np.array([59, 2, 30, 31, 10]), np.array([31, 0, 58, 30])
    monkeypatch.setattr(linalg, "GATHERED", [])
    B = linalg.gather_submatrix(aij(dense), rows, cols)
    assert np.array_equal(B.toarray(), dense[np.ix_(rows, cols)])
    x = PETSc.Vec().createMPI(n, comm=COMM)
    start, end = x.getOwnershipRange()
    x.array[:] = np.arange(start, end) ** 2
    assert np.array_equal(linalg.gather_entries(x, rows), rows.astype(float) ** 2)
    assert [g[:3] for g in linalg.GATHERED] == [("submatrix", rows.size, cols.size), ("entries", rows.size, 1)]
