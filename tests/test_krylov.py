"""The iterative (Krylov + multigrid) path of the field solvers, ``femtools.krylov``.

References: the direct (MUMPS) solve of the same discrete system, to 1e-8
relative (the Krylov tolerance is 1e-11 relative to the right-hand side, and
the preconditioned operators are well conditioned); the closed forms of the
existing cases are then those of tests/test_cell.py, tests/test_fluid.py and tests/test_gel.py.
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
from dolfinx import fem, mesh as dmesh

from cell import NeoHookeanCellSolver, meshes
from cell.meshes import BOTTOM as BOTTOM_C, LEFT, RIGHT, TOP as TOP_C
from femtools.errors import LinearSolveError
from femtools.mesh import BOTTOM as BOTTOM_G, LEFT as LEFT_G, RIGHT as RIGHT_G, TOP as TOP_G, rectangle_mesh
from fluid import FluidInterface, StokesSolver
from fluid.ale import MovingStokesSolver
from gel import GelParameters, PoroelasticGelSolver

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
        # the counters the summary reports: every Newton step's Krylov iterations, none for MUMPS
        assert iterative.stats["krylov_iterations"] == sum(iterative._newton.solver.iterations) > 0
        assert direct.stats["krylov_iterations"] == 0 and direct.stats["solves"] > 0


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


def unit_square(n: int):
    msh = dmesh.create_unit_square(COMM, n, n)
    msh.topology.create_connectivity(1, 2)
    return msh


def enclosed_mms(msh, solver: str) -> StokesSolver:
    """verification.md 1b on the unit square: no slip everywhere, the pressure pinned at a corner."""
    facets = dmesh.exterior_facet_indices(msh.topology)
    ft = dmesh.meshtags(msh, 1, facets, np.full(facets.size, 1, dtype=np.int32))
    x = ufl.SpatialCoordinate(msh)
    pi, sin, cos = np.pi, ufl.sin, ufl.cos
    f = ufl.as_vector((pi * (2 * pi**2 * (1 - 2 * cos(2 * pi * x[0])) * sin(2 * pi * x[1])
                             - sin(pi * x[0]) * cos(pi * x[1])),
                       pi * (-2 * pi**2 * (1 - 2 * cos(2 * pi * x[1])) * sin(2 * pi * x[0])
                             - cos(pi * x[0]) * sin(pi * x[1]))))
    return StokesSolver(msh, ft, viscosity=1.0, velocity_bcs=[(1, (0.0, 0.0))], body_force=f,
                        pressure_pin=(0.0, 0.0), solver=solver)


def test_enclosed_stokes_with_a_pinned_pressure():
    """The pinned pressure's block (krylov.PinnedPressure) keeps the iterations bounded; direct answer."""
    levels = []
    for n in (8, 16, 32):
        msh = unit_square(n)      # one mesh for both: its partition on 2 ranks may differ from call to call
        direct, iterative = _solved(enclosed_mms(msh, "direct")), _solved(enclosed_mms(msh, "iterative"))
        assert relative_difference(iterative.w, direct.w) < 1e-8, n
        levels.append(stokes_iterations(iterative))
    print(f"\nenclosed Stokes MINRES iterations, 8, 16, 32 cells a side: {levels}")
    assert bounded(levels), levels


# --------------------------------------------------------------------------- Stokes on a moving mesh
def moving_channel(h: float, solver: str) -> MovingStokesSolver:
    """The sheared and stretched channel of tests/test_moving_fluid.py (mesh motion included)."""
    msh, ft = meshes.rectangle(2.0, 1.0, h)
    Hc = 1.2

    def motion(X):
        return np.vstack([0.3 * X[1], 0.2 * X[1]])

    def profile(X):
        y = X[1] + 0.2 * X[1]
        return np.vstack([4 * y * (Hc - y) / Hc**2, 0 * y])
    s = MovingStokesSolver(msh, ft, viscosity=0.7, velocity_bcs=[((LEFT, RIGHT), profile), ((BOTTOM_C, TOP_C), (0, 0))],
                           mesh_boundaries={"walls": (LEFT, RIGHT, TOP_C)}, pressure_pin=(0.0, 0.0), solver=solver)
    s.set_boundary_displacement("walls", motion)
    return s


def test_moving_stokes_and_mesh_motion_iterative_equal_direct():
    direct, iterative = _solved(moving_channel(0.25, "direct")), _solved(moving_channel(0.25, "iterative"))
    assert relative_difference(iterative.mesh_displacement, direct.mesh_displacement) < 1e-8
    assert relative_difference(iterative.w, direct.w) < 1e-8
    assert iterative.motion.solver.solver.iterations and iterative.newton.solver.iterations


# --------------------------------------------------------------------------- the gel
def chamber_mesh(n: int):
    """The gel's chamber [0, 1] x [-0.5, 0], n x n cell pairs: build it once for the solvers compared
    (create_rectangle's partition on 2 ranks may differ between calls)."""
    return rectangle_mesh(0.0, -0.5, 1.0, 0.0, n, n)


