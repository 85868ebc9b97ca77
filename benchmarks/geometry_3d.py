"""The built-in 3D devices (model.md section 10): mesh sizes per region and the errors of their measures.

    .venv/bin/python benchmarks/geometry_3d.py [--sizes 6 4 3 2] [--height 0.4] [--walls noslip]

For each device (shear, normal, each with its default cell) and each size
factor: tetrahedra per region, Γ2 facets, the build time (gmsh + dolfinx
meshes, mesh cache off) and the largest relative error of a volume or area
against ``closed_form_measures_3d`` (the flat ones are exact to rounding; the
largest is the cell's: its hemisphere or quarter sphere).  Rank 0 prints.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from mpi4py import MPI

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
from geometry3d_measures import errors, measure  # noqa: E402

from gelcell.case import CaseParameters  # noqa: E402
from gelcell.case.devices import NormalGeometry, ShearGeometry  # noqa: E402
from gelcell.case.meshsizes import MeshSizes  # noqa: E402


def _row(case: str, size: float, height: float, walls: str) -> str:
    g = (ShearGeometry if case == "shear" else NormalGeometry)(chip_height=height, walls=walls)
    params = CaseParameters(case=case, geometry=g, mesh=MeshSizes(size_factor=size))
    t0 = time.perf_counter()
    m = measure(params)
    seconds = time.perf_counter() - t0
    err = errors(params, m)
    worst = max(err, key=err.get)
    c = m["counts"]
    return (f"{case:7s} {size:5.2f} {c['fluid']['cells']:9d} {c['gel']['cells']:9d} {c['cell']['cells']:7d} "
            f"{c['cell']['facets'].get('GAMMA2', 0):6d} {seconds:7.1f}  {err[worst]:.2e} {'/'.join(worst)}  "
            f"Γ2 {err[('cell', 'GAMMA2')]:.2e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[6.0, 4.0, 3.0, 2.0])
    ap.add_argument("--height", type=float, default=0.4)
    ap.add_argument("--walls", default="noslip")
    args = ap.parse_args()
    os.environ["GELCELL_MESH_CACHE"] = "0"
    if MPI.COMM_WORLD.rank == 0:
        print(f"H = {args.height}, walls = {args.walls}, {MPI.COMM_WORLD.size} rank(s)")
        print("device   size  fluid tets  gel tets  cell tets  Γ2 tri  build s  worst rel. error")
    for case in ("shear", "normal"):
        for size in args.sizes:
            line = _row(case, size, args.height, args.walls)
            if MPI.COMM_WORLD.rank == 0:
                print(line, flush=True)


if __name__ == "__main__":
    main()
