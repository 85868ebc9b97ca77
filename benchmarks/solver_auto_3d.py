"""Direct (MUMPS) against iterative (CG + GAMG) on a 3D P2 elasticity problem: where ``--solver auto`` switches.

    .venv/bin/python benchmarks/solver_auto_3d.py                 # n = 4 6 8 10 12
    .venv/bin/python benchmarks/solver_auto_3d.py --levels 8 16

The cell solver (``cell.NeoHookeanCellSolver``, small load: one Newton step) on
a unit cube of n^3 x 6 tetrahedra, clamped at z = 0, a traction on z = 1.  Per
level: the global unknowns, the wall time of the solve (factorisation or
preconditioner set-up and the Krylov solve) on each path, their ratio, the
Krylov iterations, MUMPS's memory (INFOG(22): MB used by the factorisation,
summed over the ranks) and the relative difference.  Prints only.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mpi4py import MPI
from petsc4py import PETSc

from dolfinx import fem, mesh as dmesh

from cell import NeoHookeanCellSolver

COMM = MPI.COMM_WORLD
BOTTOM, TOP = 1, 2


def cube(n: int):
    msh = dmesh.create_box(COMM, [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], [n, n, n], dmesh.CellType.tetrahedron)
    fdim = msh.topology.dim - 1
    facets = [dmesh.locate_entities_boundary(msh, fdim, lambda x, z=z: np.isclose(x[2], z)) for z in (0.0, 1.0)]
    index = np.concatenate(facets).astype(np.int32)
    values = np.concatenate([np.full(len(f), tag, dtype=np.int32) for f, tag in zip(facets, (BOTTOM, TOP))])
    order = np.argsort(index)
    return msh, dmesh.meshtags(msh, fdim, index[order], values[order])


def solve(msh, ft, solver: str):
    t = fem.Constant(msh, PETSc.ScalarType((1e-8, 0.0, -1e-8)))
    s = NeoHookeanCellSolver(msh, ft, mu=0.4, lmbda=0.6, tractions=[([TOP], t)],
                             dirichlet=[([BOTTOM], 0.0)], solver=solver)
    COMM.barrier()
    t0 = time.perf_counter()
    s.solve()
    wall = COMM.allreduce(time.perf_counter() - t0, op=MPI.MAX)
    linear = s._newton.solver
    its = list(getattr(linear, "iterations", []))
    memory = linear.ksp.getPC().getFactorMatrix().getMumpsInfog(22) if solver == "direct" else None
    return s.u, wall, its, memory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, nargs="+", default=[4, 6, 8, 10, 12])
    args = parser.parse_args()
    if COMM.rank == 0:
        print(f"{COMM.size} rank(s)\n{'n':>3s} {'unknowns':>9s} {'direct s':>9s} {'iterative s':>12s} "
              f"{'ratio':>6s} {'Krylov its':>12s} {'MUMPS MB':>9s} {'rel. diff':>9s}")
    for n in args.levels:
        msh, ft = cube(n)
        ud, td, _, memory = solve(msh, ft, "direct")
        ui, ti, its, _ = solve(msh, ft, "iterative")
        nloc = ud.function_space.dofmap.index_map.size_local * 3
        diff = COMM.allreduce(float(np.abs(ui.x.array[:nloc] - ud.x.array[:nloc]).max(initial=0)), op=MPI.MAX)
        ref = COMM.allreduce(float(np.abs(ud.x.array[:nloc]).max(initial=0)), op=MPI.MAX)
        if COMM.rank == 0:
            print(f"{n:3d} {ud.vector.getSize():9d} {td:9.3f} {ti:12.3f} {ti / td:6.2f} {str(its):>12s} "
                  f"{memory:9d} {diff / ref:9.1e}", flush=True)


if __name__ == "__main__":
    main()
