"""Verification of the neo-Hookean cell solver (verification.md section 5, our NH variant).

Closed forms are derived from the project's law (model.md section 2)

    sigma = mu J^-1 (F F^T - I) + lambda (J - 1) I,   P = J sigma F^-T   (plane strain)

written here in numpy, independently of the UFL in ``cell/forms.py``.
Measure the numbers quoted in the report with ``pytest -s tests/test_cell.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from mpi4py import MPI
from petsc4py import PETSc

import basix
import dolfinx.fem.petsc  # noqa: F401  (fem.petsc)
import ufl
from dolfinx import fem

from cell import NeoHookeanCellSolver, meshes
from femtools.functions import integrate
from mpi_run import assert_same_on_one_and_two_ranks

MU, LMBDA = 1.0, 1.5  # the moduli of verification.md 5d


# -- closed forms ----------------------------------------------------------------
def cauchy(F, mu=MU, lmbda=LMBDA):
    """Our neo-Hookean Cauchy stress (2x2 in-plane block) for a homogeneous F."""
    J = np.linalg.det(F)
    return mu / J * (F @ F.T - np.eye(2)) + lmbda * (J - 1) * np.eye(2)


def first_piola(F, mu=MU, lmbda=LMBDA):
    return np.linalg.det(F) * cauchy(F, mu, lmbda) @ np.linalg.inv(F).T


def von_mises_2d(s):
    return np.sqrt(s[0, 0]**2 + s[1, 1]**2 - s[0, 0] * s[1, 1] + 3 * s[0, 1]**2)


def lateral_stretch(l1, mu=MU, lmbda=LMBDA):
    """Uniaxial stress: the lateral stretch l2 with sigma_yy(diag(l1, l2)) = 0 (brentq).

    sigma_yy = mu (l2^2 - 1)/(l1 l2) + lambda (l1 l2 - 1) increases monotonically in l2 > 0
    from -inf, so the root in (1e-3, 10) is unique.
    """
    return scipy.optimize.brentq(lambda l2: cauchy(np.diag([l1, l2]), mu, lmbda)[1, 1], 1e-3, 10.0,
                                 xtol=1e-15, rtol=1e-15)


def lame(a, b, p_i, E, nu):
    """Plane-strain Lame cylinder (verification.md 5c): u_r = A r + B / r."""
    s1 = p_i * a**2 / (b**2 - a**2)
    s2 = p_i * a**2 * b**2 / (b**2 - a**2)
    return (1 + nu) / E * (1 - 2 * nu) * s1, (1 + nu) / E * s2


# -- helpers ---------------------------------------------------------------------
def at_quadrature_points(solver, expr, degree=4):
    """Values of a UFL expression at the quadrature points of every owned cell, (n, *shape)."""
    pts, _ = basix.make_quadrature(basix.CellType.triangle, degree)
    e = fem.Expression(expr, pts)
    ncells = solver.mesh.topology.index_map(2).size_local
    return e.eval(np.arange(ncells, dtype=np.int32)).reshape(-1, *expr.ufl_shape)


def gmax(local: np.ndarray) -> float:
    """Maximum of a local array over all ranks (-inf if empty everywhere)."""
    return MPI.COMM_WORLD.allreduce(float(np.max(local, initial=-np.inf)), op=MPI.MAX)


def affine(G):
    """The displacement u = G X as a callable for ``interpolate``/``dirichlet``."""
    return lambda x: G @ x[:2]


@pytest.fixture(scope="module")
def block():
    return meshes.block(2.0, 1.0, 6)


ALL_SIDES = (meshes.LEFT, meshes.RIGHT, meshes.BOTTOM, meshes.TOP)


# -- 1. Lame thick cylinder, small-strain limit ------------------------------------
E_L, NU_L, A_L, B_L = 1.0, 0.3, 1.0, 2.0
# p/E = 1e-8: the neo-Hookean answer differs from the linear one by O(|grad u|) ~ 1e-8
# relative, a thousand times below the smallest discretisation error measured (2e-5).
P_L = 1e-8


def lame_solver(h, quarter=False):
    msh, ft = meshes.annulus(A_L, B_L, h, quarter=quarter)
    mu = E_L / (2 * (1 + NU_L))
    lmbda = E_L * NU_L / ((1 + NU_L) * (1 - 2 * NU_L))
    p = fem.Constant(msh, PETSc.ScalarType(P_L))
    load = [(meshes.INNER, -p * ufl.FacetNormal(msh))]   # dead pressure on r = a
    if quarter:
        return NeoHookeanCellSolver(msh, ft, mu=mu, lmbda=lmbda, tractions=load,
                                    symmetry=[(meshes.XAXIS, 1), (meshes.YAXIS, 0)])
    return NeoHookeanCellSolver(msh, ft, mu=mu, lmbda=lmbda, tractions=load, remove_rigid_modes=True)


def lame_error(solver):
    """Relative L2 error of u against Lame, minimised over the rigid modes; and the rigid fit."""
    msh = solver.mesh
    x = ufl.SpatialCoordinate(msh)
    k = fem.Constant(msh, PETSc.ScalarType((0.0, 0.0)))
    k.value = lame(A_L, B_L, P_L, E_L, NU_L)
    r2 = x[0]**2 + x[1]**2
    u_ex = (k[0] + k[1] / r2) * x
    modes = [ufl.as_vector((1.0, 0.0)), ufl.as_vector((0.0, 1.0)), ufl.as_vector((-x[1], x[0]))]
    dx = ufl.dx(domain=msh, metadata={"quadrature_degree": 8})
    e = solver.displacement_scale * solver.displacement - u_ex
    M = np.array([[integrate(ufl.inner(m, n), dx) for n in modes] for m in modes])
    c = fem.Constant(msh, PETSc.ScalarType((0.0, 0.0, 0.0)))
    c.value = np.linalg.solve(M, [integrate(ufl.inner(e, m), dx) for m in modes])
    e = e - c[0] * modes[0] - c[1] * modes[1] - c[2] * modes[2]
    return np.sqrt(integrate(ufl.inner(e, e), dx) / integrate(ufl.inner(u_ex, u_ex), dx)), c.value.copy()


def inner_radial_errors(solver, rigid):
    """Relative errors of u_r on r = a: (mean over the circle, max over its nodes).

    The mean, -int u.N dS / int dS with N the annulus' outward normal, is
    blind to rigid motions on the discrete (P2) circle: int N dS = 0 and
    (-y, x).N dS = -d(r^2/2) integrate to zero exactly.  The nodal values
    have the rigid fit ``rigid`` (from ``lame_error``) removed.
    """
    msh = solver.mesh
    ka, kb = lame(A_L, B_L, P_L, E_L, NU_L)
    exact = ka * A_L + kb / A_L
    ds = solver.ds(meshes.INNER)
    one = fem.Constant(msh, PETSc.ScalarType(1.0))
    u = solver.displacement_scale * solver.displacement
    mean = -integrate(ufl.dot(u, ufl.FacetNormal(msh)), ds) / integrate(one, ds)
    n = solver.V.dofmap.index_map.size_local
    X = solver.V.tabulate_dof_coordinates()[:n, :2]
    un = solver.displacement_scale * solver.displacement.x.array.reshape(-1, 2)[:n]
    un = un - rigid[:2] - rigid[2] * np.column_stack([-X[:, 1], X[:, 0]])
    r = np.linalg.norm(X, axis=1)
    on = np.abs(r - A_L) < 1e-9
    nodal = np.abs(np.sum(un[on] * X[on], axis=1) / r[on] - exact).max(initial=0.0) / exact
    return abs(mean - exact) / exact, solver.comm.allreduce(nodal, op=MPI.MAX)


def test_lame_full_annulus_rate_and_rigid_modes():
    """Full annulus, pure traction: rigid modes removed by the pins; P2 L2 rate ~ 3."""
    hs = [0.4, 2 * np.pi * A_L / 32, 0.1]      # the middle mesh: 32 elements on r = a
    errors, radial = [], None
    for h in hs:
        s = lame_solver(h)
        s.solve()
        err, rigid = lame_error(s)
        errors.append(err)
        # the pressure is exactly self-equilibrated: the pins carry (round-off) nothing
        assert s.rigid_mode_reaction["relative"] < 1e-10, s.rigid_mode_reaction
        if h == hs[1]:
            radial = inner_radial_errors(s, rigid)
    rate = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    print(f"\nLame full annulus: h {hs}, L2 errors {errors}, rate {rate:.3f}; "
          f"u_r(a) errors at 32/circumference: mean {radial[0]:.2e}, nodal max {radial[1]:.2e}")
    assert rate >= 2.7, f"L2 rate {rate:.3f} (errors {errors})"
    assert errors[-1] < 5e-5, f"L2 errors {errors}"
    assert radial[0] < 1e-4, f"mean u_r(a) relative error {radial[0]:.2e} at 32 elements per circumference"


def test_lame_quarter_annulus_symmetry():
    """Quarter annulus with the two symmetry lines (no rigid mode left): u_r(a) at 32 and 64/circ."""
    results = []
    for n in (32, 64):
        s = lame_solver(2 * np.pi * A_L / n, quarter=True)
        s.solve()
        err, rigid = lame_error(s)
        # symmetry lines leave no rigid mode: the best rigid fit is at discretisation level
        assert np.abs(rigid).max() < 1e-4 * sum(lame(A_L, B_L, P_L, E_L, NU_L)), rigid
        results.append((err, *inner_radial_errors(s, np.zeros(3))))
    print(f"\nLame quarter annulus (L2, mean u_r(a), nodal max u_r(a)): 32/circ {results[0]}, "
          f"64/circ {results[1]}")
    assert results[0][1] < 1e-4, f"mean u_r(a) relative error {results[0][1]:.2e} at 32/circumference"
    # nodal values converge too; within 1e-4 from 64 elements per circumference on
    assert results[0][2] < 1e-3 and results[1][2] < 1e-4, results
    assert results[1][0] < results[0][0] / 5, results


def test_unbalanced_traction_is_detected():
    """A uniform traction on the outer circle has resultant 2 pi b t: the pins must carry it."""
    msh, ft = meshes.annulus(A_L, B_L, 0.4)
    t = np.array([1e-6, 0.0])
    s = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.0, tractions=[(meshes.OUTER, t)],
                             remove_rigid_modes=True)
    with pytest.raises(RuntimeError, match="not self-equilibrated"):
        s.solve()
    perimeter = integrate(fem.Constant(msh, PETSc.ScalarType(1.0)), s.ds(meshes.OUTER))
    np.testing.assert_allclose(s.rigid_mode_reaction["force"], -t * perimeter, rtol=1e-9, atol=1e-15)


def test_traction_update_scales_the_small_strain_answer():
    """Callable tractions can be changed between solves; at p/E = 1e-8 the response is linear."""
    msh, ft = meshes.annulus(A_L, B_L, 0.4, quarter=True)
    p = 1e-8

    def outer_pressure(scale):
        return lambda x: -scale * p * x[:2] / np.linalg.norm(x[:2], axis=0)    # -p N on r = b

    s = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.0, tractions=[(meshes.OUTER, outer_pressure(1.0))],
                             symmetry=[(meshes.XAXIS, 1), (meshes.YAXIS, 0)])
    s.solve()
    u1 = s.displacement.x.array.copy()
    s.set_traction(0, outer_pressure(2.0))
    s.solve()
    assert gmax(np.abs(s.displacement.x.array - 2 * u1)) < 1e-6 * gmax(np.abs(u1))
    # the outer pressure compresses: u_r < 0 at r = b
    n = s.V.dofmap.index_map.size_local
    X = s.V.tabulate_dof_coordinates()[:n, :2]
    on = np.abs(np.linalg.norm(X, axis=1) - B_L) < 1e-9
    assert gmax(np.sum(s.displacement.x.array.reshape(-1, 2)[:n][on] * X[on], axis=1)) < 0
    with pytest.raises(TypeError, match="UFL"):
        lame_solver(0.4, quarter=True).set_traction(0, [0.0, 0.0])


# -- 2. homogeneous finite strains on a distorted mesh ---------------------------------
AFFINE = {"uniaxial strain": np.diag([1.1, 1.0]), "simple shear": np.array([[1.0, 0.1], [0.0, 1.0]]),
          "equibiaxial": np.diag([0.95, 0.95])}


@pytest.mark.parametrize("case", list(AFFINE))
def test_affine_patch(block, case):
    """u = (F - I) X on the whole boundary: exact stress, strain, centroid; quadratic Newton."""
    msh, ft = block
    F = AFFINE[case]
    G = F - np.eye(2)
    s = NeoHookeanCellSolver(msh, ft, mu=MU, lmbda=LMBDA, dirichlet=[(ALL_SIDES, affine(G))],
                             reuse="never", newton_rtol=1e-14)
    # start away from the answer (a bubble inside), so that Newton has work to do
    s.displacement.interpolate(lambda x: 0.3 * np.vstack([np.sin(np.pi * x[0] / 2) * np.sin(np.pi * x[1]),
                                                          x[0] * (2 - x[0]) * x[1] * (1 - x[1])]))
    s.solve()
    sigma = at_quadrature_points(s, s.cauchy_stress_expression())
    E = at_quadrature_points(s, s.green_lagrange_expression())
    err_s = gmax(np.abs(sigma - cauchy(F)))
    err_E = gmax(np.abs(E - 0.5 * (F.T @ F - np.eye(2))))
    hist = s.newton_history
    print(f"\n{case}: stress error {err_s:.1e}, strain error {err_E:.1e}, Newton {hist}")
    assert err_s < 1e-10 and err_E < 1e-10, (err_s, err_E)
    # quadratic convergence: each correction about the square of the previous one
    # (below 0.1, above the round-off floor); modified Newton gives b ~ c a, not b ~ c a^2
    pairs = [(a, b) for a, b in zip(hist, hist[1:]) if a < 0.1 and b > 1e-13]
    ratios = [b / a**2 for a, b in pairs]
    print(f"  quadratic ratios |du_k+1| / |du_k|^2: {ratios}")
    assert len(pairs) >= 2, f"too few informative Newton steps in {hist}"
    assert max(ratios) < 10, f"not quadratic: corrections {hist}, ratios {ratios}"
    # accessors against the same closed forms
    vm = s.von_mises_range()
    np.testing.assert_allclose(vm["stress"], [von_mises_2d(cauchy(F))] * 2, rtol=1e-10)
    np.testing.assert_allclose(vm["strain"], [von_mises_2d(0.5 * (F.T @ F - np.eye(2)))] * 2,
                               rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(s.centroid_displacement(), G @ [1.0, 0.5], rtol=1e-12, atol=1e-14)
    corners = np.array([[0, 0], [2, 0], [0, 1], [2, 1]], dtype=float)
    assert np.isclose(s.max_displacement(), np.linalg.norm(corners @ G.T, axis=1).max(), rtol=1e-12)
    # the DG output fields (interpolated cell by cell)
    assert gmax(np.abs(s.cauchy_stress().x.array.reshape(-1, 2, 2) - cauchy(F))) < 1e-10
    E_dg = s.green_lagrange_strain().x.array.reshape(-1, 2, 2)
    assert gmax(np.abs(E_dg - 0.5 * (F.T @ F - np.eye(2)))) < 1e-10
    assert gmax(np.abs(s.von_mises_stress().x.array - von_mises_2d(cauchy(F)))) < 1e-10
    assert gmax(np.abs(s.von_mises_strain().x.array - von_mises_2d(0.5 * (F.T @ F - np.eye(2))))) < 1e-10


def test_adaptive_reuse_converges_to_the_same_answer(block):
    """Modified Newton (reuse="adaptive") converges linearly to the full-Newton answer."""
    msh, ft = block
    l1 = 1.2
    answers = {}
    for reuse in ("never", "adaptive"):
        s = NeoHookeanCellSolver(msh, ft, mu=MU, lmbda=LMBDA, reuse=reuse,
                                 symmetry=[(meshes.LEFT, 0), (meshes.BOTTOM, 1)],
                                 dirichlet=[(meshes.RIGHT, (l1 - 1) * 2.0, 0)])
        s.solve()
        answers[reuse] = (s.displacement.x.array.copy(), dict(s.stats), s.newton_history)
    u_n, st_n, h_n = answers["never"]
    u_a, st_a, h_a = answers["adaptive"]
    print(f"\nfull Newton {h_n} ({st_n['factorizations']} LU); adaptive {h_a} ({st_a['factorizations']} LU)")
    assert gmax(np.abs(u_a - u_n)) < 1e-9 * gmax(np.abs(u_n))
    assert st_a["factorizations"] < st_n["factorizations"]


# -- 3. uniaxial stress at finite stretch -------------------------------------------
@pytest.mark.parametrize("l1", [0.8, 1.3])
def test_uniaxial_stress(block, l1):
    """Free lateral side: lateral stretch and end force against the brentq closed form."""
    msh, ft = block
    L, H = 2.0, 1.0
    s = NeoHookeanCellSolver(msh, ft, mu=MU, lmbda=LMBDA,
                             symmetry=[(meshes.LEFT, 0), (meshes.BOTTOM, 1)],
                             dirichlet=[(meshes.RIGHT, (l1 - 1) * L, 0)])
    s.solve()
    l2 = lateral_stretch(l1)
    F = np.diag([l1, l2])
    n = s.V.dofmap.index_map.size_local
    X = s.V.tabulate_dof_coordinates()[:n, :2]
    u = s.displacement.x.array.reshape(-1, 2)[:n]
    top = np.isclose(X[:, 1], H)
    l2_error = gmax(np.abs(1 + u[top, 1] / H - l2))        # every node of the free side
    force = s.boundary_force(meshes.RIGHT)
    exact = first_piola(F)[0, 0] * H      # = sigma_xx * l2 * H, reference-configuration force
    print(f"\nuniaxial stress l1={l1}: l2 {l2:.12f}, FE error {l2_error:.1e}; force {force}, exact {exact:.12f}")
    assert l2_error < 1e-10
    assert abs(force[0] - exact) < 1e-10 * abs(exact) and abs(force[1]) < 1e-10 * abs(exact)
    assert np.isclose(exact, cauchy(F)[0, 0] * l2 * H, rtol=1e-12)


# -- 4. consistent reaction at an interface -------------------------------------------
def test_interface_force_is_the_consistent_reaction(block):
    """Uniaxial strain, right end an interface: nodal forces = P_xx int phi_j dS, sum = sigma_xx H."""
    msh, ft = block
    F = np.diag([1.1, 1.0])
    G = F - np.eye(2)
    d = 0.5                                   # a displacement unit != 1 on purpose
    s = NeoHookeanCellSolver(msh, ft, mu=MU, lmbda=LMBDA, displacement_scale=d,
                             interfaces={"end": meshes.RIGHT},
                             dirichlet=[((meshes.LEFT, meshes.BOTTOM, meshes.TOP), affine(G / d))])
    s.set_interface_data("end", displacement=s.interface_points("end") @ G.T / d)
    s.solve()
    force = s.interface_data("end")["force"]
    # independent: int phi_j dS on the right end, the consistent load of a unit traction
    v = ufl.TestFunction(s.V)
    b = fem.petsc.assemble_vector(fem.form(v[0] * ufl.ds(domain=msh, subdomain_data=ft)(meshes.RIGHT)))
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    weights = s.interface_nodes("end").from_array(b.array)[:, 0]
    P = first_piola(F)
    H = 1.0
    print(f"\ninterface force sum {force.sum(axis=0)}, closed form ({cauchy(F)[0, 0] * H}, 0)")
    np.testing.assert_allclose(force[:, 0], P[0, 0] * weights, rtol=0, atol=1e-12)
    np.testing.assert_allclose(force.sum(axis=0), [cauchy(F)[0, 0] * H, 0.0], rtol=0, atol=1e-11)


# -- 5. both scaling paths ------------------------------------------------------------
@pytest.mark.parametrize("strain", [1e-6, 0.2])
def test_scaling_paths_agree(block, strain):
    """s = d = 1 and s = d = 3e-10 give the same physical answer (device-small and finite strain)."""
    msh, ft = block
    mu, lmbda = 0.01, 0.01                    # the default cell in units of mu_s (model.md 5)
    G = np.array([[strain, 0.3 * strain], [0.0, -0.5 * strain]])
    out = []
    for scale in (1.0, 3e-10):
        s = NeoHookeanCellSolver(msh, ft, mu=mu, lmbda=lmbda, stress_scale=scale, displacement_scale=scale,
                                 interfaces={"end": meshes.RIGHT}, symmetry=[(meshes.LEFT, 0), (meshes.BOTTOM, 1)])
        pts = s.interface_points("end")
        bump = pts[:, 1:] * (1 - pts[:, 1:])   # a non-affine end displacement
        s.set_interface_data("end", displacement=(pts @ G.T + strain * bump) / scale)
        s.solve()
        out.append({"u": scale * s.displacement.x.array, "force": scale * s.interface_data("end")["force"],
                    "centroid": s.centroid_displacement(), "umax": s.max_displacement(),
                    "vm": np.array(list(s.von_mises_range().values()))})
    print(f"\nscaling paths, strain {strain}: force sum {out[0]['force'].sum(0)} vs {out[1]['force'].sum(0)}")
    for key in out[0]:
        ref = gmax(np.abs(out[0][key]))
        assert ref > 0
        assert gmax(np.abs(out[1][key] - out[0][key])) < 1e-8 * ref, key


# -- 6. serial == parallel --------------------------------------------------------------
@pytest.mark.mpi
@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="launches its own mpirun")
def test_same_answer_on_one_and_two_ranks():
    assert_same_on_one_and_two_ranks("cell_mpi.py")


# -- factorise once ------------------------------------------------------------------
def test_interface_updates_reuse_the_factorisation():
    """Device-small strains: new interface data do not refactorise; the answer is full Newton's."""
    msh, ft = meshes.disk(0.03, 0.004)
    kw = dict(mu=0.01, lmbda=0.01, stress_scale=3e-10, displacement_scale=3e-10,
              interfaces={"Gamma2": meshes.BOUNDARY})
    adaptive, never = NeoHookeanCellSolver(msh, ft, **kw), NeoHookeanCellSolver(msh, ft, reuse="never", **kw)
    X = adaptive.interface_points("Gamma2") / 0.03          # on the unit circle
    for k, amp in enumerate([1e-6, 1.3e-6, 0.7e-6]):       # physical displacements ~ 1e-6 L0
        g = amp * np.column_stack([-X[:, 0] + 0.2 * X[:, 1], 0.5 * X[:, 1] + 0.1 * k * X[:, 0]**2])
        for s in (adaptive, never):
            s.set_interface_data("Gamma2", displacement=g / 3e-10)
            s.solve()
        fa, fn = adaptive.interface_data("Gamma2")["force"], never.interface_data("Gamma2")["force"]
        assert np.abs(fa - fn).max() < 1e-9 * np.abs(fn).max()
    print(f"\nadaptive {adaptive.stats}\nnever    {never.stats}")
    assert adaptive.stats["factorizations"] == 1
    assert never.stats["factorizations"] >= 3


