"""The cheap coupling iteration (issue 8, item 3): linear path, block-triangular solves, traction recovery.

* A linear-path solve (one step with the kept linearisation at rest, taken
  when a solve continues the previous one) equals the exact Newton solution
  to 1e-10 where the problem is linear: tiny loads, references converged
  to 1e-13.
* Where the nonlinear remainder matters (strains of ~10 %), the linear
  path's test sends the solve down the exact Newton path, which converges to
  the same solution as full Newton.
* The block-triangular solve of the gel's linearisation at rest is the
  solution of the whole system, not an approximation.
* The interface mass matrix on the interface nodes is the one of the whole
  space restricted to them.
* Solves that all start from one state (a time window's checkpoint) assemble
  the state part of the residual there once.
"""

from __future__ import annotations

import numpy as np
import pytest

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

from dense_aij import aij
from cell import NeoHookeanCellSolver
from cell import meshes
from femtools.functions import quadrature_measure
from femtools.interface import InterfaceMass, InterfaceNodes
from femtools.linalg import BlockTriangularSolver, DirectSolver, NewtonSolver, is_symmetric, schur_complement
from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, rectangle_mesh
from gel import GelParameters, PoroelasticGelSolver

COMM = MPI.COMM_WORLD


def gnorm(values: np.ndarray) -> float:
    """Norm over the ranks of owned values (each rank passes its owned part)."""
    return float(np.sqrt(COMM.allreduce(float(np.sum(np.asarray(values) ** 2)), op=MPI.SUM)))


def owned(f: fem.Function) -> np.ndarray:
    imap, bs = f.function_space.dofmap.index_map, f.function_space.dofmap.index_map_bs
    return f.x.array[: imap.size_local * bs]


# -- the gel: a column under the fluid's traction and velocity --------------------------------
def _column(params: GelParameters, **kwargs) -> PoroelasticGelSolver:
    msh, ft = rectangle_mesh(0.0, -1.0, 0.2, 0.0, 3, 12)
    return PoroelasticGelSolver(msh, ft, params, symmetry=[((LEFT, RIGHT), 0)], no_slip=BOTTOM,
                                fluid_interfaces={"top": TOP}, **kwargs)


def _load(gel: PoroelasticGelSolver, scale: float) -> None:
    X = gel.interface_points("top")
    traction = np.column_stack([0.3 * np.sin(np.pi * X[:, 0] / 0.2), -1.0 + 0.2 * X[:, 0]])
    velocity = np.column_stack([0.1 + 0 * X[:, 0], -0.05 + 0 * X[:, 0]])
    gel.set_interface_data("top", traction=scale * traction, velocity=scale * velocity)


def _gel_pair(params, scales, rtol=1e-13):
    """The same loads on a linear-path gel (solved after each load) and an exact-path gel (last load)."""
    fast = _column(params, linear_path=True, newton_rtol=rtol)
    for s in scales:
        _load(fast, s)
        fast.solve()
    exact = _column(params, newton_rtol=rtol)
    _load(exact, scales[-1])
    exact.solve()
    return fast, exact


def test_gel_linear_path_equals_newton_where_linear():
    """Strains ~1e-12 (viscous units at Ca = 1e-12): the one step is the solution, to 1e-10."""
    fast, exact = _gel_pair(GelParameters.viscous_units(Ca=1e-12), scales=[1.0, 1.7])
    assert fast.newton.stats["linear_steps"] == 1, fast.newton.stats     # the second solve took the path
    assert fast.newton.stats["linear_fallbacks"] == 0, fast.newton.stats
    a, b = owned(fast.state), owned(exact.state)
    assert gnorm(a - b) <= 1e-10 * gnorm(b), gnorm(a - b) / gnorm(b)


