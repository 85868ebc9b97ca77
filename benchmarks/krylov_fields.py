"""Direct (MUMPS) against iterative (femtools.krylov) solves per field, at a few 2D mesh sizes.

    .venv/bin/python benchmarks/krylov_fields.py                  # the default sizes
    .venv/bin/python benchmarks/krylov_fields.py --levels 0.1 0.05 0.025

Per field and mesh size: the global number of unknowns, the wall time of the
first solve (set-up: factorisation or preconditioner; and the solve) and of a
second solve with new data where the case has some (Stokes: new Robin data;
back-substitution or a warm-started Krylov solve), the Krylov iterations of each, and the relative difference of the two
answers.  The cases are those of tests/test_krylov.py: the cell's quarter
annulus (Lame), the Stokes channel with a Robin wall, the enclosed Stokes
square with a pinned pressure, the gel's chamber (steady, and one backward-Euler
step of 1e-6 from rest: the undrained start).  The gel's unit square has 1/h
cells a side.  Prints only.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from mpi4py import MPI

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
import numpy as np  # noqa: E402

from test_krylov import (channel, chamber_mesh, enclosed_mms, gel_chamber, lame_cell,  # noqa: E402
                         relative_difference, unit_square)

COMM = MPI.COMM_WORLD


def _cell(h, solver):
    s = lame_cell(h, solver)
    return s, s.u, (lambda: s._newton.solver), None


def _stokes(h, solver):
    s = channel(h, solver)
    g = np.tile([0.3, -0.2], (s.interface_points("wall").shape[0], 1))
    return s, s.w, (lambda: s._solver.solver), (lambda: s.set_interface_data("wall", robin_normal=g))


_MESHES: dict[tuple[str, int], object] = {}     # one mesh per size for both solvers (a partition may differ per call)


def _mesh(kind, n):
    """One mesh per kind and size for both solvers."""
    if (kind, n) not in _MESHES:
        _MESHES[kind, n] = unit_square(n) if kind == "square" else chamber_mesh(n)
    return _MESHES[kind, n]


def _enclosed(h, solver):
    s = enclosed_mms(_mesh("square", int(round(1 / h))), solver)
    return s, s.w, (lambda: s._solver.solver), None


def _gel(h, solver, dt=None):
    n = int(round(1 / h))
    s = gel_chamber(n, solver, dt=dt, mesh=_mesh("chamber", n))
    X = s.interface_points("top")
    T = 3e-10 * np.column_stack([0.2 * np.cos(np.pi * X[:, 0]), -1 + 0 * X[:, 0]]) / s.params.stress_scale
    return s, s.state, (lambda: s.newton.solver), (lambda: s.set_interface_data("top", traction=T))


def _gel_step(h, solver):
    return _gel(h, solver, dt=1e-6)


FIELDS = {"cell": _cell, "stokes": _stokes, "stokes_enclosed": _enclosed, "gel": _gel, "gel_step": _gel_step}


def measure(field: str, h: float) -> dict:
    """Both solvers on one case: unknowns, wall times, Krylov iterations, difference."""
    out = {}
    for solver in ("direct", "iterative"):
        s, unknown, linear, update = FIELDS[field](h, solver)
        COMM.barrier()
        t0 = time.perf_counter()
        s.solve()
        first = time.perf_counter() - t0
        second = float("nan")
        if update is not None:
            update()
            t0 = time.perf_counter()
            s.solve()
            second = time.perf_counter() - t0
        its = list(getattr(linear(), "iterations", []))
        out[solver] = dict(first=COMM.allreduce(first, op=MPI.MAX), second=COMM.allreduce(second, op=MPI.MAX),
                           iterations=its, u=unknown.x.array.copy(), f=unknown)
    out["unknowns"] = out["direct"]["f"].vector.getSize()
    out["difference"] = relative_difference(out["iterative"]["f"], out["direct"]["f"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=float, nargs="+", default=[0.1, 0.05, 0.025])
    parser.add_argument("--fields", nargs="+", default=list(FIELDS), choices=list(FIELDS))
    args = parser.parse_args()
    if COMM.rank == 0:
        print(f"{COMM.size} rank(s)")
        print(f"{'field':16s} {'h':>6s} {'unknowns':>9s} {'direct 1st/2nd s':>17s} "
              f"{'iterative 1st/2nd s':>20s} {'Krylov its':>12s} {'rel. diff':>9s}")
    for field in args.fields:
        for h in args.levels:
            r = measure(field, h)
            d, i = r["direct"], r["iterative"]
            if COMM.rank == 0:
                print(f"{field:16s} {h:6.3f} {r['unknowns']:9d} {d['first']:8.3f}/{d['second']:8.3f} "
                      f"{i['first']:10.3f}/{i['second']:9.3f} {str(i['iterations']):>12s} "
                      f"{r['difference']:9.1e}", flush=True)


if __name__ == "__main__":
    main()