# -- input validation -------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, match", [
    (dict(mu=0.0), "mu must be > 0"),
    (dict(mu=-1.0), "mu must be > 0"),
    (dict(lmbda=-0.7), "Poisson ratio"),
    (dict(mu=float("nan")), "finite"),
    (dict(stress_scale=0.0), "stress_scale must be > 0"),
    (dict(displacement_scale=-1e-3), "displacement_scale must be > 0"),
    (dict(reuse="always"), "reuse"),
    (dict(quadrature_degree=0), "quadrature_degree"),
    (dict(interfaces={"G": 99}), "no facets tagged"),
    (dict(symmetry=[(meshes.LEFT, 2)]), "component must be 0"),
    (dict(interfaces={}, remove_rigid_modes=True, symmetry=[(meshes.LEFT, 0)]), "pure traction"),
    (dict(interfaces={}), "no displacement is prescribed"),
])
def test_invalid_input(block, kwargs, match):
    msh, ft = block
    args = dict(mu=1.0, lmbda=1.0, interfaces={"end": meshes.RIGHT})
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        NeoHookeanCellSolver(msh, ft, **args)


def test_interface_data_shape_is_checked(block):
    msh, ft = block
    s = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.0, interfaces={"end": meshes.RIGHT})
    with pytest.raises(ValueError, match="shape"):
        s.set_interface_data("end", displacement=np.zeros((3, 2)))
    with pytest.raises(KeyError, match="takes"):
        s.set_interface_data("end", traction=np.zeros((s.interface_nodes("end").size, 2)))