def test_gel_exact_path_at_a_large_load():
    """Paper units, strains of ~3 %: the test rejects the one step; Newton converges to the solution."""
    params = GelParameters(phi_s0=0.3, xi=5.0, lambda_s=1.5, beta=0.7, eta=0.4, Ca=0.5)
    fast, exact = _gel_pair(params, scales=[0.3, 1.0], rtol=1e-12)
    assert fast.newton.stats["linear_fallbacks"] == 1, fast.newton.stats
    assert fast.newton.stats["linear_steps"] == 0, fast.newton.stats
    assert fast.newton.last_linear_ratio > fast.newton.linear_tolerance
    # the one step would have been far off: the correction after it is well above 1e-10
    assert fast.newton.history[1] > 1e-6, fast.newton.history
    a, b = owned(fast.state), owned(exact.state)
    assert gnorm(a - b) <= 1e-10 * gnorm(b), gnorm(a - b) / gnorm(b)


# -- the cell: Dirichlet data on its boundary ----------------------------------------------
def _stretch(cell: NeoHookeanCellSolver, amplitude: float) -> None:
    X = cell.interface_points("boundary")
    g = amplitude * np.column_stack([0.10 * X[:, 0] + 0.05 * X[:, 1] ** 2, -0.04 * X[:, 1] + 0.03 * X[:, 0] * X[:, 1]])
    cell.set_interface_data("boundary", displacement=g)


def _cell_pair(d: float, amplitudes, rtol=1e-13):
    msh, ft = meshes.block(1.0, 1.0, 6)
    tags = tuple(int(t) for t in np.unique(np.hstack(COMM.allgather(np.unique(ft.values)))))
    make = lambda **kw: NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, displacement_scale=d,  # noqa: E731
                                             interfaces={"boundary": tags}, newton_rtol=rtol, **kw)
    fast = make(linear_path=True)
    for a in amplitudes:
        _stretch(fast, a)
        fast.solve()
    exact = make(reuse="never")
    _stretch(exact, amplitudes[-1])
    exact.solve()
    return fast, exact


def test_cell_linear_path_equals_newton_where_linear():
    fast, exact = _cell_pair(1e-12, [1.0, 1.5])
    assert fast.stats["linear_steps"] == 1 and fast.stats["linear_fallbacks"] == 0, fast.stats
    a, b = owned(fast.displacement), owned(exact.displacement)
    assert gnorm(a - b) <= 1e-10 * gnorm(b)
    fa, fb = (c.interface_data("boundary")["force"] for c in (fast, exact))
    assert np.linalg.norm(fa - fb) <= 1e-10 * np.linalg.norm(fb)


def test_cell_exact_path_at_a_large_load():
    """Stretches of ~15 %: the one step is rejected; the result is the full-Newton solution."""
    fast, exact = _cell_pair(1.0, [0.5, 1.5], rtol=1e-12)
    assert fast.stats["linear_fallbacks"] == 1 and fast.stats["linear_steps"] == 0, fast.stats
    assert fast.newton_history[1] > 1e-6, fast.newton_history
    a, b = owned(fast.displacement), owned(exact.displacement)
    assert gnorm(a - b) <= 1e-10 * gnorm(b)


def test_linear_path_needs_a_continued_state():
    """A first solve, or one from a state set from outside, is the exact path (it cannot count on a next one)."""
    gel = _column(GelParameters.viscous_units(Ca=1e-12), linear_path=True)
    _load(gel, 1.0)
    gel.solve()
    assert gel.newton.stats["linear_steps"] == 0
    gel.set_state({"state": 0.5 * gel.state.x.array})
    gel.solve()
    assert gel.newton.stats["linear_steps"] == 0
    _load(gel, 2.0)
    gel.solve()
    assert gel.newton.stats["linear_steps"] == 1


