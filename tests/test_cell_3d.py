"""The neo-Hookean cell in three dimensions (model.md section 10), on tetrahedral meshes.

Closed forms, written here in numpy/scipy independently of the UFL in ``cell/forms.py``:

* Lame's hollow sphere a < r < b under internal pressure p (small strain):
  u_r = A r + B / r^2,  A = p a^3 (1 - 2 nu) / (E (b^3 - a^3)),  B = p a^3 b^3 (1 + nu) / (2 E (b^3 - a^3)),
  sigma_rr = p a^3 (1 - b^3/r^3) / (b^3 - a^3),  sigma_tt = p a^3 (1 + b^3/(2 r^3)) / (b^3 - a^3).
* The same sphere at finite strain: r = r(R), lambda_r = r', lambda_t = r / R (twice),
  J = lambda_r lambda_t^2, and from W = mu/2 (tr C - 3) - mu ln J + lambda/2 (J - 1)^2

      P_RR = mu (lambda_r - 1/lambda_r) + lambda lambda_t^2 (J - 1)
      P_TT = mu (lambda_t - 1/lambda_t) + lambda lambda_r lambda_t (J - 1)

  with equilibrium dP_RR/dR + 2 (P_RR - P_TT)/R = 0, i.e.

      lambda_r' = -[2 (P_RR - P_TT) + 2 lambda lambda_t (2 J - 1)(lambda_r - lambda_t)]
                  / (R [mu (1 + 1/lambda_r^2) + lambda lambda_t^4]),

  P_RR(a) = -p (dead pressure on the inner face), P_RR(b) = 0; solved by scipy's solve_bvp (tol 1e-10).
* Homogeneous deformations: sigma = mu J^-1 (F F^T - I) + lambda (J - 1) I, P = J sigma F^-T.

Measure the numbers quoted in the report with ``pytest -s tests/test_cell_3d.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate

from mpi4py import MPI
from petsc4py import PETSc

import basix
import dolfinx.fem.petsc  # noqa: F401  (fem.petsc)
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh

from cell import NeoHookeanCellSolver, meshes
from femtools.functions import integrate
from mpi_run import assert_same_on_one_and_two_ranks

E_L, NU_L, A_L, B_L = 1.0, 0.3, 1.0, 1.5
MU_L, LMBDA_L = E_L / (2 * (1 + NU_L)), E_L * NU_L / ((1 + NU_L) * (1 - 2 * NU_L))
# p/E = 1e-8: the neo-Hookean answer is Lame's to ~1e-8 relative, far below the P2 errors (1e-4)
P_L = 1e-8
H0 = 0.6           # the base mesh; the levels are its uniform refinements (nested, h0/2, h0/4)
H_FULL = 0.5      # the full sphere (gmsh inverts a curved tetrahedron of the full sphere at h = 0.6)
OCTANT_SYMMETRY = [(meshes.PLANE_X, 0), (meshes.PLANE_Y, 1), (meshes.PLANE_Z, 2)]


# -- closed forms ----------------------------------------------------------------
def lame_coefficients(p=P_L, E=E_L):
    k = p * A_L**3 / (E * (B_L**3 - A_L**3))
    return k * (1 - 2 * NU_L), k * (1 + NU_L) * B_L**3 / 2


def lame_stresses(r, p=P_L):
    """(sigma_rr, sigma_tt) of Lame's sphere."""
    k = p * A_L**3 / (B_L**3 - A_L**3)
    return k * (1 - B_L**3 / r**3), k * (1 + B_L**3 / (2 * r**3))


def cauchy(F, mu, lmbda):
    J = np.linalg.det(F)
    return mu / J * (F @ F.T - np.eye(3)) + lmbda * (J - 1) * np.eye(3)


def von_mises_3d(s):
    return np.sqrt(0.5 * ((s[0, 0] - s[1, 1])**2 + (s[1, 1] - s[2, 2])**2 + (s[2, 2] - s[0, 0])**2)
                   + 3 * (s[0, 1]**2 + s[1, 2]**2 + s[2, 0]**2))


# -- helpers ---------------------------------------------------------------------
def gmax(local) -> float:
    return MPI.COMM_WORLD.allreduce(float(np.max(local, initial=-np.inf)), op=MPI.MAX)