@pytest.mark.benchmark
@pytest.mark.parametrize("h", [0.003, 0.0012])
def test_benchmark_factorise_once(h):
    """Time of an interface-data solve that reuses the factorised Jacobian vs one that refactorises."""
    import time
    msh, ft = meshes.disk(0.03, h)
    kw = dict(mu=0.01, lmbda=0.01, stress_scale=3e-10, displacement_scale=3e-10,
              interfaces={"Gamma2": meshes.BOUNDARY})
    times = {}
    for reuse in ("adaptive", "never"):
        s = NeoHookeanCellSolver(msh, ft, reuse=reuse, **kw)
        X = s.interface_points("Gamma2") / 0.03
        walls = []
        for k in range(6):
            g = 1e-6 * (1 + 0.1 * k) * np.column_stack([-X[:, 0] + 0.2 * X[:, 1], 0.5 * X[:, 1]])
            s.set_interface_data("Gamma2", displacement=g / 3e-10)
            t0 = time.perf_counter()
            s.solve()
            walls.append(time.perf_counter() - t0)
        times[reuse] = (np.median(walls[1:]), dict(s.stats))
    ndofs = s.V.dofmap.index_map.size_global * 2
    print(f"\nfactorise once, {ndofs} dofs: reuse {times['adaptive'][0] * 1e3:.1f} ms/solve "
          f"({times['adaptive'][1]['factorizations']} LU in 6 solves), refactorise "
          f"{times['never'][0] * 1e3:.1f} ms/solve ({times['never'][1]['factorizations']} LU)")
    assert times["adaptive"][1]["factorizations"] == 1