def test_a_cell_restored_from_a_checkpoint_continues_as_the_one_that_wrote_it():
    """The checkpoint says whether the unknowns are the last solve's solution: a solver restored from it
    takes the next solve's linear step where the writer does, to the same bits; without it, the exact path."""
    msh, ft = meshes.block(1.0, 1.0, 6)
    tags = tuple(int(t) for t in np.unique(np.hstack(COMM.allgather(np.unique(ft.values)))))
    make = lambda: NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, displacement_scale=1e-12,  # noqa: E731
                                        interfaces={"boundary": tags}, newton_rtol=1e-13, linear_path=True)
    writer = make()
    _stretch(writer, 1.0)
    writer.solve()
    state = writer.checkpoint_state()
    assert state["newton"]["at_solution"]
    restored, forgetful = make(), make()
    restored.load_checkpoint_state(state)
    forgetful.load_checkpoint_state({"u": state["u"]})        # a checkpoint without the flag
    for cell in (writer, restored, forgetful):
        _stretch(cell, 1.5)
        cell.solve()
    assert writer.stats["linear_steps"] == restored.stats["linear_steps"] == 1, restored.stats
    assert forgetful.stats["linear_steps"] == 0, forgetful.stats
    assert np.array_equal(owned(restored.displacement), owned(writer.displacement))
    writer.displacement.x.array[:] *= 0.5                      # set from outside: not a solution any more
    assert not writer.checkpoint_state()["newton"]["at_solution"]


def test_solves_from_one_state_assemble_its_state_residual_once():
    """Every coupling iteration of a time window solves from the window's checkpoint: F(u0) once.

    The cell (finite strain, stretches of ~10-15 %) solved from rest, u0 = 0, for three stretches,
    by exact Newton (at least three steps each, so the iterates would displace u0 from a cache
    of the last two states; a kept Jacobian's undone steps would leave states that differ by
    round-off). The first solve assembles the state part of the residual at each accepted
    iterate but the last (its step decides convergence); the later ones, which start from u0
    again, at one fewer. Each solution is the one a new solver finds from rest (to 1e-10).
    """
    msh, ft = meshes.block(1.0, 1.0, 6)
    tags = tuple(int(t) for t in np.unique(np.hstack(COMM.allgather(np.unique(ft.values)))))
    make = lambda: NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, displacement_scale=1.0,  # noqa: E731
                                        interfaces={"boundary": tags}, newton_rtol=1e-12, reuse="never")
    cell = make()
    newton = cell._newton
    for k, amplitude in enumerate((1.0, 1.2, 1.4)):
        cell.displacement.x.array[:] = 0.0
        _stretch(cell, amplitude)
        assembled, stepped = newton.stats["state_assemblies"], newton.stats["newton_iterations"]
        cell.solve()
        steps = newton.stats["newton_iterations"] - stepped
        assert steps >= 3, steps
        assert newton.stats["state_assemblies"] - assembled == (steps if k == 0 else steps - 1)
        fresh = make()
        _stretch(fresh, amplitude)
        fresh.solve()
        a, b = owned(cell.displacement), owned(fresh.displacement)
        assert gnorm(a - b) <= 1e-10 * gnorm(b)


# -- the block-triangular solve ------------------------------------------------------------
def test_block_triangular_solve_is_the_solution():
    """The gel's linearisation at rest, solved block by block, against one LU of the whole matrix."""
    gel = _column(GelParameters.viscous_units(Ca=3e-10))
    newton = gel.newton
    newton._assemble_jacobian()
    assert newton._linear is newton._blocks, "the gel's linearisation at rest is block lower-triangular"
    A = newton.A
    full = DirectSolver(COMM, "full")
    full.set_operator(A)
    full.factorize()
    b = A.createVecLeft()
    b.setRandom()
    x_blocks, x_full = A.createVecRight(), A.createVecRight()
    newton._blocks.solve(b, x_blocks)
    full.solve(b, x_full)
    x_blocks.axpy(-1.0, x_full)
    assert x_blocks.norm() <= 1e-10 * x_full.norm()
    # a matrix whose first block's equations contain the second block's unknowns is refused
    first, second = (np.asarray(s.getIndices()) for s in newton._blocks.sets)
    swapped = BlockTriangularSolver(COMM, "swapped", [second, first])
    assert not swapped.factorize(A)