def lame_field(msh, coefficients):
    """u = (A + B / r^3) x as UFL on ``msh``."""
    x = ufl.SpatialCoordinate(msh)
    return (coefficients[0] + coefficients[1] / ufl.dot(x, x)**1.5) * x


def rigid_modes(msh):
    x = ufl.SpatialCoordinate(msh)
    return [ufl.as_vector(e) for e in np.eye(3)] + [ufl.as_vector((-x[1], x[0], 0.0)),
                                                    ufl.as_vector((0.0, -x[2], x[1])),
                                                    ufl.as_vector((x[2], 0.0, -x[0]))]


def relative_errors(solver, u_ex, remove_rigid=False):
    """Relative L2 and energy-norm errors of the displacement (rigid fit removed if asked)."""
    msh = solver.mesh
    dx = ufl.dx(domain=msh, metadata={"quadrature_degree": 8})
    e = solver.displacement_scale * solver.displacement - u_ex
    if remove_rigid:
        modes = rigid_modes(msh)
        M = np.array([[integrate(ufl.inner(m, n), dx) for n in modes] for m in modes])
        c = np.linalg.solve(M, [integrate(ufl.inner(e, m), dx) for m in modes])
        e = e - sum(float(ci) * m for ci, m in zip(c, modes))
    l2 = np.sqrt(integrate(ufl.inner(e, e), dx) / integrate(ufl.inner(u_ex, u_ex), dx))
    return l2, energy(e, dx) / energy(u_ex, dx)


def quadrature_l2(solver, exact, degree=8):
    """Relative L2 error of the displacement against ``exact(x) -> (n, 3)`` at the quadrature points."""
    msh = solver.mesh
    pts, weights = basix.make_quadrature(basix.CellType.tetrahedron, degree)
    x = ufl.SpatialCoordinate(msh)
    expr = fem.Expression(ufl.as_vector([*x, *solver.displacement, abs(ufl.JacobianDeterminant(msh))]), pts)
    cells = np.arange(msh.topology.index_map(3).size_local, dtype=np.int32)
    vals = expr.eval(cells).reshape(cells.size, len(weights), 7)
    w = (vals[:, :, 6] * weights).ravel()
    X, u = vals[:, :, :3].reshape(-1, 3), solver.displacement_scale * vals[:, :, 3:6].reshape(-1, 3)
    ue = exact(X) if X.size else np.zeros((0, 3))
    sums = msh.comm.allreduce(np.array([w @ np.sum((u - ue)**2, axis=1), w @ np.sum(ue**2, axis=1)]), op=MPI.SUM)
    return np.sqrt(sums[0] / sums[1])


def energy(w, dx):
    eps = ufl.sym(ufl.grad(w))
    return np.sqrt(integrate(2 * MU_L * ufl.inner(eps, eps) + LMBDA_L * ufl.tr(eps)**2, dx))


def pressurised_shell(refine, octant=True, p=P_L, h0=H0):
    msh, ft = meshes.shell(A_L, B_L, h0, octant=octant, refine=refine)
    pressure = fem.Constant(msh, PETSc.ScalarType(p))
    load = [(meshes.INNER, -pressure * ufl.FacetNormal(msh))]     # dead pressure on r = a
    if octant:
        s = NeoHookeanCellSolver(msh, ft, mu=MU_L, lmbda=LMBDA_L, tractions=load, symmetry=OCTANT_SYMMETRY)
    else:
        s = NeoHookeanCellSolver(msh, ft, mu=MU_L, lmbda=LMBDA_L, tractions=load, remove_rigid_modes=True)
    return s, pressure


