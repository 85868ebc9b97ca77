"""Verification of the steady poroelastic gel solver (gel.PoroelasticGelSolver).

Closed forms are recomputed from OUR equations (gel/forms.py): with uniform
phi and v_s = 0 the fluid-phase equation divided by phi_f reads
Ca lap v_f - grad p - xi Ca phi_s v_f = 0, so mu_e = Ca, zeta = xi Ca phi_s,
delta = 1/sqrt(xi phi_s) and the Darcy mobility is kappa = phi_f/(xi Ca phi_s);
the network carries the partial stress phi_s sigma_s, so its drained
oedometric modulus is phi_s (2 + lambda_s) (in units of mu_s).

Unless a test says otherwise the solver runs in the viscous units
s = d = Ca (GelParameters.viscous_units): a stress value x of the solver is
x*Ca in units of mu_s, a displacement value x is x*Ca in units of L0.
"""

from __future__ import annotations

import numpy as np
import pytest

from mpi4py import MPI

import ufl
from dolfinx import fem

from femtools.functions import integrate, interpolate, quadrature_measure
from femtools.interface import InterfaceNodes
from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, rectangle_mesh
from gel import forms
from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver
from gel_cases import line_weights
from mpi_run import run_mpi

COMM = MPI.COMM_WORLD


def rates(h, err):
    """Least-squares slope of log(err) over log(h)."""
    return float(np.polyfit(np.log(h), np.log(err), 1)[0])


def l2(expr, msh, degree=8):
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": degree})
    return np.sqrt(integrate(ufl.inner(expr, expr), dx))


# --------------------------------------------------------------------------
# 1. Brinkman channel (verification.md 2a): cosh profile with the delta layer
# --------------------------------------------------------------------------
def test_brinkman_channel_profile_and_rate():
    """Pressure-driven flow between no-slip walls y = +-h.

    Exact: v_x = (G/zeta) [1 - cosh(y/delta)/cosh(h/delta)], G = p_in/L_x,
    zeta = xi (Ca/s) phi_s, delta = 1/sqrt(xi phi_s) (= 0.2 here, h = 1).
    Inlet/outlet are fluid interfaces with T = -p n and v_f,y = 0 (parallel
    flow); eta -> infinity removes the interfacial pressure jump.  Superficial
    flux Q = phi_f (G/zeta)(2h - 2 delta tanh(h/delta)).
    """
    prm = GelParameters.viscous_units(phi_s0=0.01, xi=2500.0, eta=1e30)
    h, Lx, p_in = 1.0, 0.4, 1.0
    delta, phi_s = prm.brinkman_length, prm.phi_s0
    zeta = prm.xi * prm.viscosity * phi_s
    G = p_in / Lx
    Q = (1 - phi_s) * G / zeta * (2 * h - 2 * delta * np.tanh(h / delta))
    sizes, errors, flux_errors = [], [], []
    for ny in (20, 40, 80):                      # mesh size delta/2, delta/4, delta/8
        msh, ft = rectangle_mesh(0.0, -h, Lx, h, 2, ny)
        gel = PoroelasticGelSolver(msh, ft, prm, no_slip=(BOTTOM, TOP),
                                   fluid_interfaces={"in": LEFT, "out": RIGHT},
                                   dirichlet=[((LEFT, RIGHT), "v_f", 0.0, 1)])
        n_in = gel.interface_points("in").shape[0]
        gel.set_interface_data("in", traction=np.tile([p_in, 0.0], (n_in, 1)))   # T = -p_in n, n = -e_x
        gel.solve()
        x = ufl.SpatialCoordinate(msh)
        exact = ufl.as_vector((G / zeta * (1 - ufl.cosh(x[1] / delta) / np.cosh(h / delta)), 0.0))
        errors.append(l2(gel.interstitial_velocity() - exact, msh) / l2(exact, msh))
        out = gel.interface_data("out")
        flux = line_weights(gel.interface_points("out"), 1) @ out["superficial_velocity"][:, 0]
        flux_errors.append(abs(flux - Q) / Q)
        sizes.append(2 * h / ny)
    r = rates(sizes, errors)
    print(f"brinkman: L2 errors {errors}, rate {r:.2f}, flux errors {flux_errors}")
    assert errors[-1] < 1e-3 and errors[0] < 1e-3, f"relative L2 errors {errors}"
    assert r > 2.7, f"v_f L2 rate {r:.2f} (errors {errors})"
    assert max(flux_errors) < 1e-3, f"superficial flux errors {flux_errors}"


