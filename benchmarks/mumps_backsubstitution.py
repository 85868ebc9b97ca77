"""MUMPS back-substitutions on 1 and 2 MPI ranks: what limits the device's parallel speed-up.

    .venv/bin/python benchmarks/mumps_backsubstitution.py [--n 300] [--solves 30]
    mpirun -n 2 .venv/bin/python benchmarks/mumps_backsubstitution.py

Factorises the 5-point Laplacian of an n x n grid (LDL^T, the settings of
``femtools.linalg.DirectSolver``: MUMPS's own ordering, distributed right-hand side on
several ranks) and prints the factorisation time, the number of entries in
the factors and the mean time of one back-substitution.  Timings are printed,
never asserted.  On the development machine (docs/performance.md) a
back-substitution gains little from a second rank, unlike the assembly.
"""

from __future__ import annotations

import argparse
import time

from mpi4py import MPI
from petsc4py import PETSc

from femtools.linalg import DirectSolver


def laplacian(n: int, comm) -> PETSc.Mat:
    """The 5-point Laplacian of an n x n grid, rows distributed by PETSc."""
    A = PETSc.Mat().createAIJ([n * n, n * n], nnz=5, comm=comm)
    start, end = A.getOwnershipRange()
    for i in range(start, end):
        r, c = divmod(i, n)
        A.setValue(i, i, 4.0)
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= rr < n and 0 <= cc < n:
                A.setValue(i, rr * n + cc, -1.0)
    A.assemble()
    return A


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=300, help="grid points per side")
    ap.add_argument("--solves", type=int, default=30)
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    A = laplacian(args.n, comm)
    solver = DirectSolver(comm, "laplacian", kind="cholesky")
    solver.set_operator(A)
    t0 = time.perf_counter()
    solver.factorize()
    factor = time.perf_counter() - t0
    b, x = A.createVecLeft(), A.createVecRight()
    b.set(1.0)
    solver.solve(b, x)                  # the first solve may allocate
    comm.barrier()
    t0 = time.perf_counter()
    for _ in range(args.solves):
        solver.solve(b, x)
    comm.barrier()
    solve = (time.perf_counter() - t0) / args.solves
    entries = solver.ksp.getPC().getFactorMatrix().getMumpsInfog(29)
    if comm.rank == 0:
        print(f"{comm.size} rank(s), {args.n * args.n} unknowns: factorisation {factor:.3f} s, "
              f"{entries:.3g} entries in the factors, one back-substitution {1e3 * solve:.2f} ms")


if __name__ == "__main__":
    main()