# -- the interface mass matrix ------------------------------------------------------------
def test_interface_mass_is_the_restricted_mass_matrix():
    """M lambda for lambda = (x, x y) on Gamma equals int lambda . s ds at the interface nodes."""
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 0.5, 4, 3)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
    nodes = InterfaceNodes(V, ft, TOP)
    ds = quadrature_measure("ds", msh, ft, degree=4)(TOP)
    mass = InterfaceMass(nodes, V, ds, np.ones((nodes.size, 2), dtype=bool))
    lam = fem.Function(V)
    lam.interpolate(lambda x: np.vstack([x[0], x[0] * x[1]]))
    load = fem_petsc.assemble_vector(fem.form(ufl.inner(lam, ufl.TestFunction(V)) * ds))
    load.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    R = nodes.from_array(load.array)
    L = nodes.from_function(lam)
    assert np.abs(mass.matrix @ L.ravel() - R.ravel()).max() <= 1e-13 * np.abs(R).max()
    np.testing.assert_allclose(mass.solve(R), L, rtol=0, atol=1e-12 * np.abs(L).max())
    # pinned components are zero and left out of the solve
    keep = np.ones((nodes.size, 2), dtype=bool)
    keep[0, :] = False
    pinned_mass = InterfaceMass(nodes, V, ds, keep)
    pinned = pinned_mass.solve(R)
    assert np.all(pinned[0] == 0.0)
    # several right-hand sides at once: the same as one by one
    columns = np.column_stack([R.ravel(), 2.0 * R.ravel() + L.ravel()])
    expected = np.column_stack([pinned_mass.solve(c.reshape(R.shape)).ravel() for c in columns.T])
    np.testing.assert_allclose(pinned_mass.solve_columns(columns), expected, rtol=0,
                               atol=1e-14 * np.abs(expected).max())


# -- MUMPS controls ----------------------------------------------------------------------------
def _tridiagonal(n: int) -> PETSc.Mat:
    A = PETSc.Mat().createAIJ([n, n], nnz=3, comm=COMM)
    start, end = A.getOwnershipRange()
    for i in range(start, end):
        A.setValue(i, i, 2.0)
        for j in (i - 1, i + 1):
            if 0 <= j < n:
                A.setValue(i, j, -1.0)
    A.assemble()
    return A


def test_direct_solver_keeps_its_mumps_controls():
    """ICNTL(14) and (24) reach MUMPS (read back after the factorisation)."""
    solver = DirectSolver(COMM, "controls", {"mat_mumps_icntl_14": 77})
    solver.set_operator(_tridiagonal(200))
    solver.factorize()
    F = solver.ksp.getPC().getFactorMatrix()
    assert F.getMumpsIcntl(14) == 77 and F.getMumpsIcntl(24) == 1


@pytest.mark.parametrize("options, used", [({"mat_mumps_icntl_7": 2}, 2), ({"mat_mumps_icntl_7": 4}, 4),
                                           ({"mat_mumps_icntl_7": 0}, 0),
                                           ({"mat_mumps_icntl_7": 6, "pc_factor_shift_type": "none"}, 6)])
def test_direct_solver_orders_by_the_ordering_asked_for(options, used):
    """The ordering (ICNTL(7); default MUMPS's automatic choice) reaches MUMPS's analysis, also for a
    solver whose other options go to the options database under a prefix (the last case), and is
    not left in that database; INFOG(7) is the ordering MUMPS used.  An ordering Debian's MUMPS
    lacks (METIS, 5) is refused with a message that names the control."""
    solver = DirectSolver(COMM, "ordering", dict(options))
    solver.set_operator(_tridiagonal(200))
    solver.factorize()
    assert solver.ksp.getPC().getFactorMatrix().getMumpsInfog(7) == used
    assert not any(key.endswith("mat_mumps_icntl_7") for key in PETSc.Options().getAll())
    with pytest.raises(ValueError, match="mat_mumps_icntl_7"):
        DirectSolver(COMM, "ordering", {"mat_mumps_icntl_7": 5})