# --------------------------------------------------------------------------
# 2. Darcy layer (verification.md 2b) with the interfacial resistance of I15
# --------------------------------------------------------------------------
@pytest.mark.parametrize("eta", [0.02, 1e30])
def test_darcy_layer_flux_and_pressure_drop(eta):
    """Uniform flow through a layer 0 < x < L between symmetry planes.

    With the fluid at rest on both sides (V = 0) I15 gives a pressure jump
    phi_f Delta p = (Ca phi_s / eta) v at each face, so (s-units, nu = Ca/s)
        v = p_in / (xi nu phi_s L + 2 r),  r = nu phi_s / (eta phi_f),
        p(0) = p_in - r v,  p(L) = r v,  q = phi_f v,
    and for eta -> inf the plain Darcy law q = kappa p_in / L.
    The network rests on a permeable support at x = L (u = 0 there).
    What is exact: v_f constant, p linear and u quadratic lie in the FE
    space, so the discrete solution is the exact one up to round-off and the
    nonlinearity of phi_s(J), of relative size strain = Ca p/(phi_s0 M) ~ 3e-11
    at Ca = 1e-12: tolerance 1e-8.
    """
    prm = GelParameters.viscous_units(eta=eta, Ca=1e-12)            # baseline phi_s0, xi
    L, p_in = 1.0, 1.0
    msh, ft = rectangle_mesh(0.0, 0.0, L, 0.25, 4, 1)
    gel = PoroelasticGelSolver(msh, ft, prm, symmetry=[((BOTTOM, TOP), 1)],
                               fluid_interfaces={"in": LEFT, "out": RIGHT}, dirichlet=[(RIGHT, "u", 0.0)])
    n_in = gel.interface_points("in").shape[0]
    gel.set_interface_data("in", traction=np.tile([p_in, 0.0], (n_in, 1)), velocity=np.zeros((n_in, 2)))
    gel.solve()
    nu, phi_s = prm.viscosity, prm.phi_s0
    phi_f = 1 - phi_s
    r = nu * phi_s / (eta * phi_f)
    v = p_in / (prm.xi * nu * phi_s * L + 2 * r)
    if eta > 1e20:
        np.testing.assert_allclose(phi_f * v, prm.darcy_mobility * prm.stress_scale * p_in / L, rtol=1e-12)
    d_in, d_out = gel.interface_data("in"), gel.interface_data("out")
    print(f"darcy eta={eta}: flux error {abs(d_out['superficial_velocity'][:, 0] / (phi_f * v) - 1).max():.1e}, "
          f"p(0) error {abs(d_in['pressure'][:, 0] / (p_in - r * v) - 1).max():.1e}")
    for d in (d_in, d_out):
        np.testing.assert_allclose(d["superficial_velocity"][:, 0], phi_f * v, rtol=1e-8)
        np.testing.assert_allclose(d["interstitial_velocity"][:, 0], v, rtol=1e-8)
        assert np.abs(d["interstitial_velocity"][:, 1]).max() < 1e-8 * v
    np.testing.assert_allclose(d_in["pressure"][:, 0], p_in - r * v, rtol=1e-8)
    np.testing.assert_allclose(d_out["pressure"][:, 0], r * v, rtol=1e-8, atol=1e-8 * p_in)
    np.testing.assert_array_equal(d_in["traction"], np.tile([p_in, 0.0], (n_in, 1)))


# --------------------------------------------------------------------------
# 3 + 5 (normal). Flow-induced compression of a column (verification.md 6 intro, 6a)
# --------------------------------------------------------------------------
def _column(prm, L=1.0, width=0.1, ny=8):
    msh, ft = rectangle_mesh(0.0, -L, width, 0.0, 2, ny)
    gel = PoroelasticGelSolver(msh, ft, prm, symmetry=[((LEFT, RIGHT), 0)],
                               fluid_interfaces={"top": TOP}, dirichlet=[(BOTTOM, "u", 0.0)])
    return msh, ft, gel