# -- 1. Lame's hollow sphere, small strain --------------------------------------------
def test_lame_octant_rate_and_von_mises():
    """Octant on three symmetry planes, two nested levels: P2 L2 rate ~3, von Mises range of the 3D formula."""
    sig_a, sig_b = lame_stresses(A_L), lame_stresses(B_L)
    exact_vm = (abs(sig_b[0] - sig_b[1]), abs(sig_a[0] - sig_a[1]))       # min at r = b, max at r = a
    errors, vm_errors, hs = [], [], []
    for refine in (1, 2):
        s, _ = pressurised_shell(refine)
        s.solve()
        errors.append(relative_errors(s, lame_field(s.mesh, lame_coefficients()))[0])
        vm = s.von_mises_range()
        vm_errors.append(max(abs(vm["stress"][k] - exact_vm[k]) / exact_vm[1] for k in range(2)))
        hs.append(H0 / 2**refine)
    rate = np.log(errors[0] / errors[1]) / np.log(hs[0] / hs[1])
    print(f"\nLame sphere octant, h0/2, h0/4: L2 errors {errors}, rate {rate:.2f}; von Mises range {vm['stress']} "
          f"vs {exact_vm}, relative errors {vm_errors}")
    assert rate >= 2.7, (rate, errors)
    # the 2D formula on the (x, y) block would be 13 % off at (a, 0, 0): the range is the 3D measure
    assert vm_errors[1] < vm_errors[0] and vm_errors[1] < 0.05, vm_errors
    # strain: e = sigma / (2 mu) for these deviatoric differences (small strain)
    assert abs(vm["strain"][1] - exact_vm[1] / (2 * MU_L)) < 2 * vm_errors[1] * exact_vm[1] / (2 * MU_L)


def test_lame_full_sphere_six_rigid_modes():
    """Full sphere, pure traction: the 3-2-1 pins carry nothing and the strains are the free body's.

    The pinned space contains the interpolant of Lame's field plus the rigid motion that
    satisfies the pins, and a rigid motion has no energy: the Galerkin solution's energy-norm
    error is at most that interpolant's (up to the P2 geometry's and the 1e-8 nonlinearity's
    perturbations, far smaller)."""
    s, _ = pressurised_shell(0, octant=False, h0=H_FULL)
    s.solve()
    reaction = s.rigid_mode_reaction
    assert reaction["relative"] < 1e-10, reaction
    u_ex = lame_field(s.mesh, lame_coefficients())
    l2, en = relative_errors(s, u_ex, remove_rigid=True)
    interpolant = fem.Function(s.V)
    interpolant.interpolate(fem.Expression(u_ex, s.V.element.interpolation_points()))
    dx = ufl.dx(domain=s.mesh, metadata={"quadrature_degree": 8})
    en_interp = energy(interpolant - u_ex, dx) / energy(u_ex, dx)
    print(f"\nLame full sphere, pins: reaction {reaction}; L2 {l2:.3e}, energy {en:.3e} "
          f"(interpolant {en_interp:.3e})")
    assert en <= en_interp * (1 + 1e-3), (en, en_interp)


# -- 2. the same sphere at finite strain ------------------------------------------------
MU_F, LMBDA_F, P_F = 1.0, 1.5, 1.5         # hoop stretch 1.47 on the inner face: a large deformation


def p_rr(lr, lt):
    return MU_F * (lr - 1 / lr) + LMBDA_F * lt**2 * (lr * lt**2 - 1)


def p_tt(lr, lt):
    return MU_F * (lt - 1 / lt) + LMBDA_F * lr * lt * (lr * lt**2 - 1)


def _rhs(R, y):
    r, lr = y
    lt = r / R
    J = lr * lt**2
    stiff = MU_F * (1 + 1 / lr**2) + LMBDA_F * lt**4
    return np.vstack([lr, -(2 * (p_rr(lr, lt) - p_tt(lr, lt)) + 2 * LMBDA_F * lt * (2 * J - 1) * (lr - lt))
                      / (R * stiff)])


@pytest.fixture(scope="module")
def radial_solution():
    """r(R) of the sphere under P_F: solve_bvp to 1e-10, checked by an independent DOP853 shot."""
    def bc(ya, yb):
        return np.array([p_rr(ya[1], ya[0] / A_L) + P_F, p_rr(yb[1], yb[0] / B_L)])
    R = np.linspace(A_L, B_L, 50)
    sol = scipy.integrate.solve_bvp(_rhs, bc, R, np.vstack([R, np.ones_like(R)]), tol=1e-10, bc_tol=1e-12,
                                    max_nodes=100000)
    assert sol.status == 0, sol.message
    shot = scipy.integrate.solve_ivp(lambda R, y: _rhs(R, y[:, None])[:, 0], (A_L, B_L), sol.sol(A_L),
                                     method="DOP853", rtol=1e-13, atol=1e-15)
    assert abs(shot.y[0, -1] - sol.sol(B_L)[0]) < 1e-10 * B_L, (shot.y[:, -1], sol.sol(B_L))
    return lambda R: sol.sol(R)[0]