def test_schur_complement_is_the_condensed_matrix():
    """``schur_complement``: K_kk - K_kr K_rr^-1 K_rk of a sparse non-symmetric matrix, against
    numpy's dense formula (1e-12), for kept indices in any order; none kept gives an empty matrix."""
    import scipy.sparse
    n = 120
    rng = np.random.default_rng(3)
    K = scipy.sparse.random(n, n, density=0.05, random_state=rng) + scipy.sparse.diags(np.full(n, 4.0))
    keep = np.array([7, 3, 90, 41, 119, 0])
    rest = np.setdiff1d(np.arange(n), keep)
    D = K.toarray()
    expected = D[np.ix_(keep, keep)] - D[np.ix_(keep, rest)] @ np.linalg.solve(D[np.ix_(rest, rest)],
                                                                                D[np.ix_(rest, keep)])
    S = schur_complement(K, keep)
    assert np.abs(S - expected).max() <= 1e-12 * np.abs(expected).max()
    assert schur_complement(K, np.empty(0, dtype=int)).shape == (0, 0)


def test_symmetry_is_judged_entrywise_relative_to_the_largest_row_sum():
    """``is_symmetric``: asymmetries of round-off size (1e-15 of an entry) pass, one of 1e-9 of the
    largest row sum does not (within a rank's rows and between two ranks' rows), nor does an entry
    without its transposed partner (on 1 and 2 ranks)."""
    n = 40
    dense = 4.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1) + 0.5 * (np.eye(n, k=7) + np.eye(n, k=-7))
    row_sum = np.abs(dense).sum(axis=1).max()
    rounded = dense.copy()
    rounded[3, 10] *= 1.0 + 1e-15
    skewed = dense.copy()
    skewed[3, 10] += 1e-9 * row_sum
    across = dense.copy()                   # on 2 ranks row 15 and column 22 have different owners
    across[15, 22] += 1e-9 * row_sum
    one_sided = dense.copy()
    one_sided[0, n - 1] = 1e-3
    for matrix, expected in ((dense, True), (rounded, True), (skewed, False), (across, False),
                             (one_sided, False)):
        assert is_symmetric(aij(matrix)) is expected


def test_symmetric_operators_are_factorised_by_ldlt_and_others_by_lu():
    """``factorize_symmetric_if_possible``: a symmetric indefinite saddle-point matrix (the shape of
    the Stokes and mesh-motion operators) is factorised by LDL^T, a matrix with an asymmetry of 1e-6
    by LU, by the same solver in turn; both solutions equal numpy's dense solve to 1e-12."""
    n, m = 60, 20
    K = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    B = np.zeros((m, n))
    for i in range(m):
        B[i, 3 * i:3 * i + 3] = (1.0, -2.0, 1.5)
    saddle = np.block([[K, B.T], [B, np.zeros((m, m))]])
    skewed = saddle.copy()
    skewed[0, 1] += 1e-6
    rhs = np.sin(np.arange(n + m) + 1.0)
    solver = DirectSolver(COMM, "ldlt")
    for dense, kind in ((saddle, "cholesky"), (skewed, "lu"), (saddle, "cholesky")):
        A = aij(dense)
        solver.set_operator(A)
        solver.factorize_symmetric_if_possible()
        assert solver.kind == kind
        assert solver.ksp.getPC().getType() == kind
        b, x = A.createVecLeft(), A.createVecRight()
        start, end = b.getOwnershipRange()
        b.array[:] = rhs[start:end]
        solver.solve(b, x)
        expected = np.linalg.solve(dense, rhs)[start:end]
        assert np.abs(x.array_r - expected).max() <= 1e-12 * np.abs(expected).max()