def gel_chamber(n: int, solver: str, prm: GelParameters | None = None, dt: float | None = None,
                load: float = 1.0, mesh=None) -> PoroelasticGelSolver:
    """The chamber of tests/test_gel.py (_scaled_problem): no-slip bottom, symmetry sides, fluid data on top;
    ``dt``: one backward-Euler step from rest (the undrained start when dt is small); ``mesh``: (mesh,
    facet tags) of :func:`chamber_mesh` (default: built here)."""
    prm = prm or GelParameters.viscous_units(Ca=3e-10)
    msh, ft = mesh or chamber_mesh(n)
    gel = PoroelasticGelSolver(msh, ft, prm, no_slip=BOTTOM_G, symmetry=[((LEFT_G, RIGHT_G), 0)],
                               fluid_interfaces={"top": TOP_G}, solver=solver, transient=dt is not None)
    X = gel.interface_points("top")
    T = prm.Ca * np.column_stack([0.5 * np.sin(np.pi * X[:, 0]), -(1 + 0.3 * np.cos(np.pi * X[:, 0]))])
    V = np.column_stack([0.2 + 0 * X[:, 0], -0.01 * X[:, 0]])
    gel.set_interface_data("top", traction=load * T / prm.stress_scale, velocity=load * V)
    if dt is not None:
        gel.set_time_step(dt, scheme="be")
    return gel


def gel_iterations(g: PoroelasticGelSolver) -> int:
    return g.newton.solver.iterations[0]


@pytest.mark.parametrize("units", ["viscous", "paper"])
def test_gel_iterative_equals_direct(units):
    """GMRES with the block preconditioner gives the direct answer in both unit systems (model.md §5)."""
    prm = GelParameters.viscous_units(Ca=3e-10) if units == "viscous" else GelParameters(Ca=3e-10)
    mesh = chamber_mesh(8)
    direct, iterative = (_solved(gel_chamber(8, kind, prm, mesh=mesh)) for kind in ("direct", "iterative"))
    assert relative_difference(iterative.state, direct.state) < 1e-8
    X = direct.interface_points("top")
    T = prm.Ca * np.column_stack([0.2 * np.cos(np.pi * X[:, 0]), -1 + 0 * X[:, 0]]) / prm.stress_scale
    for s in (direct, iterative):          # new coupling data: the kept preconditioner serves
        s.set_interface_data("top", traction=T)
        s.solve()
    assert relative_difference(iterative.state, direct.state) < 1e-8
    assert iterative.newton.solver.setups == 1


def test_gel_time_step_iterative_equals_direct():
    mesh = chamber_mesh(8)
    direct, iterative = (_solved(gel_chamber(8, kind, dt=1e-6, mesh=mesh)) for kind in ("direct", "iterative"))
    assert relative_difference(iterative.state, direct.state) < 1e-8


def test_gel_iterations_bounded_under_refinement_and_parameters():
    """Three levels, at the device's xi = 4.5e4 (Darcy-dominated, Brinkman length 0.047), at xi / 1000
    (Brinkman-dominated) and a time step from rest of 1e-8 (undrained); more regimes and the variants of
    the pressure block in benchmarks/krylov_gel_preconditioner.py."""
    cases = {"device": {}, "xi / 1000": dict(prm=GelParameters.viscous_units(Ca=3e-10, xi=45.0)),
             "dt 1e-8": dict(dt=1e-8)}
    counts = {name: [gel_iterations(_solved(gel_chamber(n, "iterative", **kw))) for n in (8, 16, 32)]
              for name, kw in cases.items()}
    print(f"\ngel GMRES iterations, 8, 16, 32 cells a side: {counts}")
    reference = counts["device"]
    assert bounded(reference), counts
    for name, levels in counts.items():
        assert max(levels) <= 1.5 * reference[-1] + 5, (name, counts)


def test_gel_zero_data_gives_zero():
    s = _solved(gel_chamber(4, "iterative", load=0.0))
    assert COMM.allreduce(float(np.abs(s.state.x.array).max(initial=0.0)), op=MPI.MAX) == 0.0


def _preconditioner_applications(gel: PoroelasticGelSolver, x: PETSc.Vec) -> tuple[PETSc.Vec, PETSc.Vec]:
    """The gel solver's preconditioner applied to ``x`` by its BlockLowerTriangular sweep and by the
    PCFIELDSPLIT multiplicative sweep it replaces (its inner split)."""
    krylov = gel.newton.solver
    swept, split = x.duplicate(), x.duplicate()
    krylov.ksp.getPC().apply(x, swept)
    krylov._inner.apply(x, split)
    return swept, split


def _norm_of_difference(a: PETSc.Vec, b: PETSc.Vec) -> float:
    d = a.copy()
    d.axpy(-1.0, b)
    return d.norm() / b.norm()


def test_gel_sweep_equals_the_multiplicative_field_split_and_follows_a_new_operator():
    """The sweep over the off-diagonal blocks is PCFIELDSPLIT's multiplicative sweep to round-off, also
    after the operator changed (a time step: the blocks are extracted again at the next set-up)."""
    gel = _solved(gel_chamber(8, "iterative", dt=1e-6))
    x = gel.newton.A.createVecRight()
    x.setRandom()
    assert _norm_of_difference(*_preconditioner_applications(gel, x)) < 1e-12
    before, _ = _preconditioner_applications(gel, x)
    setups = gel.newton.solver.setups
    gel.set_time_step(1e-8, scheme="be")
    gel.solve()
    assert gel.newton.solver.setups > setups          # the new operator set the preconditioner up again
    after, split = _preconditioner_applications(gel, x)
    assert _norm_of_difference(after, split) < 1e-12
    assert _norm_of_difference(after, before) > 1e-6  # and it is the new operator's


def test_the_krylov_newton_iterate_holds_the_dirichlet_values_exactly():
    """After a Krylov solve the Newton correction's Dirichlet rows are set exactly, so the next residual
    needs no lifting (a Krylov method leaves them to round-off)."""
    gel = _solved(gel_chamber(8, "iterative"))
    assert gel.newton._dirichlet_satisfied()
