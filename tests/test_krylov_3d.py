"""The 3D closed forms on the iterative path (``solver="iterative"``, femtools.krylov).

The builders of tests/test_fluid_3d.py, tests/test_gel_3d.py and
tests/test_cell_3d.py run with the field solver class of their module replaced
by one that passes ``solver="iterative"`` (and records the solvers built), so
the meshes, data and closed-form checks are those of the direct tests.
References, per field:

* the closed form with the direct test's tolerance (the whole direct test where
  it is cheap enough, else its tolerance at the coarsest level);
* the direct (MUMPS) solve of the same discrete problem, to 1e-8 relative at
  every node (nodes matched by coordinates: the partition on 2 ranks may differ
  between two meshes);
* the Krylov iterations at two 3D levels: finest <= 1.5 coarsest + 5, the
  bound of tests/test_krylov.py (a mesh-independent preconditioner).

GAMG coarsens on the squared graph in 3D (``femtools.krylov.AMG_3D_OPTIONS``, the
factories' default there): with ``square_graph 0`` the set-up at the finer 3D levels
was 4 x slower (duct (4, 8, 4): 8 s instead of 2 s, 104 instead of 127 MINRES
iterations; Lame sphere h0/4: 16 s instead of 4 s, 36 instead of 61 CG iterations).
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

import fluid3d_cases
import test_cell_3d
import test_fluid_3d
import test_gel_3d
from cell import NeoHookeanCellSolver
from fluid import StokesSolver
from fluid3d_cases import BACK, FLOOR, FRONT, LID
from gel.solver import PoroelasticGelSolver
from test_cell_3d import radial_solution  # noqa: F401  (the fixture of the finite-strain test)
from test_krylov import bounded

COMM = MPI.COMM_WORLD


def use_solver(monkeypatch, module, name: str, real, kind: str, petsc_options: dict | None = None) -> list:
    """Make ``module.name`` build ``real`` solvers with ``solver=kind``; returns the list of
    (solver, positional arguments) of those built."""
    built = []

    def build(*args, **kwargs):
        built.append((real(*args, solver=kind, petsc_options=petsc_options, **kwargs), args))
        return built[-1][0]
    monkeypatch.setattr(module, name, build)
    return built


def nodal_difference(a, b) -> float:
    """max |a - b| / max |b| over all nodes of two functions on meshes with the same nodes, matched by
    their coordinates (gathered on every rank)."""
    rows = []
    for u in (a, b):
        V = u.function_space
        n, bs = V.dofmap.index_map.size_local, V.dofmap.index_map_bs
        X = np.vstack(COMM.allgather(V.tabulate_dof_coordinates()[:n]))
        values = np.vstack(COMM.allgather(u.x.array[:n * bs].reshape(n, bs)))
        rows.append(values[np.lexsort(np.round(X, 10).T[::-1])])
    assert rows[0].shape == rows[1].shape
    return float(np.abs(rows[0] - rows[1]).max() / np.abs(rows[1]).max())


def krylov_counts(linear_solver) -> tuple[int, int]:
    """(min, max) Krylov iterations over the solves of a field solver's linear solver."""
    return min(linear_solver.iterations), max(linear_solver.iterations)


# --------------------------------------------------------------------------- Stokes: the duct
def test_duct_on_the_iterative_path(monkeypatch):
    """MINRES: the duct test (two levels, its rates and error bound); the coarsest level = direct."""
    built = use_solver(monkeypatch, fluid3d_cases, "StokesSolver", StokesSolver, "iterative")
    test_fluid_3d.test_duct_against_the_series_at_the_taylor_hood_rate()
    monkeypatch.undo()
    (coarse, (msh, ft)), _ = built
    direct = fluid3d_cases.channel(msh, ft, walls=(FRONT, BACK, FLOOR, LID))
    diff = max(nodal_difference(coarse.velocity, direct.velocity), nodal_difference(coarse.pressure, direct.pressure))
    counts = [max(s._solver.solver.iterations) for s, _ in built]
    print(f"\n3D duct MINRES iterations, levels (2, 4, 2), (4, 8, 4): {counts}; iterative - direct {diff:.1e}")
    assert diff < 1e-8
    assert bounded(counts), counts