def test_finite_strain_sphere_against_the_radial_ode(radial_solution):
    """Dead internal pressure P_F, 4 load steps, two nested levels: the FE displacement converges to
    the ODE's, and at the finer level its error is far below the linear answer's distance from it
    (so the finite-strain terms are seen)."""
    r = radial_solution
    E_F = MU_F * (3 * LMBDA_F + 2 * MU_F) / (LMBDA_F + MU_F)
    assert np.isclose(LMBDA_F / (2 * (LMBDA_F + MU_F)), NU_L)          # Lame's formula takes nu = NU_L

    def exact(X, radial=r):
        R = np.linalg.norm(X, axis=1)
        return ((radial(R) - R) / R)[:, None] * X

    ka, kb = lame_coefficients(P_F, E_F)
    linear_gap = quadrature_l2_of(exact, lambda X: (ka + kb / np.linalg.norm(X, axis=1)**3)[:, None] * X)
    errors, faces, hs = [], [], []
    for refine in (0, 1):
        msh, ft = meshes.shell(A_L, B_L, H0, octant=True, refine=refine)
        pressure = fem.Constant(msh, PETSc.ScalarType(0.0))
        s = NeoHookeanCellSolver(msh, ft, mu=MU_F, lmbda=LMBDA_F, symmetry=OCTANT_SYMMETRY,
                                 tractions=[(meshes.INNER, -pressure * ufl.FacetNormal(msh))], newton_rtol=1e-12)
        for k in range(1, 5):
            pressure.value = k / 4 * P_F
            s.solve()
        errors.append(quadrature_l2(s, exact))
        n = s.V.dofmap.index_map.size_local
        X = s.V.tabulate_dof_coordinates()[:n]
        R = np.linalg.norm(X, axis=1)
        ur = np.sum(s.displacement.x.array.reshape(-1, 3)[:n] * X, axis=1) / R
        faces.append([gmax(np.abs(ur[np.abs(R - Rf) < 1e-9] - (r(Rf) - Rf))) / (r(Rf) - Rf) for Rf in (A_L, B_L)])
        hs.append(H0 / 2**refine)
    rate = np.log(errors[0] / errors[1]) / np.log(hs[0] / hs[1])
    print(f"\nfinite-strain sphere, P = {P_F}: hoop stretch {r(A_L) / A_L:.4f} (inner), {r(B_L) / B_L:.4f} (outer); "
          f"L2 errors {errors}, rate {rate:.2f}; nodal u_r errors on the faces {faces}; "
          f"the linear (Lame) answer is {linear_gap:.3e} off; finer level: {s.stats['newton_iterations']} Newton "
          f"iterations, {s.stats['factorizations']} factorisations over the 4 load steps")
    assert r(A_L) / A_L > 1.4
    assert rate >= 2.0, (rate, errors)
    assert errors[1] < 0.1 * linear_gap, (errors, linear_gap)


def quadrature_l2_of(exact, other, n=400):
    """Relative L2 distance of two radial fields over the shell (1D quadrature in r)."""
    R, w = np.polynomial.legendre.leggauss(n)
    R = A_L + (B_L - A_L) * (R + 1) / 2
    X = np.column_stack([R, np.zeros_like(R), np.zeros_like(R)])
    d, e = exact(X)[:, 0] - other(X)[:, 0], exact(X)[:, 0]
    return np.sqrt(np.sum(w * R**2 * d**2) / np.sum(w * R**2 * e**2))


