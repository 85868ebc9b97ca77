"""The iterative (Krylov + multigrid) path of the field solvers, ``femtools.krylov``.

References: the direct (MUMPS) solve of the same discrete system, to 1e-8
relative (the Krylov tolerance is 1e-11 relative to the right-hand side, and
the preconditioned operators are well conditioned); the closed forms of the
existing cases are then those of tests/test_cell.py and tests/test_fluid.py.
Iteration counts bounded under refinement and across the parameters are a
property of the preconditioner: the bound asserted is the coarsest count
times 1.5 plus 5 (a mesh-independent preconditioner; the counts seen grow by
a few iterations per level at most).
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from dolfinx import fem

from cell import NeoHookeanCellSolver, meshes
from femtools.errors import LinearSolveError
from fluid import FluidInterface, StokesSolver

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "mpi_scripts"))
from fluid_cases import BOTTOM, INLET, OUTLET, TOP, channel_mesh  # noqa: E402

COMM = MPI.COMM_WORLD
E_L, NU_L, A_L, B_L, P_L = 1.0, 0.3, 1.0, 2.0, 1e-8     # the Lame case of tests/test_cell.py


def relative_difference(a: fem.Function, b: fem.Function) -> float:
    """max |a - b| / max |b| over the owned entries of all ranks."""
    n = a.function_space.dofmap.index_map.size_local * a.function_space.dofmap.index_map_bs
    diff = COMM.allreduce(float(np.abs(a.x.array[:n] - b.x.array[:n]).max(initial=0.0)), op=MPI.MAX)
    ref = COMM.allreduce(float(np.abs(b.x.array[:n]).max(initial=0.0)), op=MPI.MAX)
    return diff / ref


def bounded(counts: list[int]) -> bool:
    """The finest count is at most 1.5 times the coarsest plus 5."""
    return max(counts) <= 1.5 * counts[0] + 5


# --------------------------------------------------------------------------- the cell
def lame_cell(h: float, solver: str, mu_factor: float = 1.0, lmbda_factor: float = 1.0, load: float = P_L,
              petsc_options: dict | None = None) -> NeoHookeanCellSolver:
    """The quarter annulus under inner pressure with its symmetry lines (tests/test_cell.py)."""
    msh, ft = meshes.annulus(A_L, B_L, h, quarter=True)
    mu = mu_factor * E_L / (2 * (1 + NU_L))
    lmbda = lmbda_factor * E_L * NU_L / ((1 + NU_L) * (1 - 2 * NU_L))
    p = fem.Constant(msh, PETSc.ScalarType(load))
    return NeoHookeanCellSolver(msh, ft, mu=mu, lmbda=lmbda, tractions=[(meshes.INNER, -p * ufl.FacetNormal(msh))],
                                symmetry=[(meshes.XAXIS, 1), (meshes.YAXIS, 0)], solver=solver,
                                petsc_options=petsc_options)


def cell_iterations(s: NeoHookeanCellSolver) -> int:
    return max(s._newton.solver.iterations)


def test_cell_iterative_equals_direct():
    """CG + GAMG (rigid-body near-null space) gives the direct answer, at Table-1-like and large loads."""
    for load in (P_L, 1e-2):
        direct, iterative = lame_cell(0.1, "direct", load=load), lame_cell(0.1, "iterative", load=load)
        direct.solve()
        iterative.solve()
        assert iterative._newton.solver.ksp.getType() == "cg"        # the Jacobian is symmetric
        assert relative_difference(iterative.u, direct.u) < 1e-8, load


def test_cell_iterations_bounded_under_refinement_and_moduli():
    """Krylov iterations at three mesh levels and with the moduli x0.1 and x10 (model.md §5's sweep:
    mu_c and lambda_c together, the Poisson ratio fixed), relative to the loads' scale."""
    levels = [cell_iterations(_solved(lame_cell(h, "iterative"))) for h in (0.2, 0.1, 0.05)]
    moduli = [cell_iterations(_solved(lame_cell(0.05, "iterative", f, f))) for f in (0.1, 10.0)]
    print(f"\ncell CG iterations: levels h = 0.2, 0.1, 0.05: {levels}; moduli x0.1, x10 at h = 0.05: {moduli}")
    assert bounded(levels), levels
    assert max(moduli) <= 1.5 * levels[-1] + 5, (levels, moduli)


def _solved(s):
    s.solve()
    return s


def test_cell_zero_load_gives_zero():
    s = _solved(lame_cell(0.2, "iterative", load=0.0))
    assert COMM.allreduce(float(np.abs(s.u.x.array).max(initial=0.0)), op=MPI.MAX) == 0.0
    assert s._newton.solver.iterations[0] == 0


def test_cell_failed_krylov_solve_names_the_field():
    s = lame_cell(0.1, "iterative", petsc_options={"ksp_max_it": 2})
    with pytest.raises(LinearSolveError, match=r"cell: .*DIVERGED_MAX_IT after 2 iterations"):
        s.solve()


def test_solver_choice_is_checked():
    with pytest.raises(ValueError, match="solver must be one of"):
        lame_cell(0.4, "krylov")


# --------------------------------------------------------------------------- Stokes
L_C, H_C, MU_C, U_C = 4.0, 1.0, 0.7, 1.3


def channel(h: float, solver: str, inflow: float = U_C, petsc_options: dict | None = None) -> StokesSolver:
    """The channel of tests/test_fluid.py: parabolic inflow, no slip on top, Robin wall at the bottom."""
    msh, ft = channel_mesh(L_C, H_C, h)
    return StokesSolver(
        msh, ft, viscosity=MU_C,
        velocity_bcs=[(INLET, lambda x: np.vstack((4 * inflow * x[1] * (H_C - x[1]) / H_C**2, 0 * x[0]))),
                      (TOP, (0.0, 0.0))],
        component_bcs=[(OUTLET, 1, lambda x: 0.0 * x[0])],
        interfaces={"wall": FluidInterface(BOTTOM, normal="robin", tangential="robin", alpha_n=1.0, alpha_t=1.0)},
        solver=solver, petsc_options=petsc_options)


def stokes_iterations(s: StokesSolver) -> int:
    return max(s._solver.solver.iterations)


def test_stokes_iterative_equals_direct():
    """MINRES with diag(GAMG, SSOR(M_p / mu)) gives the direct answer, also after new interface data."""
    direct, iterative = channel(0.1, "direct"), channel(0.1, "iterative")
    for s in (direct, iterative):
        s.solve()
    assert relative_difference(iterative.w, direct.w) < 1e-8
    g = np.tile([0.3, -0.2], (direct.interface_points("wall").shape[0], 1))
    for s in (direct, iterative):
        s.set_interface_data("wall", robin_normal=g, robin_tangential=g)
        s.solve()
    assert relative_difference(iterative.w, direct.w) < 1e-8
    assert iterative._solver.solver.setups == 1        # the preconditioner is reused


def test_stokes_iterations_bounded_under_refinement():
    levels = [stokes_iterations(_solved(channel(h, "iterative"))) for h in (0.2, 0.1, 0.05)]
    print(f"\nStokes MINRES iterations, h = 0.2, 0.1, 0.05: {levels}")
    assert bounded(levels), levels


def test_stokes_zero_data_gives_zero():
    s = _solved(channel(0.2, "iterative", inflow=0.0))
    assert COMM.allreduce(float(np.abs(s.w.x.array).max(initial=0.0)), op=MPI.MAX) == 0.0