# --------------------------------------------------------------------------- the gel
def test_terzaghi_column_on_the_iterative_path(monkeypatch):
    """GMRES: the 3D column (nz = 8, 40 steps) against the series with the direct test's tolerance
    (2 (|q(h, dt) - q(h, dt/2)| + |q(h, dt) - q(h/2, dt)|) + 1e-4, its halvings solved directly);
    every step's p and settlement and the final state = direct."""
    direct_built = use_solver(monkeypatch, test_gel_3d, "PoroelasticGelSolver", PoroelasticGelSolver, "direct")
    direct, half_dt, half_h = (test_gel_3d._terzaghi_column(nz, steps) for nz, steps in ((8, 40), (8, 80), (16, 40)))
    built = use_solver(monkeypatch, test_gel_3d, "PoroelasticGelSolver", PoroelasticGelSolver, "iterative")
    base = test_gel_3d._terzaghi_column(8, 40)
    series = np.array([(test_gel_3d.terzaghi_pressure(1.0, T), test_gel_3d.terzaghi_consolidation(T))
                       for T in test_gel_3d.TERZAGHI_T])
    tol = 2 * (np.abs(direct - half_dt) + np.abs(direct - half_h)) + 1e-4
    (gel, _), (gel_direct, _) = built[0], direct_built[0]
    diff = max(nodal_difference(f(gel), f(gel_direct)) for f in _GEL_FIELDS)
    print(f"\nTerzaghi 3D, GMRES iterations per step (min, max): {krylov_counts(gel.newton.solver)}; "
          f"errors {np.abs(base - series).ravel()} (tol {tol.ravel()}); iterative - direct: outputs "
          f"{np.abs(base - direct).max():.1e}, final state {diff:.1e}")
    assert np.all(np.abs(base - series) <= tol)
    assert np.all(np.abs(base - direct) <= 1e-8 * np.abs(direct)) and diff < 1e-8


_GEL_FIELDS = (lambda g: g.interstitial_velocity(), lambda g: g.displacement(), lambda g: g.pore_pressure())


def test_gel_manufactured_solution_on_the_iterative_path(monkeypatch):
    """GMRES: the small-strain 3D manufactured solution at N = 2 and 3 (the direct test's two coarsest
    levels): the rates of (v_f, u, p) >= 3, 3, 2 minus the direct test's margin 0.3; N = 2 = direct."""
    prm, amp = test_gel_3d.MMS_CASES["small"]
    fns = test_gel_3d._manufactured_3d(prm, "small", amp)
    direct_built = use_solver(monkeypatch, test_gel_3d, "PoroelasticGelSolver", PoroelasticGelSolver, "direct")
    test_gel_3d._mms_errors_3d(prm, "small", fns, 2)
    built = use_solver(monkeypatch, test_gel_3d, "PoroelasticGelSolver", PoroelasticGelSolver, "iterative")
    errors = np.array([test_gel_3d._mms_errors_3d(prm, "small", fns, N) for N in (2, 3)])
    rates = np.log(errors[0] / errors[1]) / np.log(3 / 2)
    diff = max(nodal_difference(f(built[0][0]), f(direct_built[0][0])) for f in _GEL_FIELDS)
    counts = [max(g.newton.solver.iterations) for g, _ in built]
    print(f"\n3D gel MMS GMRES iterations, N = 2, 3: {counts}; rates v_f, u, p {np.round(rates, 2)}; "
          f"iterative - direct {diff:.1e}")
    assert np.all(rates >= np.array([3.0, 3.0, 2.0]) - 0.3), (rates, errors)
    assert diff < 1e-8
    assert bounded(counts), counts