# -- 3. interface data on the sphere ------------------------------------------------------
def test_interface_data_on_the_sphere():
    """Hollow sphere, free inner face, the outer sphere r = b a Dirichlet interface with Lame's
    displacement (sigma_rr(a) = 0): points (N, 3) on the sphere, displacement (N, 3) back as given,
    nodal forces (N, 3) against the consistent nodal form of the closed-form traction, two levels.
    The same surface as a Robin interface given the closed-form nodal forces f* and springs towards
    the closed-form displacement u*: its displacement output (N, 3) converges to the closed form."""
    # u = (A + B / r^3) x with sigma_rr(a) = (3 lambda + 2 mu) A - 4 mu B / a^3 = 0
    k = (1e-8, (3 * LMBDA_L + 2 * MU_L) * 1e-8 * A_L**3 / (4 * MU_L))
    errors, robin_errors = [], []
    for refine in (0, 1):
        msh, ft = meshes.shell(A_L, B_L, H_FULL, refine=refine)
        s = NeoHookeanCellSolver(msh, ft, mu=MU_L, lmbda=LMBDA_L, interfaces={"Gamma2": meshes.OUTER})
        X = s.interface_points("Gamma2")
        assert X.shape[1] == 3 and np.abs(np.linalg.norm(X, axis=1) - B_L).max() < 1e-9 * B_L
        g = (k[0] + k[1] / B_L**3) * X
        s.set_interface_data("Gamma2", displacement=g)
        s.solve()
        data = s.interface_data("Gamma2")
        assert data["force"].shape == data["displacement"].shape == X.shape
        np.testing.assert_array_equal(data["displacement"], g)
        # independent: int sigma(u_ex) N . phi_j dS on r = b, the consistent load of Lame's traction
        u_ex = lame_field(msh, k)
        eps = ufl.sym(ufl.grad(u_ex))
        sigma = 2 * MU_L * eps + LMBDA_L * ufl.tr(eps) * ufl.Identity(3)
        v = ufl.TestFunction(s.V)
        form = fem.form(ufl.inner(sigma * ufl.FacetNormal(msh), v) * s.ds(meshes.OUTER))
        b = fem.petsc.assemble_vector(form)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        reference = s.interface_nodes("Gamma2").from_array(b.array)
        b.destroy()
        errors.append(np.linalg.norm(data["force"] - reference) / np.linalg.norm(reference))
        robin = NeoHookeanCellSolver(msh, ft, mu=MU_L, lmbda=LMBDA_L,
                                     robin_interfaces={"Gamma2": (meshes.OUTER, 10 * MU_L / B_L)})
        robin.set_interface_data("Gamma2", displacement=g, force=reference)
        robin.solve()
        u_robin = robin.interface_data("Gamma2")["displacement"]
        robin_errors.append(np.linalg.norm(u_robin - g) / np.linalg.norm(g))
        # the traction is radial and uniform: the net force vanishes by symmetry of the closed surface
        assert np.abs(data["force"].sum(axis=0)).max() < 1e-8 * np.abs(data["force"]).sum()
    sig_b = (3 * LMBDA_L + 2 * MU_L) * k[0] - 4 * MU_L * k[1] / B_L**3
    print(f"\ninterface data on r = b: N = {X.shape[0]} points; sigma_rr(b) = {sig_b:.4e}; "
          f"nodal force errors {errors}; Robin interface displacement errors {robin_errors}")
    assert errors[1] < errors[0] / 2, errors
    # P2: O(h^2) or better at the nodes; halving h must at least halve it
    assert robin_errors[1] < robin_errors[0] / 2, robin_errors


def test_interface_stiffness_of_a_free_ball_has_the_six_rigid_modes():
    """The ball held only on its sphere: the condensed stiffness (3N x 3N) is symmetric positive
    semi-definite with exactly the six rigid motions as null space."""
    msh, ft = meshes.ball(0.03, 0.015, centre=(2.0, -0.2, 0.2))
    s = NeoHookeanCellSolver(msh, ft, mu=0.01, lmbda=0.01, interfaces={"Gamma2": meshes.BOUNDARY})
    K = s.interface_stiffness("Gamma2")
    X = s.interface_points("Gamma2") - np.array([2.0, -0.2, 0.2])
    n = X.shape[0]
    assert K.shape == (3 * n, 3 * n)
    zero, one = np.zeros(n), np.ones(n)
    x, y, z = X.T
    modes = [np.column_stack(c).ravel() for c in ((one, zero, zero), (zero, one, zero), (zero, zero, one),
                                                   (-y, x, zero), (zero, -z, y), (z, zero, -x))]
    scale = np.abs(K).max()
    rigid = max(np.abs(K @ m).max() / (np.abs(m).max() * scale) for m in modes)
    eig = np.linalg.eigvalsh(K) / scale
    print(f"\nfree ball: {n} interface nodes, |K r| / |K| |r| <= {rigid:.1e} for the six rigid modes; "
          f"eigenvalues / max |K|: {eig[:8]}")
    assert np.abs(K - K.T).max() < 1e-12 * scale
    assert rigid < 1e-10
    assert np.abs(eig[:6]).max() < 1e-10 and eig[6] > 1e-6