# -- interface stiffness: a Robin condition whose operator is a matrix ----------------------------
def test_interface_stiffness_equals_the_robin_form():
    """K = kappa M_Gamma added by ``set_interface_stiffness`` solves as the form kappa int u.v ds does.

    -div grad u = f, u = 0 on the left edge, kappa u + du/dn = 0 on the top, natural elsewhere:
    once with the Robin term in the form, once with the interface mass matrix as the stiffness
    (the top's left end is a Dirichlet node: its row and column are left out).
    """
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 0.5, 6, 4)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
    ds = quadrature_measure("ds", msh, ft, degree=4)
    v = ufl.TestFunction(V)
    f = ufl.as_vector([1.0 + ufl.SpatialCoordinate(msh)[1], -0.5])
    kappa = 3.0
    nodes = InterfaceNodes(V, ft, TOP)
    mass = InterfaceMass(nodes, V, ds(TOP), np.ones((nodes.size, 2), dtype=bool)).matrix.toarray()
    solutions = []
    for robin_form in (True, False):
        u = fem.Function(V)
        bc = fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, ft.find(LEFT)), V)
        F = ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx - ufl.inner(f, v) * ufl.dx
        if robin_form:
            F += kappa * ufl.inner(u, v) * ds(TOP)
        newton = NewtonSolver(F, u, [bc], name="robin", rtol=1e-13)
        if not robin_form:
            dofs = nodes.global_dofs(V, bcs=[bc]).ravel()
            assert np.sum(dofs < 0) == 2                     # the corner node on the left edge
            newton.set_interface_stiffness(dofs, kappa * mass)
        newton.solve()
        assert newton.stats["factorizations"] == 1 and len(newton.history) <= 2, newton.history
        solutions.append(owned(u).copy())
    a, b = solutions
    assert gnorm(a - b) <= 1e-11 * gnorm(b), gnorm(a - b) / gnorm(b)


def test_cell_interface_stiffness_is_its_dirichlet_to_neumann_map():
    """The cell's K on its whole boundary: K g = its own solve's nodal forces for the displacement g
    (linear regime, strains 1e-12), K symmetric, and a rigid translation costs no force."""
    msh, ft = meshes.block(1.0, 1.0, 6)
    tags = tuple(int(t) for t in np.unique(np.hstack(COMM.allgather(np.unique(ft.values)))))
    cell = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, displacement_scale=1e-12,
                                interfaces={"boundary": tags}, newton_rtol=1e-13)
    K = cell.interface_stiffness("boundary")
    _stretch(cell, 1.0)
    cell.solve()
    g = cell.interface_data("boundary")["displacement"]
    force = cell.interface_data("boundary")["force"]
    assert np.linalg.norm(K @ g.ravel() - force.ravel()) <= 1e-9 * np.linalg.norm(force)
    assert np.abs(K - K.T).max() <= 1e-12 * np.abs(K).max()
    for shift in ([1.0, 0.0], [0.0, 1.0]):
        t = np.tile(shift, K.shape[0] // 2)
        assert np.abs(K @ t).max() <= 1e-10 * np.abs(K).max()


def test_cell_interface_jacobian_is_its_linear_response():
    """interface_jacobian(): d(force)/d(displacement) is K, and d(displacement)/d(displacement) the
    identity but where a symmetry condition holds the component at 0 (the solver's own outputs,
    linear regime, strains 1e-12)."""
    msh, ft = meshes.block(1.0, 1.0, 6)
    tags = tuple(int(t) for t in np.unique(np.hstack(COMM.allgather(np.unique(ft.values)))))
    cell = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, displacement_scale=1e-12,
                                interfaces={"boundary": tags[1:]}, symmetry=[(tags[:1], 1)], newton_rtol=1e-13)
    J = cell.interface_jacobian()
    assert set(J) == {(("boundary", "force"), ("boundary", "displacement")),
                      (("boundary", "displacement"), ("boundary", "displacement"))}
    assert np.array_equal(J[("boundary", "force"), ("boundary", "displacement")], cell.interface_stiffness("boundary"))
    g = np.random.default_rng(5).standard_normal((cell.interface_points("boundary").shape[0], 2))
    cell.set_interface_data("boundary", displacement=g)
    cell.solve()
    out = cell.interface_data("boundary")
    held = np.diag(J[("boundary", "displacement"), ("boundary", "displacement")]) == 0
    assert held.any() and not held.all()          # the symmetry line fixes some components
    for key in ("force", "displacement"):
        predicted = J[("boundary", key), ("boundary", "displacement")] @ g.ravel()
        # the held components' force is the symmetry condition's reaction: left out (docstring)
        free = out[key].ravel()[~held]
        assert np.linalg.norm(predicted[~held] - free) <= 1e-9 * np.linalg.norm(free), key
    assert np.all(out["displacement"].ravel()[held] == 0)


