"""Poiseuille flow in a rectangular duct on tetrahedra: errors against the series and observed rates.

    .venv/bin/python benchmarks/fluid_duct_3d.py [--levels 4]

The duct of tests/test_fluid_3d.py (W x H = 1 x 0.5, L = 0.5, pressure-driven,
no slip on its four walls; ``tests/fluid3d_cases.py``) at levels n = (2, 4, 2) 2^k:
relative L2 errors of V and P against ``gelcell.geometry.layout.duct_poiseuille``,
the rates between consecutive levels, the unknowns and the wall time per level.
Runs under mpirun as well (rank 0 prints).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from mpi4py import MPI

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
from fluid3d_cases import BACK, DP, FLOOR, FRONT, LID, MU, box_mesh, channel, relative_errors  # noqa: E402

from gelcell.geometry.layout import duct_poiseuille, duct_poiseuille_peak  # noqa: E402

W, H, L = 1.0, 0.5, 0.5


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, default=3, help="number of mesh levels (default 3)")
    levels = parser.parse_args().levels
    comm = MPI.COMM_WORLD
    peak = duct_poiseuille_peak(W, H, DP / L, MU)
    rows = []
    for k in range(levels):
        n = (2 << k, 4 << k, 2 << k)
        t0 = time.perf_counter()
        solver = channel(*box_mesh((L, W, H), n, comm=comm), walls=(FRONT, BACK, FLOOR, LID))
        errors = relative_errors(solver, lambda y, z: duct_poiseuille(y, z, W, H, peak), L)
        unknowns = solver.W.dofmap.index_map.size_global * solver.W.dofmap.index_map_bs
        rows.append((n, unknowns, *errors, time.perf_counter() - t0))
    if comm.rank == 0:
        print(f"{'cubes':>12} {'unknowns':>9} {'L2 err V':>10} {'rate':>5} {'L2 err P':>10} {'rate':>5} {'time s':>7}")
        for k, (n, unknowns, eV, eP, seconds) in enumerate(rows):
            rV = f"{np.log2(rows[k - 1][2] / eV):5.2f}" if k else "  -  "
            rP = f"{np.log2(rows[k - 1][3] / eP):5.2f}" if k else "  -  "
            print(f"{str(n):>12} {unknowns:9d} {eV:10.3e} {rV} {eP:10.3e} {rP} {seconds:7.1f}")


if __name__ == "__main__":
    main()