# -- 4. homogeneous finite strain on tetrahedra ----------------------------------------------
AFFINE_3D = {"triaxial": np.diag([1.1, 0.95, 1.05]),
             "shear": np.array([[1.0, 0.1, 0.05], [0.0, 1.0, 0.2], [0.1, 0.0, 0.9]])}


@pytest.mark.parametrize("case", list(AFFINE_3D))
def test_affine_patch_3d(case):
    """u = (F - I) X on the whole boundary of a box: exact 3D stress, von Mises, end force."""
    msh = dmesh.create_box(MPI.COMM_WORLD, [np.zeros(3), np.array([1.0, 1.0, 1.0])], [3, 3, 3],
                           dmesh.CellType.tetrahedron)
    right = dmesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 1.0))
    others = np.setdiff1d(dmesh.locate_entities_boundary(msh, 2, lambda x: np.full(x.shape[1], True)), right)
    idx = np.hstack([right, others]).astype(np.int32)
    val = np.hstack([np.full(right.size, 1), np.full(others.size, 2)]).astype(np.int32)
    order = np.argsort(idx)
    ft = dmesh.meshtags(msh, 2, idx[order], val[order])
    F = AFFINE_3D[case]
    G = F - np.eye(3)
    s = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, dirichlet=[((1, 2), lambda x: G @ x)], newton_rtol=1e-13)
    s.solve()
    pts, _ = basix.make_quadrature(basix.CellType.tetrahedron, 4)
    cells = np.arange(msh.topology.index_map(3).size_local, dtype=np.int32)
    sig = fem.Expression(s.cauchy_stress_expression(), pts).eval(cells).reshape(-1, 3, 3)
    exact = cauchy(F, 1.0, 1.5)
    err = gmax(np.abs(sig - exact))
    vm = s.von_mises_range()
    force = s.boundary_force(1)
    P = np.linalg.det(F) * exact @ np.linalg.inv(F).T
    print(f"\naffine {case}: stress error {err:.1e}; von Mises {vm['stress']} vs {von_mises_3d(exact):.12f}; "
          f"end force {force} vs {P[:, 0]}")
    assert err < 1e-10
    np.testing.assert_allclose(vm["stress"], [von_mises_3d(exact)] * 2, rtol=1e-10)
    np.testing.assert_allclose(vm["strain"], [von_mises_3d(0.5 * (F.T @ F - np.eye(3)))] * 2, rtol=1e-10)
    np.testing.assert_allclose(s.centroid_displacement(), G @ [0.5, 0.5, 0.5], rtol=1e-12, atol=1e-14)
    # nodal forces on x = 1 (nodes on its edges included): sum = P N area for the unit face
    np.testing.assert_allclose(force, P[:, 0], rtol=0, atol=1e-10)


# -- 5. input checks and ranks ------------------------------------------------------------------
def test_invalid_3d_input():
    msh, ft = meshes.ball(0.03, 0.015)
    kw = dict(mu=0.01, lmbda=0.01)
    with pytest.raises(ValueError, match=r"0 \(x\), 1 \(y\) or 2 \(z\)"):
        NeoHookeanCellSolver(msh, ft, symmetry=[(meshes.BOUNDARY, 3)], **kw)
    with pytest.raises(ValueError, match="3-vector"):
        NeoHookeanCellSolver(msh, ft, remove_rigid_modes=True,
                             tractions=[(meshes.BOUNDARY, ufl.as_vector((1.0, 0.0)))], **kw)
    s = NeoHookeanCellSolver(msh, ft, interfaces={"Gamma2": meshes.BOUNDARY}, **kw)
    n = s.interface_points("Gamma2").shape[0]
    with pytest.raises(ValueError, match=r"shape \(%d, 3\)" % n):
        s.set_interface_data("Gamma2", displacement=np.zeros((n, 2)))


@pytest.mark.mpi
@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="launches its own mpirun")
def test_same_answer_on_one_and_two_ranks_3d():
    assert_same_on_one_and_two_ranks("cell3d_mpi.py")