def test_nodal_loads_on_a_repeated_dof_add_up():
    """``set_nodal_loads``: a dof listed twice (a node shared by two interfaces) takes both loads,
    the same solution as one load of their sum."""
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 0.5, 6, 4)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
    v = ufl.TestFunction(V)
    nodes = InterfaceNodes(V, ft, TOP)
    owned_dofs = nodes.dofs()[nodes.owned].ravel().astype(np.int32)
    solutions = []
    for twice in (False, True):
        u = fem.Function(V)
        bc = fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, ft.find(LEFT)), V)
        newton = NewtonSolver(ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx, u, [bc], name="loads", rtol=1e-13)
        values = np.linspace(1.0, 2.0, owned_dofs.size)
        if twice:
            newton.set_nodal_loads(np.hstack([owned_dofs, owned_dofs]), np.hstack([0.25 * values, 0.75 * values]))
        else:
            newton.set_nodal_loads(owned_dofs, values)
        newton.solve()
        solutions.append(owned(u).copy())
    a, b = solutions
    assert gnorm(b) > 0 and gnorm(a - b) <= 1e-12 * gnorm(a), gnorm(a - b) / gnorm(a)


# -- the linearisation at rest: folded by UFL, the same matrix -----------------------------------
def test_jacobian_at_rest_folded_equals_zero_functions():
    """jacobian_at_rest replaces the state by UFL zeros (F = I folds before code generation): its
    matrix is the one of dF/du at a zero-valued state, here a finite-strain neo-Hookean solid."""
    from femtools.linalg import jacobian_at_rest
    msh, _ = rectangle_mesh(0.0, 0.0, 1.0, 1.0, 3, 3)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
    u, v = fem.Function(V), ufl.TestFunction(V)
    F = ufl.Identity(2) + ufl.grad(u)
    J = ufl.det(F)
    P = 1.3 * (F - ufl.inv(F).T) + 0.7 * ufl.ln(J) * ufl.inv(F).T
    residual = ufl.inner(P, ufl.grad(v)) * ufl.dx
    zero = fem.Function(V)
    A = fem_petsc.assemble_matrix(fem.form(jacobian_at_rest(residual, u)))
    B = fem_petsc.assemble_matrix(fem.form(ufl.replace(ufl.derivative(residual, u), {u: zero})))
    A.assemble()
    B.assemble()
    B.axpy(-1.0, A, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    assert B.norm() <= 1e-13 * A.norm()


def test_a_small_load_solve_never_compiles_the_exact_jacobian():
    """At small loads the kept linearisation at rest serves the whole solve: the exact Jacobian
    (tens of seconds to compile for a 3D finite-strain gel) is compiled only when first needed."""
    gel = _column(GelParameters.viscous_units(Ca=1e-12), kinematics="finite")
    _load(gel, 1.0)
    gel.solve()
    newton = gel.newton
    assert newton._J is None
    assert newton.J is not None and newton._J is newton.J


def _neo_hookean_bar(stretch: float, kwargs: dict):
    """A finite-strain neo-Hookean square: u_x = stretch on the left side (a non-zero Dirichlet value),
    held at x = 1, a dead load and a nonlinear spring on top; returns (NewtonSolver, u)."""
    from femtools.linalg import jacobian_at_rest
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 1.0, 4, 4)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
    u, v = fem.Function(V), ufl.TestFunction(V)
    F = ufl.Identity(2) + ufl.grad(u)
    P = 1.3 * (F - ufl.inv(F).T) + 0.7 * ufl.ln(ufl.det(F)) * ufl.inv(F).T
    load = fem.Constant(msh, np.array([0.0, -0.1 * stretch]))
    ds = ufl.Measure("ds", domain=msh, subdomain_data=ft)
    spring = 0.5 * ufl.dot(u, v) * (1 + ufl.dot(u, u))       # a nonlinear Robin term: J has a boundary part
    residual = ufl.inner(P, ufl.grad(v)) * ufl.dx + (spring - ufl.dot(load, v)) * ds(TOP)
    left = fem.locate_dofs_topological(V, 1, ft.find(LEFT))
    right = fem.locate_dofs_topological(V, 1, ft.find(RIGHT))
    bcs = [fem.dirichletbc(np.array([stretch, 0.0]), left, V), fem.dirichletbc(np.zeros(2), right, V)]
    if kwargs.pop("reference", False):
        kwargs["J_reference"] = jacobian_at_rest(residual, u)
    return NewtonSolver(residual, u, bcs, name="bar", **kwargs), u