def test_robin_interface_patch():
    """Robin data taken from an affine finite-strain state reproduce that state.

    With u* = the affine displacement and f* = its exact nodal reactions on
    the Robin boundary, the spring term vanishes at the affine state, which
    therefore solves  int P : grad v + int kappa (u - u*) . v = f*(v).
    Any kappa > 0 must give it (and kappa holds the rigid modes).
    """
    from cell.meshes import BOUNDARY, disk
    msh, ft = disk(radius=1.0, h=0.25)
    tag = BOUNDARY
    Fm = np.array([[1.05, 0.02], [-0.01, 0.97]])
    affine = lambda x: np.vstack(((Fm[0, 0] - 1) * x[0] + Fm[0, 1] * x[1],  # noqa: E731
                                  Fm[1, 0] * x[0] + (Fm[1, 1] - 1) * x[1]))
    reference = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, dirichlet=[(tag, affine)])
    reference.solve()
    from femtools.interface import InterfaceNodes
    nodes = InterfaceNodes(reference.V, ft, tag)
    from femtools.linalg import assemble_residual_vector
    R = nodes.from_array(assemble_residual_vector(reference._internal_form).array)
    u_star = nodes.from_function(reference.displacement)
    for kappa in (0.1, 10.0):
        robin = NeoHookeanCellSolver(msh, ft, mu=1.0, lmbda=1.5, robin_interfaces={"G": (tag, kappa)})
        robin.set_interface_data("G", displacement=u_star, force=R)
        robin.solve()
        out = robin.interface_data("G")
        assert np.abs(out["displacement"] - u_star).max() < 1e-10 * np.abs(u_star).max()
        assert np.abs(out["force"] - R).max() < 1e-9 * np.abs(R).max()