def test_column_permeation_interface_split_and_compression():
    """Gel -L < z < 0 on a rigid permeable support (u = 0, p = 0 at z = -L).

    The fluid above pushes a superficial flux q downward: V = (0, -q) (I13)
    and T = -P n.  Our equations give (s-units, nu = Ca/s, M = 2 + lambda_s):
        v_f = -q/phi_f,  dp/dz = g = xi nu phi_s q / phi_f,  p(0) = g L,
        Delta p_i = P - p(0) = nu q phi_s^2 / (eta phi_f^2)            (I15)
        sigma_s,zz(0) = -Ca q phi_s / (eta phi_f^2)  [units of mu_s]   (I14 + I15)
        phi_s M (d/s) u_z' = p - P  =>  u_z(0) = -(L/(phi_s M (d/s))) (g L/2 + Delta p_i)
    The parameters make Delta p_i 11 % of the drop across the gel.  u_z is
    quadratic and p linear: exact in the FE space up to the O(strain) ~ 2e-11
    nonlinearity at Ca = 1e-12 (tolerance 1e-8).
    """
    prm = GelParameters.viscous_units(phi_s0=0.1, xi=50.0, eta=0.02, lambda_s=1.5, Ca=1e-12)
    L, width, q = 1.0, 0.1, 1.0
    msh, ft, gel = _column(prm, L, width)
    nu, phi_s = prm.viscosity, prm.phi_s0
    phi_f = 1 - phi_s
    g = prm.xi * nu * phi_s * q / phi_f
    dp_i = nu * q * phi_s**2 / (prm.eta * phi_f**2)
    P = g * L + dp_i
    n = gel.interface_points("top").shape[0]
    gel.set_interface_data("top", traction=np.tile([0.0, -P], (n, 1)), velocity=np.tile([0.0, -q], (n, 1)))
    gel.solve()
    out = gel.interface_data("top")
    np.testing.assert_allclose(out["superficial_velocity"], np.tile([0.0, -q], (n, 1)), rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(out["interstitial_velocity"][:, 1], -q / phi_f, rtol=1e-8)
    np.testing.assert_allclose(P - out["pressure"][:, 0], dp_i, rtol=1e-8)     # interfacial jump
    ds = quadrature_measure("ds", msh, ft)
    sigma_zz = integrate(gel.network_stress()[1, 1], ds(TOP)) / width          # units of mu_s
    expected = -prm.Ca * q * phi_s / (prm.eta * phi_f**2)
    assert abs(sigma_zz - expected) < 1e-8 * abs(expected), (sigma_zz, expected)
    u_top = integrate(gel.displacement()[1], ds(TOP)) / width * prm.displacement_scale   # units of L0
    u_ref = -(L / (phi_s * (2 + prm.lambda_s) * prm.stiffness)) * (g * L / 2 + dp_i) * prm.displacement_scale
    print(f"column: dp_i error {abs((P - out['pressure'][:, 0]) / dp_i - 1).max():.1e}, sigma_zz(0) error "
          f"{abs(sigma_zz / expected - 1):.1e}, u_z(0) error {abs(u_top / u_ref - 1):.1e}")
    assert abs(u_top - u_ref) < 1e-8 * abs(u_ref), (u_top, u_ref)


def test_column_uniaxial_neo_hookean_law_through_cell_force():
    """The network's stress law and phi_s = phi_s0/J at 10 % uniaxial strain (s = d = 1), via the Gamma2 force path.

    What it checks: the top of the column is a cell interface (v_f = 0)
    loaded by the consistent nodal forces of a uniform pressure P; the
    support is open (p = 0).  No flow, so p = 0 and the mixture balance is
    phi_s sigma_zz(J) = -P with phi_s = phi_s0/J and, for F = diag(1, J),
    sigma_zz = (J^2 - 1)/J + lambda_s (J - 1).  Choosing J = 0.9 fixes P;
    the displacement is linear, u_z(0) = (J - 1) L: exact in the FE space.
    It also checks that Newton converges at this strain and that the
    answer differs from the linear one.

    What it cannot see: with F = diag(1, J) the first Piola stress J sigma F^-T
    has the same zz component as the Cauchy stress sigma, and the loaded
    face keeps its length, so this test passes whether or not the gel is in
    total Lagrangian form.  The gel today uses the Cauchy stress as if it
    were the first Piola stress (docs/gel.md); the next test sees that.
    """
    prm = GelParameters(phi_s0=0.1, lambda_s=1.5, Ca=1.0)
    L, width, J = 1.0, 0.1, 0.9
    P = -prm.phi_s0 / J * ((J**2 - 1) / J + prm.lambda_s * (J - 1))
    msh, ft = rectangle_mesh(0.0, -L, width, 0.0, 2, 4)
    gel = PoroelasticGelSolver(msh, ft, prm, symmetry=[((LEFT, RIGHT), 0)],
                               cell_interfaces={"cell": TOP}, dirichlet=[(BOTTOM, "u", 0.0)])
    w = line_weights(gel.interface_points("cell"), 0)
    gel.set_interface_data("cell", force=np.column_stack([0 * w, -P * w]))
    gel.solve()
    u = gel.interface_data("cell")["displacement"]
    print(f"neo-Hookean column: u_z(0) error {abs(u[:, 1] / ((J - 1) * L) - 1).max():.1e}, "
          f"Newton corrections {gel.newton.history}")
    np.testing.assert_allclose(u[:, 1], (J - 1) * L, rtol=1e-10)
    assert np.abs(u[:, 0]).max() < 1e-12
    # the linear answer would be off by O(strain): make sure this test can tell
    u_linear = -P * L / (prm.phi_s0 * (2 + prm.lambda_s))
    assert abs(u_linear - (J - 1) * L) > 0.05 * abs((J - 1) * L)
    assert gel.newton.stats["newton_iterations"] <= 8, gel.newton.history


def test_column_stretched_sideways_sees_the_first_piola_stress():
    """Biaxial F = diag(lambda_1, lambda_2), where Cauchy and first Piola differ in the loaded component.

    The sides are pulled to lambda_1 = 1.1 (u_x prescribed, shear-free), the
    bottom slides (u_y = 0), and the top (a cell interface, v_f = 0) carries a
    dead load: nodal forces of a nominal traction t per unit REFERENCE length.
    No flow: p = 0.  Total Lagrangian equilibrium of the homogeneous state
    with P = J (phi_s sigma_s) F^-T and phi_s = phi_s0/J:

        P_yy = phi_s0 sigma_yy / lambda_2 = t,
        sigma_yy = (lambda_2^2 - 1)/J + lambda_s (J - 1),   J = lambda_1 lambda_2,

    so t for lambda_2 = 0.9 gives u_y(0) = (lambda_2 - 1) L exactly (linear u,
    in the FE space).  Using sigma as if it were P instead balances
    phi_s sigma_yy = t, i.e. lambda_1 = 1.1 times too small a stress: it
    settles at lambda_2 = 0.8947, 5 % more compression: the small-strain
    path (``kinematics="small"``) fails this test; the total Lagrangian one
    (``kinematics="finite"``, gel.lagrangian) passes it.
    """
    prm = GelParameters(phi_s0=0.1, lambda_s=1.5, Ca=1.0)
    L, width, l1, l2 = 1.0, 0.1, 1.1, 0.9
    J = l1 * l2
    t = prm.phi_s0 * ((l2**2 - 1) / J + prm.lambda_s * (J - 1)) / l2
    msh, ft = rectangle_mesh(0.0, -L, width, 0.0, 2, 4)
    gel = PoroelasticGelSolver(msh, ft, prm, cell_interfaces={"cell": TOP},
                               dirichlet=[(LEFT, "u", 0.0, 0), (RIGHT, "u", (l1 - 1) * width, 0),
                                          (BOTTOM, "u", 0.0, 1)], kinematics="finite")
    w = line_weights(gel.interface_points("cell"), 0)
    gel.set_interface_data("cell", force=np.column_stack([0 * w, t * w]))
    gel.solve()
    X = gel.interface_points("cell")
    u = gel.interface_data("cell")["displacement"]
    print(f"stretched column: u_y(0) = {u[:, 1].mean():.6f}, total Lagrangian {(l2 - 1) * L:.6f}")
    np.testing.assert_allclose(u[:, 0], (l1 - 1) * X[:, 0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(u[:, 1], (l2 - 1) * L, rtol=1e-8)


# --------------------------------------------------------------------------
# 5 (tangential). Shear over a gel layer: I17 and the Brinkman layer
# --------------------------------------------------------------------------
def test_shear_layer_tangential_split():
    """Gel -H < y < 0 bonded at y = -H, sheared by a fluid traction T = (tau, 0).

    x-invariant solution (s-units, nu = Ca/s, stiffness k = d/s):
        v_f,x = W sinh((y + H)/delta)/sinh(H/delta)
        top:   phi_f nu v_f,x'(0) = tau - (nu phi_s^2/beta) W
               => W = tau / (nu phi_f coth(H/delta)/delta + nu phi_s^2/beta)
        network: phi_s k u_x' = tau - phi_f nu v_f,x'  =>  u_x(0) = (tau H - nu phi_f W)/(phi_s k)
    and I17 at the interface: sigma_s n.t = (Ca phi_s/beta) v_f.t.
    beta is chosen so that the slip term is 40 % of the viscous one.
    """
    prm = GelParameters.viscous_units(phi_s0=0.1, xi=90.0, beta=0.005)
    H, width, tau = 0.5, 0.2, 1.0
    msh, ft = rectangle_mesh(0.0, -H, width, 0.0, 2, 40)
    gel = PoroelasticGelSolver(msh, ft, prm, no_slip=BOTTOM, symmetry=[((LEFT, RIGHT), 1)],
                               fluid_interfaces={"top": TOP})
    n = gel.interface_points("top").shape[0]
    gel.set_interface_data("top", traction=np.tile([tau, 0.0], (n, 1)))
    gel.solve()
    nu, phi_s, k = prm.viscosity, prm.phi_s0, prm.stiffness
    phi_f, delta = 1 - phi_s, prm.brinkman_length
    W = tau / (nu * phi_f / (delta * np.tanh(H / delta)) + nu * phi_s**2 / prm.beta)
    U0 = (tau * H - nu * phi_f * W) / (phi_s * k)
    out = gel.interface_data("top")
    np.testing.assert_allclose(out["interstitial_velocity"][:, 0], W, rtol=1e-5)
    ds = quadrature_measure("ds", msh, ft)
    u0 = integrate(gel.displacement()[0], ds(TOP)) / width
    assert abs(u0 - U0) < 1e-5 * abs(U0), (u0, U0)
    # I17 with the network stress recovered from grad u (O(h^2) accurate)
    sigma_nt = integrate(gel.network_stress()[0, 1], ds(TOP)) / width        # units of mu_s
    slip = prm.Ca * phi_s / prm.beta * W
    print(f"shear: W error {abs(out['interstitial_velocity'][:, 0] / W - 1).max():.1e}, u_x(0) error "
          f"{abs(u0 / U0 - 1):.1e}, I17 error {abs(sigma_nt / slip - 1):.1e}")
    assert abs(sigma_nt - slip) < 2e-3 * abs(slip), (sigma_nt, slip)
    assert nu * phi_s**2 / prm.beta > 0.3 * nu * phi_f / delta          # the slip term matters


# --------------------------------------------------------------------------
# 4. Manufactured solution of the coupled steady system
# --------------------------------------------------------------------------
def _exact(x, m, amp):
    """(v_f, u, p) of the manufactured solution; ``m`` is ufl or numpy."""
    av, au, ap = amp
    v = (av * m.sin(np.pi * x[1]) * m.cos(x[0]), av * m.exp(x[0]) * x[1])
    u = (au * m.sin(1.5 * x[0] + 0.5 * x[1]), 0.8 * au * x[0] * m.cos(x[0] - x[1]))
    p = ap * (m.cos(np.pi * x[0]) * m.sin(np.pi * x[1]) + x[0])
    return v, u, p


def _mms_errors(prm, amp, N):
    """Relative L2 errors of (v_f, u, p) on the unit square with N x N cell pairs.

    Dirichlet v_f, u on x = 0, y = 0, y = 1; x = 1 is a fluid interface fed
    with the exact total traction T and a velocity V satisfying the exact
    normal condition (V - v_f).n = phi_f eta (sigma_f,nn - sigma_s,nn)/nu
    (I15), plus Dirichlet v_f,y (tangential): the fluid interface's normal
    split fixes the pressure level.  Body forces = strong residuals.
    """
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 1.0, N, N)
    x = ufl.SpatialCoordinate(msh)
    v, u, p = _exact(x, ufl, amp)
    v, u = ufl.as_vector(v), ufl.as_vector(u)
    names = ("phi_s0", "xi", "lambda_s", "beta", "eta", "viscosity", "stiffness", "d")
    values = (prm.phi_s0, prm.xi, prm.lambda_s, prm.beta, prm.eta, prm.viscosity, prm.stiffness,
              prm.displacement_scale)
    c = forms.GelCoefficients(**{k: fem.Constant(msh, float(val)) for k, val in zip(names, values)})
    phi_s = forms.solid_fraction(u, c)
    phi_f = 1 - phi_s
    sf, total = forms.fluid_stress(v, c), forms.total_stress(v, u, p, c)
    f_w = -ufl.div(phi_f * sf) + phi_f * ufl.grad(p) + c.viscosity * c.xi * phi_f * phi_s * v
    f_z = -ufl.div(total)
    f_q = -ufl.div(phi_f * v)

    def field(i):
        if i == 2:
            return lambda X: _exact(X, np, amp)[2]
        return lambda X: np.vstack([np.broadcast_to(a, X.shape[1]) for a in _exact(X, np, amp)[i]])

    walls = (LEFT, BOTTOM, TOP)
    gel = PoroelasticGelSolver(msh, ft, prm, fluid_interfaces={"right": RIGHT},
                               dirichlet=[(walls, "v_f", field(0)), (walls, "u", field(1)),
                                          (RIGHT, "v_f", lambda X: _exact(X, np, amp)[0][1], 1)],
                               body_forces=(f_w, f_z, f_q))
    nvec = ufl.as_vector((1.0, 0.0))

    def snn(s):
        return ufl.dot(ufl.dot(s, nvec), nvec)

    V_n = v[0] + phi_f * c.eta * (snn(sf) - snn(forms.network_stress(u, c))) / c.viscosity
    V2 = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
    nodes = InterfaceNodes(V2, ft, RIGHT)
    gel.set_interface_data("right", traction=nodes.from_function(interpolate(ufl.dot(total, nvec), V2)),
                           velocity=nodes.from_function(interpolate(ufl.as_vector((V_n, v[1])), V2)))
    gel.solve()
    errs = [l2(gel.interstitial_velocity() - v, msh) / l2(v, msh),
            l2(gel.displacement() - u, msh) / l2(u, msh),
            l2(gel.pore_pressure() - p, msh) / l2(p, msh)]
    return errs, gel.newton.history


_MMS_N = (4, 8, 16)


@pytest.fixture(scope="module")
def mms_linear():
    """Device scaling s = d = Ca (tiny strains: phi_s(J) and the network are effectively linear)."""
    prm = GelParameters.viscous_units(phi_s0=0.3, xi=5.0, lambda_s=1.5, beta=0.7, eta=0.4, Ca=1e-6)
    return np.array([_mms_errors(prm, (0.5, 0.1, 1.0), N)[0] for N in _MMS_N])


@pytest.fixture(scope="module")
def mms_nonlinear():
    """Paper units s = d = 1, 10 % strains, phi_s0 = 0.3: phi_s(J) varies by +-10 %."""
    prm = GelParameters(phi_s0=0.3, xi=5.0, lambda_s=1.5, beta=0.7, eta=0.4, Ca=0.5)
    return np.array([_mms_errors(prm, (0.05, 0.1, 0.1), N)[0] for N in _MMS_N])


def test_mms_rates_device_scaling(mms_linear):
    h = 1.0 / np.array(_MMS_N)
    r = [rates(h, mms_linear[:, i]) for i in range(3)]
    msg = f"rates v_f, u, p = {np.round(r, 2)}; errors {mms_linear.tolist()}"
    print("mms device scaling:", msg)
    assert r[0] >= 2.7 and r[1] >= 2.7 and r[2] >= 1.8, msg


def test_mms_rates_finite_strain(mms_nonlinear):
    """At finite strain the fluid-phase coefficients depend on grad u_h.

    phi_s = phi_s0/J(grad u_h) enters the mass balance div(phi_f v_f), the
    fluid pressure term p div(phi_f w) and the fluid-phase interface
    traction; grad u_h of the P2 displacement is O(h^2) accurate, so v_f and
    u are bounded by O(h^2) here (see docs/gel.md); p stays at its optimal 2.
    """
    h = 1.0 / np.array(_MMS_N)
    r = [rates(h, mms_nonlinear[:, i]) for i in range(3)]
    msg = f"rates v_f, u, p = {np.round(r, 2)}; errors {mms_nonlinear.tolist()}"
    print("mms finite strain:", msg)
    assert min(r) >= 1.8, msg
    assert mms_nonlinear[-1].max() < 5e-3, msg


# --------------------------------------------------------------------------
# 6. Both scaling paths (model.md section 5)
# --------------------------------------------------------------------------
def _scaled_problem(prm, N=8):
    """A 2D chamber: no-slip bottom, symmetry sides, nonuniform fluid traction on top.

    Inputs are given in units of mu_s and converted with s; outputs are
    converted back with s (stresses) and d (displacements).
    """
    msh, ft = rectangle_mesh(0.0, -0.5, 1.0, 0.0, N, N)
    gel = PoroelasticGelSolver(msh, ft, prm, no_slip=BOTTOM, symmetry=[((LEFT, RIGHT), 0)],
                               fluid_interfaces={"top": TOP})
    X = gel.interface_points("top")
    T_paper = prm.Ca * np.column_stack([0.5 * np.sin(np.pi * X[:, 0]), -(1 + 0.3 * np.cos(np.pi * X[:, 0]))])
    V = np.column_stack([0.2 + 0 * X[:, 0], -0.01 * X[:, 0]])
    gel.set_interface_data("top", traction=T_paper / prm.stress_scale, velocity=V)
    gel.solve()
    s, d = prm.stress_scale, prm.displacement_scale
    out = gel.interface_data("top")
    return {"v_f": gel.interstitial_velocity().x.array, "u": d * gel.displacement().x.array,
            "p": s * gel.pore_pressure().x.array, "flux": out["superficial_velocity"],
            "p_top": s * out["pressure"],
            "stress": integrate(gel.network_von_mises(), quadrature_measure("dx", msh))}


def test_scaling_paths_agree():
    """Ca = 3e-10: paper units (s = d = 1, relative criteria only) vs s = d = Ca."""
    a = _scaled_problem(GelParameters(Ca=3e-10))
    b = _scaled_problem(GelParameters.viscous_units(Ca=3e-10))
    for key in a:
        err = np.linalg.norm(np.ravel(a[key]) - np.ravel(b[key])) / np.linalg.norm(np.ravel(b[key]))
        print(f"scaling paths: {key} relative difference {err:.1e}")
        assert err < 1e-8, f"{key}: relative difference {err:.2e}"
    assert 1e-10 < np.abs(b["u"]).max() < 1e-7 and 1e-11 < np.abs(b["p"]).max() < 1e-8   # paper magnitudes


# --------------------------------------------------------------------------
# Gamma2 force path, factorise-once, parallel
# --------------------------------------------------------------------------
def _two_sided(cell_path: bool, t0=(0.3, -0.5)):
    """Top: fluid interface; bottom: either a cell interface with the consistent
    nodal load of a uniform traction t0, or the same t0 as a fluid-interface
    traction with v_f = 0 imposed (which makes the fluid-phase terms vanish)."""
    prm = GelParameters.viscous_units()
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 0.5, 6, 3)
    kw = dict(no_slip=LEFT, symmetry=[(RIGHT, 0)])
    if cell_path:
        gel = PoroelasticGelSolver(msh, ft, prm, fluid_interfaces={"top": TOP},
                                   cell_interfaces={"bottom": BOTTOM}, **kw)
        w = line_weights(gel.interface_points("bottom"), 0)
        gel.set_interface_data("bottom", force=np.outer(w, t0))
    else:
        gel = PoroelasticGelSolver(msh, ft, prm, fluid_interfaces={"top": TOP, "bottom": BOTTOM},
                                   dirichlet=[(BOTTOM, "v_f", 0.0)], **kw)
        nb = gel.interface_points("bottom").shape[0]
        gel.set_interface_data("bottom", traction=np.tile(t0, (nb, 1)))
    X = gel.interface_points("top")
    gel.set_interface_data("top", traction=np.column_stack([0.1 * X[:, 0], -1.0 + 0 * X[:, 0]]),
                           velocity=np.zeros_like(X))
    gel.solve()
    return gel


def test_cell_force_equals_consistent_traction_load():
    a, b = _two_sided(True), _two_sided(False)
    ua = a.interface_data("bottom")["displacement"]
    ub = b.displacement()
    nodes = InterfaceNodes(ub.function_space, b.facet_tags, BOTTOM)
    np.testing.assert_allclose(ua, nodes.from_function(ub), rtol=1e-9, atol=1e-9 * np.abs(ua).max())
    np.testing.assert_allclose(a.interface_data("top")["pressure"], b.interface_data("top")["pressure"], rtol=1e-9)
    assert np.abs(ua).max() > 1.0             # the load does move the interface (viscous units)


def test_factorisation_reused_across_coupling_iterations():
    """Device parameters: new interface data must not trigger a refactorisation,
    and the result must equal a fresh solve."""
    prm = GelParameters.viscous_units()
    msh, ft = rectangle_mesh(0.0, -0.5, 1.0, 0.0, 8, 4)
    def make():
        return PoroelasticGelSolver(msh, ft, prm, no_slip=BOTTOM, symmetry=[((LEFT, RIGHT), 0)],
                                    fluid_interfaces={"top": TOP})
    gel = make()
    X = gel.interface_points("top")
    for k in range(4):
        T = np.column_stack([(0.2 + 0.1 * k) * np.sin(np.pi * X[:, 0]), -(1.0 + 0.2 * k) + 0 * X[:, 0]])
        gel.set_interface_data("top", traction=T, velocity=np.column_stack([0.1 * k + 0 * X[:, 0], 0 * X[:, 0]]))
        gel.solve()
    assert gel.newton.stats["factorizations"] == 1, gel.newton.stats
    fresh = make()
    fresh.set_interface_data("top", traction=T, velocity=np.column_stack([0.3 + 0 * X[:, 0], 0 * X[:, 0]]))
    fresh.solve()
    for f in ("v_f", "u", "p"):
        i = ("v_f", "u", "p").index(f)
        a, b = gel.state.sub(i).collapse().x.array, fresh.state.sub(i).collapse().x.array
        assert np.linalg.norm(a - b) <= 1e-9 * np.linalg.norm(b), f


@pytest.mark.mpi
def test_same_answer_on_one_and_two_ranks():
    """Viscous units on 1 rank vs 2 ranks, and the paper's units on 2 ranks vs both."""
    one = run_mpi("gel_mpi.py", 1, ["12", "viscous"])
    two = run_mpi("gel_mpi.py", 2, ["12", "viscous"])
    paper = run_mpi("gel_mpi.py", 2, ["12", "paper"])
    for key in ("flux", "interstitial", "pressure", "displacement"):
        a, b = np.array(one[key]), np.array(paper[key])
        err = np.abs(a - b).max() / np.abs(a).max()
        print(f"mpi: {key} paper units (2 ranks) vs viscous (1 rank) {err:.1e}")
        assert err < 1e-8, f"{key}: paper units on 2 ranks vs viscous units on 1 rank differ by {err:.2e}"
        a, b = np.array(one[key]), np.array(two[key])
        err = np.abs(a - b).max() / np.abs(a).max()
        print(f"mpi: {key} 1 vs 2 ranks {err:.1e}")
        assert err < 1e-9, f"{key}: 1 vs 2 ranks differ by {err:.2e}"
    for key in ("norm_v_f", "norm_u", "norm_p"):
        assert abs(one[key] - two[key]) <= 1e-9 * abs(one[key]), key
    assert two["factorizations"] == 1 and one["factorizations"] == 1


# --------------------------------------------------------------------------
# Argument validation
# --------------------------------------------------------------------------
@pytest.mark.parametrize("name,value", [("phi_s0", 0.0), ("phi_s0", 1.0), ("xi", -1.0), ("lambda_s", -0.7),
                                        ("beta", 0.0), ("eta", -1.0), ("Ca", 0.0), ("stress_scale", 0.0),
                                        ("displacement_scale", float("nan")), ("xi", float("inf"))])
def test_parameter_validation(name, value):
    with pytest.raises(ValueError, match=name):
        GelParameters(**{name: value})


def test_solver_argument_validation():
    msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 1.0, 2, 2)
    prm = GelParameters.viscous_units()
    with pytest.raises(ValueError, match="no_slip"):
        PoroelasticGelSolver(msh, ft, prm, no_slip=99)
    with pytest.raises(ValueError, match="field"):
        PoroelasticGelSolver(msh, ft, prm, dirichlet=[(LEFT, "pressure", 0.0)])
    with pytest.raises(RuntimeError, match="transient"):
        PoroelasticGelSolver(msh, ft, prm, no_slip=BOTTOM).set_time_step(0.1)
    gel = PoroelasticGelSolver(msh, ft, prm, no_slip=BOTTOM, fluid_interfaces={"top": TOP})
    with pytest.raises(ValueError, match="shape"):
        gel.set_interface_data("top", traction=np.zeros((3, 2)))
    with pytest.raises(KeyError, match="force"):
        gel.set_interface_data("top", force=np.zeros((gel.interface_points("top").shape[0], 2)))