def test_dirichlet_values_lifted_with_the_kept_jacobian():
    """A non-zero Dirichlet value at a small load: the lifting uses the kept linearisation at rest, so
    the exact Jacobian is never compiled, and the solution is the exact Newton one (to 1e-9)."""
    kept, u = _neo_hookean_bar(1e-6, dict(reference=True, rtol=1e-13))
    kept.solve()
    assert kept._J is None, "the lifting of the Dirichlet value compiled the exact Jacobian"
    exact, u_exact = _neo_hookean_bar(1e-6, dict(reuse="never", rtol=1e-13))
    exact.solve()
    assert gnorm(owned(u) - owned(u_exact)) <= 1e-9 * gnorm(owned(u_exact))


def test_exact_newton_with_dirichlet_values_converges_quadratically():
    """Exact Newton (the Jacobian's cell and boundary parts compiled apart) from rest to a 20 %
    Dirichlet stretch: each correction below 1e-2 is followed by one at most 10 times its square."""
    newton, _ = _neo_hookean_bar(0.2, dict(reuse="never", rtol=1e-13))
    newton.solve()
    h = newton.history
    print("exact Newton corrections:", " ".join(f"{e:.1e}" for e in h))
    assert len(newton.J) == 2, "the Jacobian was not split into its cell and boundary parts"
    pairs = [(a, b) for a, b in zip(h, h[1:]) if a < 1e-2 and b > 1e-13]
    assert pairs and all(b <= 10 * a**2 for a, b in pairs), h


def test_split_jacobian_assembles_the_whole_matrix():
    """split_by_integral_type: the cell and the boundary parts, assembled into one matrix with Dirichlet
    rows, give the matrix of the whole form (to round-off)."""
    from femtools.linalg import _assemble_into, split_by_integral_type
    newton, u = _neo_hookean_bar(0.05, dict(reuse="never"))
    u.interpolate(lambda x: np.vstack([0.05 * x[0] * x[1], -0.03 * x[0] ** 2]))
    u.x.scatter_forward()
    J = newton._J_ufl                    # dF/du, cell and exterior facet integrals
    parts = [fem.form(p) for p in split_by_integral_type(J)]
    assert len(parts) == 2
    whole = fem.form(J)
    A, B = fem_petsc.create_matrix(whole), fem_petsc.create_matrix(whole)
    _assemble_into(A, whole, newton.bcs)
    _assemble_into(B, tuple(parts), newton.bcs)
    B.axpy(-1.0, A)
    assert B.norm() <= 1e-13 * A.norm()
