"""The gel in total Lagrangian form (``kinematics="finite"``, gel/lagrangian.py) at large strain.

Every reference here is derived from the model's equations in the CURRENT
configuration (model.md section 2), not from the code's weak forms:

* homogeneous states (confined and unconfined compression, simple shear, a
  rotated and stretched Darcy layer): the neo-Hookean network with
  phi_s = phi_s0/J, the nominal traction P N = J sigma F^-T N on the loaded
  faces; the exact displacement is linear in X, so it lies in the P2 space
  and the discrete solution must reproduce it to the Newton tolerance;
* a manufactured solution whose source terms sympy derives from the strong
  form div_x(sigma) etc. with spatial derivatives (grad_x = grad_X F^-1),
  independently of gel/lagrangian.py, with its convergence rates.

The solver runs in the paper's units (s = d = 1) unless a test says otherwise.
Derivations: docs/finite-strain.md.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import sympy as sp

from mpi4py import MPI

import ufl
from dolfinx import fem

from femtools.errors import NewtonError
from femtools.interface import InterfaceNodes
from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, rectangle_mesh
from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver
from test_gel import l2 as norm_l2, rates

COMM = MPI.COMM_WORLD


def nodal(gel, name, field):
    return gel.interface_data(name)[field]


def network_cauchy(F, lambda_s):
    """Neo-Hookean Cauchy stress J^-1 (F F^T - I) + lambda_s (J - 1) I (model.md section 2), numpy."""
    J = np.linalg.det(F)
    return (F @ F.T - np.eye(2)) / J + lambda_s * (J - 1) * np.eye(2)


def uniaxial_lateral_stretch(l2, lambda_s):
    """lambda_1 with sigma_xx = 0 for F = diag(lambda_1, l2): (l1^2 - 1)/J + lambda_s (J - 1) = 0."""
    f = lambda l1: network_cauchy(np.diag([l1, l2]), lambda_s)[0, 0]   # noqa: E731
    return scipy.optimize.brentq(f, 0.5, 2.0, xtol=1e-15, rtol=1e-15)


PRM = GelParameters(phi_s0=0.1, lambda_s=1.5, Ca=1.0)


# --------------------------------------------------------------------------
# drained compression of a column: confined (oedometer) and unconfined
# --------------------------------------------------------------------------
@pytest.mark.parametrize("strain", [0.1, 0.2, 0.3])
@pytest.mark.parametrize("confined", [True, False], ids=["confined", "unconfined"])
def test_drained_column_compression(strain, confined):
    """A drained column 0 < x < W, 0 < y < H compressed by a dead nominal load on its top.

    Drained steady state: no flow, p = 0 (the open faces), so the network
    carries the load alone.  Homogeneous F = diag(l1, l2), l2 = 1 - strain:

        confined   l1 = 1 (sides slide on walls),
        unconfined sigma_xx = 0 gives l1 (sides free),
        load       t = P_yy = J phi_s sigma_yy F^-T_yy = phi_s0 sigma_yy / l2   (phi_s = phi_s0/J)

    and the top settles at u_y(H) = (l2 - 1) H, the free side at u_x(W) = (l1 - 1) W.
    Confined, F = diag(1, l2) makes Cauchy and first Piola agree (J F^-T_yy = 1):
    this checks the law and phi_s(J); unconfined (l1 > 1) they differ by l1.
    """
    H, W = 1.0, 0.25
    l2 = 1.0 - strain
    l1 = 1.0 if confined else uniaxial_lateral_stretch(l2, PRM.lambda_s)
    t = PRM.phi_s0 * network_cauchy(np.diag([l1, l2]), PRM.lambda_s)[1, 1] / l2
    msh, ft = rectangle_mesh(0.0, 0.0, W, H, 2, 4)
    sides = [((LEFT, RIGHT), 0)] if confined else [(LEFT, 0)]
    gel = PoroelasticGelSolver(msh, ft, PRM, symmetry=sides + [(BOTTOM, 1)], tractions=[(TOP, (0.0, t))],
                               kinematics="finite")
    gel.solve()
    u = gel.displacement()
    x = ufl.SpatialCoordinate(msh)
    exact = ufl.as_vector(((l1 - 1) * x[0], (l2 - 1) * x[1]))
    err = norm_l2(u - exact, msh) / norm_l2(exact, msh)
    print(f"{'confined' if confined else 'unconfined'} {strain:.0%}: l1 = {l1:.6f}, load {t:.6e}, "
          f"relative L2 error of u {err:.1e}, Newton {gel.newton.history}")
    # the exact u is linear (in the P2 space): only the Newton tolerance (1e-11) remains
    assert err < 1e-9, err
    assert np.abs(gel.pore_pressure().x.array).max() < 1e-9 * abs(t)


def test_unconfined_compression_small_path_misses_the_first_piola_stress():
    """The same 20 % unconfined load on the small-strain path: the Cauchy stress used as if it were P
    balances the load with l1 = 1.11 times too small a stress, so the column is compressed more."""
    H, W, strain = 1.0, 0.25, 0.2
    l2 = 1.0 - strain
    l1 = uniaxial_lateral_stretch(l2, PRM.lambda_s)
    t = PRM.phi_s0 * network_cauchy(np.diag([l1, l2]), PRM.lambda_s)[1, 1] / l2
    msh, ft = rectangle_mesh(0.0, 0.0, W, H, 2, 4)
    gel = PoroelasticGelSolver(msh, ft, PRM, symmetry=[(LEFT, 0), (BOTTOM, 1)], tractions=[(TOP, (0.0, t))])
    gel.solve()
    top = InterfaceNodes(gel.displacement().function_space, ft, TOP).from_function(gel.displacement())
    print(f"unconfined 20 % on the small path: u_y(H) = {top[:, 1].mean():.5f}, exact {l2 - 1:.5f}")
    assert abs(top[:, 1].mean() - (l2 - 1) * H) > 0.01 * strain


# --------------------------------------------------------------------------
# simple shear of a layer
# --------------------------------------------------------------------------
@pytest.mark.parametrize("gamma", [0.5, 1.0])
def test_simple_shear_of_a_layer(gamma):
    """Simple shear x = X + gamma Y, F = [[1, gamma], [0, 1]], J = 1, of a drained layer.

    sigma_s = F F^T - I = [[gamma^2, gamma], [gamma, 0]] and P = J sigma_s F^-T = [[0, gamma], [gamma, 0]]:
    the nominal tractions phi_s0 P N are (phi_s0 gamma, 0) on the top and (0, +-phi_s0 gamma) on the
    sides; the Cauchy traction on the sides, (+-phi_s0 gamma^2, phi_s0 gamma), would differ.  With these
    dead loads and the bottom held, the layer takes u = (gamma y, 0) exactly.  The small-strain path
    (sigma in place of P, gradients in X) does not: it is checked to miss it (or to fail).
    """
    H, W = 0.5, 1.0
    msh, ft = rectangle_mesh(0.0, 0.0, W, H, 4, 2)
    g = PRM.phi_s0 * gamma
    loads = [(TOP, (g, 0.0)), (RIGHT, (0.0, g)), (LEFT, (0.0, -g))]
    x = ufl.SpatialCoordinate(msh)
    exact = ufl.as_vector((gamma * x[1], 0.0 * x[1]))
    errors = {}
    for kinematics in ("finite", "small"):
        gel = PoroelasticGelSolver(msh, ft, PRM, no_slip=BOTTOM, tractions=loads, kinematics=kinematics)
        try:
            for step in (0.25, 0.5, 0.75, 1.0):      # dead loads: load stepping keeps Newton in its basin
                for k, (_, value) in enumerate(loads):
                    gel.set_traction(k, step * np.asarray(value))
                gel.solve()
        except NewtonError:
            errors[kinematics] = np.inf
            continue
        errors[kinematics] = norm_l2(gel.displacement() - exact, msh) / norm_l2(exact, msh)
    print(f"simple shear gamma = {gamma}: relative L2 error of u, finite {errors['finite']:.1e}, "
          f"small {errors['small']:.1e}")
    assert errors["finite"] < 1e-9
    assert errors["small"] > 1e-2


# --------------------------------------------------------------------------
# Darcy flow through a rotated, stretched layer: the interface terms on the current interface
# --------------------------------------------------------------------------
def test_darcy_layer_rotated_and_stretched():
    """Uniform permeation of a layer that is stretched sideways by 20 % and turned by 30 degrees.

    The network is held on three sides by the homogeneous map x = F X,
    F = R(30 deg) diag(l1, l2), l2 = 1.2 and sigma_xx(l1, l2) = 0 (free axially);
    the fluid at rest on both faces, pressure p_in upstream and 0 downstream.
    In the current configuration the layer has thickness l = l1 L and
    phi_s = phi_s0 / (l1 l2); the flow is uniform along R e_x and the
    closed form of the Darcy layer with the I15 jumps (test_gel.py) holds there:

        v = p_in / (xi nu phi_s l + 2 r),  r = nu phi_s / (eta phi_f),
        p(0) = p_in - r v,  p(l) = r v.

    The upstream face has length l2 H and normal -R e_x: the gel receives the
    nominal traction j T = l2 p_in R e_x.  The flow's own load on the network
    (p_in = 1e-6 against a drained modulus 0.35) changes phi_s by ~1e-6: the
    tolerance is 1e-5.  The interface terms see j, the rotated normal and
    phi_s(J); the flux the Piola transform.
    """
    prm = GelParameters(phi_s0=0.1, lambda_s=1.5, xi=4.5e4, eta=0.02, Ca=1e-6)
    L, H, p_in, angle, l2 = 1.0, 0.25, 1e-6, np.pi / 6, 1.2
    l1 = uniaxial_lateral_stretch(l2, prm.lambda_s)
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    F = R @ np.diag([l1, l2])
    nu, phi_s = prm.viscosity, prm.phi_s0 / (l1 * l2)
    phi_f = 1 - phi_s
    r = nu * phi_s / (prm.eta * phi_f)
    v = p_in / (prm.xi * nu * phi_s * l1 * L + 2 * r)
    e = R[:, 0]
    msh, ft = rectangle_mesh(0.0, 0.0, L, H, 4, 1)

    def homogeneous(X):
        return (F - np.eye(2)) @ X[:2]
    gel = PoroelasticGelSolver(msh, ft, prm, fluid_interfaces={"in": LEFT, "out": RIGHT}, kinematics="finite",
                               dirichlet=[((BOTTOM, TOP, RIGHT), "u", homogeneous),
                                          ((BOTTOM, TOP), "v_f", tuple(v * e))])
    n_in, n_out = (gel.interface_points(k).shape[0] for k in ("in", "out"))
    gel.set_interface_data("in", traction=np.tile(l2 * p_in * e, (n_in, 1)), velocity=np.zeros((n_in, 2)))
    gel.set_interface_data("out", traction=np.zeros((n_out, 2)), velocity=np.zeros((n_out, 2)))
    gel.solve()
    vf = gel.interstitial_velocity().x.array.reshape(-1, 2)
    err_v = np.abs(vf - v * e).max() / v
    p_up, p_down = nodal(gel, "in", "pressure"), nodal(gel, "out", "pressure")
    err_p = max(np.abs(p_up - (p_in - r * v)).max(), np.abs(p_down - r * v).max()) / p_in
    X = gel.interface_points("in")
    u_in = nodal(gel, "in", "displacement")
    err_u = np.abs(u_in - ((F - np.eye(2)) @ X.T).T).max()
    # sum_i int j (q.n) psi_i n dA = int (q.n) n da; n = -e and q.n = -phi_f v: phi_f v l2 H e
    flux = nodal(gel, "in", "normal_flux").sum(axis=0) @ e
    err_q = abs(flux - phi_f * v * l2 * H) / (phi_f * v * l2 * H)
    print(f"rotated stretched layer: l1 = {l1:.6f}, v = {v:.6e}, errors v {err_v:.1e}, p {err_p:.1e}, "
          f"u {err_u:.1e}, flux {err_q:.1e}")
    assert err_v < 1e-5 and err_p < 1e-5 and err_q < 1e-5
    assert err_u < 1e-5 * np.abs(u_in).max()


# --------------------------------------------------------------------------
# Newton: quadratic convergence with the exact Jacobian
# --------------------------------------------------------------------------
def test_exact_newton_converges_quadratically():
    """The 30 % unconfined column with a factorisation per iteration: e_{k+1} <= C e_k^2.

    Quadratic convergence needs the exact Jacobian of the total Lagrangian
    residual (ufl.derivative of every term).  Once in the basin (corrections
    below 5 %) each step must double the number of correct digits,
    log e_{k+1} / log e_k >= 1.8, until round-off (1e-12).
    """
    strain = 0.3
    l2 = 1.0 - strain
    l1 = uniaxial_lateral_stretch(l2, PRM.lambda_s)
    t = PRM.phi_s0 * network_cauchy(np.diag([l1, l2]), PRM.lambda_s)[1, 1] / l2
    msh, ft = rectangle_mesh(0.0, 0.0, 0.25, 1.0, 2, 4)
    gel = PoroelasticGelSolver(msh, ft, PRM, symmetry=[(LEFT, 0), (BOTTOM, 1)], tractions=[(TOP, (0.0, t))],
                               kinematics="finite", newton_reuse="never", newton_rtol=1e-14)
    gel.solve()
    e = np.array(gel.newton.history)
    print(f"Newton corrections, 30 % strain: {e}")
    orders = [np.log(b) / np.log(a) for a, b in zip(e[:-1], e[1:]) if a < 0.05 and b > 1e-12]
    print(f"orders log e_(k+1) / log e_k: {np.round(orders, 2)}")
    assert e[-1] < 1e-13 and len(orders) >= 2, e
    assert min(orders) >= 1.8, orders


# --------------------------------------------------------------------------
# manufactured solution at finite strain, sources from the strong form (sympy)
# --------------------------------------------------------------------------
def _manufactured(prm: GelParameters, amp=(0.05, 0.1, 0.1)):
    """Exact (v_f, u, p) and the loads that make them a steady solution, derived with sympy.

    The strong form in the current configuration (model.md section 2, v_s = 0):
        r_m = div_x(phi_f sigma_f + phi_s sigma_s - p I),
        r_f = div_x(phi_f sigma_f) - phi_f grad_x p - xi Ca phi_f phi_s v_f,
        r_q = div_x(phi_f v_f),
    with grad_x a = (da/dX) F^-1 and the loads per unit REFERENCE volume
    f_z = -J r_m, f_w = -J r_f, f_q = -J r_q (dv = J dX).  On the face x = 1
    (a fluid interface) the fields are chosen so that it stays the straight
    line x = 1 with u_y, v_f,y and the shear stresses of both phases zero,
    stretched along itself (j = 1 + du_y/dy != 1); there the data are the
    nominal traction J sigma F^-T e_x and the fluid velocity V of I15.
    """
    X, Y = sp.symbols("X Y", real=True)
    av, au, ap = amp
    v = sp.Matrix([av * sp.sin(sp.pi * Y) * sp.cos(X), av * sp.exp(X) * Y * (1 - X)])
    u = sp.Matrix([au * sp.sin(sp.Rational(3, 2) * X + Y * (1 - X) ** 2 / 2),
                   sp.Rational(4, 5) * au * (X * (X - 1) ** 2 * sp.cos(X - Y) + sp.sin(Y) / 2)])
    p = ap * (sp.cos(sp.pi * X) * sp.sin(sp.pi * Y) + X)
    Xs = (X, Y)
    Ca, xi, phi_s0, lam = (sp.nsimplify(x) for x in (prm.Ca, prm.xi, prm.phi_s0, prm.lambda_s))
    grad_X = lambda a: a.jacobian(Xs)                                     # noqa: E731
    F = sp.eye(2) + grad_X(u)
    J = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    Finv = sp.Matrix([[F[1, 1], -F[0, 1]], [-F[1, 0], F[0, 0]]]) / J
    phi_s = phi_s0 / J
    phi_f = 1 - phi_s
    grad_x = lambda a: grad_X(a) * Finv                                   # noqa: E731

    def div_x_tensor(S):
        return sp.Matrix([sum(sp.diff(S[i, j], Xs[k]) * Finv[k, j] for j in range(2) for k in range(2))
                          for i in range(2)])

    def div_x_vector(a):
        return sum(sp.diff(a[i], Xs[k]) * Finv[k, i] for i in range(2) for k in range(2))

    Lv = grad_x(v)
    sigma_f = Ca * (Lv + Lv.T)
    sigma_s = (F * F.T - sp.eye(2)) / J + lam * (J - 1) * sp.eye(2)
    sigma = phi_f * sigma_f + phi_s * sigma_s - p * sp.eye(2)
    r_m = div_x_tensor(sigma)
    r_f = div_x_tensor(phi_f * sigma_f) - phi_f * grad_x(sp.Matrix([p])).T - xi * Ca * phi_f * phi_s * v
    r_q = div_x_vector(phi_f * v)
    loads = {"f_w": -J * r_f, "f_z": -J * r_m, "f_q": sp.Matrix([-J * r_q])}
    # the face x = 1 (N = e_x): nominal traction and the normal velocity of I15 with n = e_x there
    T0 = J * sigma * Finv.T * sp.Matrix([1, 0])
    V_x = v[0] + phi_f * sp.nsimplify(prm.eta) * (sigma_f[0, 0] - sigma_s[0, 0]) / Ca
    exprs = {"v": v, "u": u, "p": sp.Matrix([p]), "T0": T0, "V": sp.Matrix([V_x, 0]), **loads}
    checks = {"u_y,x": sp.diff(u[1], X), "u_x,y": sp.diff(u[0], Y), "v_y": v[1]}
    for name, e in checks.items():      # the face x = 1 stays straight and shear-free, as claimed
        assert abs(float(e.subs({X: 1, Y: 0.37}))) < 1e-14, name
    return {k: sp.lambdify((X, Y), list(e), "numpy", cse=True) for k, e in exprs.items()}


def _interpolated(f, V):
    """Interpolate a lambdified sympy vector function into V (components broadcast to the points)."""
    g = fem.Function(V)
    bs = V.dofmap.index_map_bs

    def values(x):
        out = f(x[0], x[1])
        return np.vstack([np.broadcast_to(np.asarray(a, dtype=float), x.shape[1]) for a in out])[:bs]
    g.interpolate(values)
    g.x.scatter_forward()
    return g


def _mms_errors(prm, fns, N):
    """Relative L2 errors of (v_f, u, p) on the unit square with N x N cell pairs.

    Dirichlet v_f and u on x = 0, y = 0, y = 1; x = 1 is a fluid interface fed with the exact
    nominal traction and V.  The loads are interpolated in P4 (their error, O(h^5), is far below
    the discretisation error)."""
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 1.0, N, N)
    V4 = fem.VectorFunctionSpace(msh, ("Lagrange", 4))
    Q4 = fem.FunctionSpace(msh, ("Lagrange", 4))
    f_w, f_z, f_q = _interpolated(fns["f_w"], V4), _interpolated(fns["f_z"], V4), _interpolated(fns["f_q"], Q4)

    def field(name):
        return lambda x: np.vstack([np.broadcast_to(np.asarray(a, float), x.shape[1]) for a in fns[name](x[0], x[1])])
    walls = (LEFT, BOTTOM, TOP)
    gel = PoroelasticGelSolver(msh, ft, prm, fluid_interfaces={"right": RIGHT}, kinematics="finite",
                               dirichlet=[(walls, "v_f", field("v")), (walls, "u", field("u"))],
                               body_forces=(f_w, f_z, f_q))
    V2 = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
    nodes = InterfaceNodes(V2, ft, RIGHT)
    gel.set_interface_data("right", traction=nodes.from_function(_interpolated(fns["T0"], V2)),
                           velocity=nodes.from_function(_interpolated(fns["V"], V2)))
    gel.solve()
    V8 = fem.VectorFunctionSpace(msh, ("Lagrange", 5))
    Q8 = fem.FunctionSpace(msh, ("Lagrange", 5))
    exact = [_interpolated(fns["v"], V8), _interpolated(fns["u"], V8), _interpolated(fns["p"], Q8)]
    computed = [gel.interstitial_velocity(), gel.displacement(), gel.pore_pressure()]
    return [norm_l2(c - e, msh) / norm_l2(e, msh) for c, e in zip(computed, exact)], gel.newton.history


MMS_N = (4, 8, 16)


@pytest.fixture(scope="module")
def mms_finite():
    prm = GelParameters(phi_s0=0.3, xi=5.0, lambda_s=1.5, beta=0.7, eta=0.4, Ca=0.5)
    fns = _manufactured(prm)
    return np.array([_mms_errors(prm, fns, N)[0] for N in MMS_N])


def test_mms_finite_strain_rates(mms_finite):
    """Rates of the total Lagrangian gel at 10-15 % strain (displacement gradients up to 0.19).

    Expected O(h^2) for all three fields (docs/finite-strain.md, as for the
    small-strain forms at finite strain in docs/gel.md): the mass balance and
    the fluid phase's pressure term contain grad(phi_f w) with
    phi_f = 1 - phi_s0/J(grad u), i.e. second derivatives of the displacement,
    which the P2 u_h has to O(h) only; at tiny strain (test_gel.py) the same
    elements give 3, 3, 2.  Measured on N = 4, 8, 16, 32: 2.88/2.38/2.16
    (v_f), 2.40/2.12/2.04 (u), 2.11/2.03/2.01 (p).
    """
    h = 1.0 / np.array(MMS_N)
    r = [rates(h, mms_finite[:, i]) for i in range(3)]
    msg = f"rates v_f, u, p = {np.round(r, 2)}; errors {mms_finite.tolist()}"
    print("mms finite strain (total Lagrangian):", msg)
    assert min(r) >= 1.8, msg
    assert mms_finite[-1].max() < 5e-3, msg