# --------------------------------------------------------------------------- the cell
def test_lame_sphere_on_the_iterative_path(monkeypatch):
    """CG + GAMG: the Lame octant test (h0/2, h0/4: its rate and von Mises bounds); h0/2 = direct."""
    built = use_solver(monkeypatch, test_cell_3d, "NeoHookeanCellSolver", NeoHookeanCellSolver, "iterative")
    test_cell_3d.test_lame_octant_rate_and_von_mises()
    monkeypatch.undo()
    direct, _ = test_cell_3d.pressurised_shell(1)
    direct.solve()
    diff = nodal_difference(built[0][0].displacement, direct.displacement)
    counts = [max(s._newton.solver.iterations) for s, _ in built]
    print(f"\n3D Lame sphere CG iterations, h0/2, h0/4: {counts}; iterative - direct {diff:.1e}")
    assert diff < 1e-8
    assert bounded(counts), counts


def test_finite_strain_sphere_on_the_iterative_path(monkeypatch, radial_solution):  # noqa: F811
    """CG + GAMG (Chebyshev to 1.5 x the largest eigenvalue estimate): the finite-strain sphere test (two
    levels, 4 load steps: its rate and its bound against the linear answer); each level's final state = direct."""
    direct_built = use_solver(monkeypatch, test_cell_3d, "NeoHookeanCellSolver", NeoHookeanCellSolver, "direct")
    test_cell_3d.test_finite_strain_sphere_against_the_radial_ode(radial_solution)
    built = use_solver(monkeypatch, test_cell_3d, "NeoHookeanCellSolver", NeoHookeanCellSolver, "iterative")
    test_cell_3d.test_finite_strain_sphere_against_the_radial_ode(radial_solution)
    diff = max(nodal_difference(s.displacement, d.displacement) for (s, _), (d, _) in zip(built, direct_built))
    counts = [krylov_counts(s._newton.solver) for s, _ in built]
    print(f"\n3D finite-strain sphere CG iterations (min, max over the Newton steps), h0, h0/2: {counts}; "
          f"iterative - direct {diff:.1e}")
    assert diff < 1e-8
    assert bounded([c[1] for c in counts]), counts


# --------------------------------------------------------------------------- p-multigrid's prolongation
def test_p1_prolongation_is_the_interpolation_into_p2_in_the_block_order():
    """P1 is in P2: P x1 must be the P2 interpolant of the P1 function x1 exactly (to round-off), in the
    order of the velocity block's index set (nodes of ``_node_ordered``, components consecutive), on
    every rank; the preconditioner would only converge more slowly with a wrong P, so it is checked here."""
    from dolfinx import fem
    from femtools.krylov import _node_ordered, p1_prolongation
    msh, _ = fluid3d_cases.box_mesh((0.5, 1.0, 0.5), (2, 3, 2))
    import ufl
    W = fem.FunctionSpace(msh, ufl.MixedElement([ufl.VectorElement("Lagrange", msh.ufl_cell(), 2),
                                                 ufl.FiniteElement("Lagrange", msh.ufl_cell(), 1)]))
    V, V_to_W = W.sub(0).collapse()
    _, nodes = _node_ordered(W, V, V_to_W)
    P = p1_prolongation(V, nodes)
    V1 = fem.VectorFunctionSpace(msh, ("Lagrange", 1))
    f1 = fem.Function(V1)
    f1.interpolate(lambda x: np.vstack([1 + x[0] * x[1], np.sin(3 * x[2]), x[0] - 2 * x[2]]))
    f2 = fem.Function(V)
    f2.interpolate(f1)
    y = P.createVecLeft()
    P.mult(f1.vector, y)
    n = V.dofmap.index_map.size_local
    expected = f2.x.array[:3 * n].reshape(n, 3)[nodes].ravel()
    assert y.getLocalSize() == expected.size
    assert np.max(np.abs(y.array - expected)) < 1e-13 * np.max(np.abs(expected))
