"""``femtools.linalg.schur_complement`` frees its factorisation (the linearized prior calls it per dt).

It held MUMPS's factors through the Python references to its PC and factor matrix: 40 MB per gel
interface Jacobian on the shear device at mesh size 3, 25 of them in an adaptive run.  Reference:
the resident memory after the first call, against which ten further calls must not grow by more
than two factorisations' worth (the leak grew by ten).
"""

import numpy as np
import pytest
import scipy.sparse as sp

from femtools import linalg


def _resident_mib() -> float:
    with open("/proc/self/status") as fh:
        return next(float(line.split()[1]) / 1024 for line in fh if line.startswith("VmRSS:"))


def _laplacian(n: int) -> sp.csr_matrix:
    """The 5-point Laplacian on an n x n grid plus the identity (regular)."""
    one = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    return (sp.kron(one, sp.identity(n)) + sp.kron(sp.identity(n), one) + sp.identity(n * n)).tocsr()


@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/status"), reason="Linux /proc only")
def test_schur_complement_releases_its_factorisation():
    K = _laplacian(150)
    keep = np.arange(0, K.shape[0], 450)
    before = _resident_mib()
    linalg.schur_complement(K, keep)
    one = _resident_mib() - before              # one factorisation (and the allocator's first growth)
    start = _resident_mib()
    for _ in range(10):
        linalg.schur_complement(K, keep)
    growth = _resident_mib() - start
    assert growth <= 2 * max(one, 1.0), (one, growth)
