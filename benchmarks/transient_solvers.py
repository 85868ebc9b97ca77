"""Back-substitutions with the time-dependent gel's kept Jacobian: MUMPS against the alternatives.

    .venv/bin/python benchmarks/transient_solvers.py [--case shear] [--solves 20]

Runs a short time-dependent device run (default mesh, serial; its output goes
to a temporary directory), keeps the first matrix the gel factorises for a
time step (its Jacobian at rest with the step's rate term), and for each
direct solver prints the factorisation time, the mean time of one
back-substitution and the relative residual of the solution:

* MUMPS LU (what the run uses; with ``PETSC_OPTIONS=-mat_mumps_icntl_4 2``
  MUMPS prints its factors' sizes) and MUMPS LDLᵀ; the latter of the symmetric
  part (A + Aᵀ)/2, a matrix of the same pattern, for its timing only (the
  gel's transient Jacobian is not symmetric);
* PETSc's own LU with its nested-dissection ordering (serial, no pivoting);
* UMFPACK and SuperLU.

Timings are printed, never asserted.
"""

from __future__ import annotations

import argparse
import tempfile
import time

from petsc4py import PETSc

import femtools.linalg as linalg
from gelcell.cli import main as gelcell_main

SOLVERS = [("MUMPS LU", "lu", "mumps", {}, False), ("MUMPS LDLt (of (A + At)/2)", "cholesky", "mumps", {}, True),
           ("PETSc LU, nested dissection", "lu", "petsc", {"pc_factor_mat_ordering_type": "nd"}, False),
           ("UMFPACK", "lu", "umfpack", {}, False), ("SuperLU", "lu", "superlu", {}, False)]


def transient_gel_matrix(case: str) -> tuple[PETSc.Mat, int]:
    """The last matrix the gel assembles to factorise in a one-window run of ``case`` (its time
    step's), and how many it assembled."""
    kept = []
    assemble = linalg.NewtonSolver._assemble_jacobian

    def keep(self):
        assemble(self)
        if self.name == "gel":
            kept.append(self.A.copy())

    linalg.NewtonSolver._assemble_jacobian = keep
    try:
        with tempfile.TemporaryDirectory() as out:
            gelcell_main(["run", case, "--transient", "--t-end", "1e-9", "--quiet", "--no-figures",
                          "--out", f"{out}/run"])
    finally:
        linalg.NewtonSolver._assemble_jacobian = assemble
    return kept[-1], len(kept)


def time_solver(A: PETSc.Mat, pc_type: str, package: str, options: dict, prefix: str, solves: int):
    """(factorisation s, one back-substitution ms, relative residual) of ``package`` on ``A``."""
    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOptionsPrefix(prefix)
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType(pc_type)
    ksp.getPC().setFactorSolverType(package)
    db = PETSc.Options()
    for key, value in options.items():
        db[prefix + key] = value
    ksp.setFromOptions()
    t0 = time.perf_counter()
    ksp.setUp()
    factor = time.perf_counter() - t0
    b = A.createVecRight()
    b.setRandom()
    x, r = b.duplicate(), b.duplicate()
    ksp.solve(b, x)                     # the first solve may allocate
    t0 = time.perf_counter()
    for _ in range(solves):
        ksp.solve(b, x)
    solve = (time.perf_counter() - t0) / solves
    A.mult(x, r)
    r.axpy(-1.0, b)
    return factor, 1e3 * solve, r.norm() / b.norm()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default="shear", choices=("shear", "normal"))
    ap.add_argument("--solves", type=int, default=20)
    args = ap.parse_args()
    A, assembled = transient_gel_matrix(args.case)
    At = A.copy()
    At.transpose()
    S = A.copy()
    S.axpy(1.0, At)
    S.scale(0.5)
    S.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    print(f"{args.case}: the gel's time-step Jacobian (the last of {assembled} it assembled), "
          f"{A.getSize()[0]} unknowns, {A.getInfo()['nz_used']:.0f} entries")
    for i, (label, pc_type, package, options, symmetric) in enumerate(SOLVERS):
        try:
            f, s, res = time_solver(S if symmetric else A, pc_type, package, options, f"s{i}_", args.solves)
            print(f"  {label:32s} factorisation {f:6.3f} s  back-substitution {s:6.2f} ms  residual {res:.1e}")
        except PETSc.Error as exc:
            print(f"  {label:32s} failed ({exc})")


if __name__ == "__main__":
    main()
