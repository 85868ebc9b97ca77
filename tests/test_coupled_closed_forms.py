"""Coupled closed forms through the partitioned device machinery (issue 12, item 5).

The channel-over-gel-layer device (``gelcell/layer.py``) runs the real
StokesSolver and PoroelasticGelSolver through gelcell.coupled.participants'
FluidParticipant, GelParticipant, coupling_data and coupling_config, coupled
by coupling.build_scheme.  Its fully developed solutions are compared with
closed forms derived from model.md's own equations and interface
conditions I13-I17 (docs/verification-coupled.md), not with anything that
shares the code's weak forms:

* the closed forms solve model.md's strong equations and I13-I17 (checked
  with sympy) and reduce to verification.md's references in its limits;
* Poiseuille over a Brinkman layer (3b) and Couette shear with network
  displacement (6b), at resolvable parameters and the Poiseuille case at
  Table 1's phi_s0, xi, beta, eta: every field, interface quantity and flow
  rate converges at its element's order, on h = delta/2, delta/4, delta/8;
* flow-induced compression (6a): the exact solution lies in the FE spaces,
  so the coupled solution matches it to the size of what the linear closed
  form neglects, the strain (and to round-off as Ca -> 0).

``python -m pytest -s tests/test_coupled_closed_forms.py`` prints every error and rate;
``examples/layer_convergence.py`` prints the tables of docs/verification-coupled.md.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import sympy as sp

from gelcell.coupled.layer import FLOWS, LayerCase, LayerClosedForm, LayerDevice

MESHES = (8, 16, 32)          # cells across the gel: h = delta/2, delta/4, delta/8 (H_g = 4 delta)

RATE_CASES = {"poiseuille": LayerCase("poiseuille"), "couette": LayerCase("couette"),
              "poiseuille-table1": LayerCase.table1("poiseuille")}

# expected order of each error: L2 errors of P2 fields and nodal P2 values 3, P1 pressures 2,
# tractions 2 (the consistent traction carries the P1 pressure and the flux recovery);
# the slip V - v_f equals beta times the traction (I16), so it is a traction-rate quantity
ORDERS = {"V": 3, "v_f": 3, "u": 3, "P": 2, "p": 2, "Gamma1/velocity": 3, "Gamma1/superficial_velocity": 3,
          "Gamma1/flux": 3, "Gamma1/displacement": 3, "Gamma1/slip": 2, "Gamma1/traction": 2,
          "Q_f": 3, "Q_p": 3}
MARGIN = {3: 0.3, 2: 0.2}     # as the field solvers' rate tests (test_gel, test_fluid)


def fitted_rate(h, err) -> float:
    """Least-squares slope of log(err) over log(h)."""
    return float(np.polyfit(np.log(h), np.log(err), 1)[0])


# ----------------------------------------------------------------------------------------------
# 1. The closed forms solve model.md's equations and reduce to verification.md's references
# ----------------------------------------------------------------------------------------------
def _grad(v, X):
    return sp.Matrix(2, 2, lambda i, j: sp.diff(v[i], X[j]))


def _div(T, X):
    return sp.Matrix([sum(sp.diff(T[i, j], X[j]) for j in range(2)) for i in range(2)])


def _model_equations(cf: LayerClosedForm) -> dict[str, tuple]:
    """model.md sections 2-3 for the closed form, as {name: (terms, points[, scale])}.

    The terms of each equation must sum to zero at its points; ``scale``
    (default: the largest term) is the size a residual is compared with,
    given for the support conditions, whose single term is zero.

    Steady (v_s = 0), linear (phi = phi_s0, sigma_s = grad u + grad u^T +
    lambda_s div u I), in viscous units (Ca -> 1 in I15-I17, stresses in
    mu V0/L0, u in Ca L0).  The body force G of the device is written back as
    the pressure gradient it stands for: P -> P - G x and p -> p - G x.
    """
    c = cf.case
    x, y = sp.symbols("x y", real=True)
    X = (x, y)
    phi_s, xi, lam = c.phi_s0, c.xi, c.lambda_s
    phi_f = 1 - phi_s
    I = sp.eye(2)
    Vx, Vy, P = cf.fluid(y)
    w, v, ux, uy, p = cf.gel(y, sp)
    V, vf, u = sp.Matrix([Vx, Vy]), sp.Matrix([w, v]), sp.Matrix([ux, uy])
    P, p = P - cf.G * x, p - cf.G * x
    Sigma = _grad(V, X) + _grad(V, X).T
    sigma_f = _grad(vf, X) + _grad(vf, X).T
    sigma_s = _grad(u, X) + _grad(u, X).T + lam * _grad(u, X).trace() * I

    def grad(f):
        return sp.Matrix([sp.diff(f, x), sp.diff(f, y)])
    n, t = sp.Matrix([0, 1]), sp.Matrix([1, 0])
    fluid_pts = [{x: 0.3 * k, y: s * c.H_f} for k in (0, 1) for s in (0.1, 0.5, 0.9)]
    gel_pts = [{x: 0.3 * k, y: -s * c.H_g} for k in (0, 1) for s in (0.1, 0.5, 0.9)]
    iface = [{x: 0.0, y: 0.0}, {x: 0.3, y: 0.0}]
    top, bottom = [{x: 0.3, y: c.H_f}], [{x: 0.3, y: -c.H_g}]
    eq = {
        "Stokes momentum": ([_div(Sigma, X), -grad(P)], fluid_pts),
        "Stokes mass": ([sp.Matrix([sp.diff(Vx, x) + sp.diff(Vy, y)])], fluid_pts),
        "G2": ([sp.Matrix([sp.diff(phi_f * w, x) + sp.diff(phi_f * v, y)])], gel_pts),
        "G3": ([_div(phi_f * sigma_f, X), -phi_f * grad(p), -xi * phi_f * phi_s * vf], gel_pts),
        "G4": ([_div(phi_s * sigma_s, X), -phi_s * grad(p), xi * phi_f * phi_s * vf], gel_pts),
        "I13": ([V.T * n, -phi_f * vf.T * n], iface),
        "I14": ([-p * n, phi_f * sigma_f * n, phi_s * sigma_s * n, P * n, -Sigma * n], iface),
        "I15": ([(V - vf).T * n, -c.eta * n.T * (Sigma - P * I) * n, c.eta * n.T * (sigma_s - p * I) * n], iface),
        "I16": ([(V - vf).T * t, -c.beta * (Sigma * n).T * t], iface),
        "I17": ([-phi_s * vf.T * t, c.beta * (sigma_s * n).T * t], iface),
        "lid": ([V, -sp.Matrix([cf.U_w, -cf.q])], top),
        "support u_s = 0": ([u], bottom, np.abs(cf.gel(0.0)[2:4]).max()),
    }
    if c.flow == "compression":     # open support: phi_f (sigma_f - p I) n = 0
        eq["support, open"] = ([phi_f * (sigma_f - p * I) * n], bottom, cf.stress_scale)
    else:                           # bonded support: v_f = 0
        eq["support v_f = 0"] = ([vf], bottom, np.abs(cf.gel(0.0)[:2]).max())
    return eq


@pytest.mark.parametrize("table1", [False, True], ids=["resolvable", "table1"])
@pytest.mark.parametrize("flow", FLOWS)
def test_closed_form_solves_the_model_equations(flow, table1):
    """Each equation's terms, summed at sample points, cancel to round-off.

    Round-off: 1e-9 of the largest term (the network's shear stress at
    Gamma1 is a difference of two stresses ~100 times larger).  Equations
    whose terms all vanish, like the mass balances of a shear flow, hold
    exactly.  A wrong coefficient or sign gives O(1) residuals.
    """
    case = LayerCase.table1(flow) if table1 else LayerCase(flow)
    for name, (terms, points, *scale) in _model_equations(LayerClosedForm(case)).items():
        for pt in points:
            values = np.array([np.array(term.subs(pt).evalf(), dtype=float).ravel() for term in terms])
            size = max([np.abs(values).max()] + scale)
            residual = np.abs(values.sum(axis=0)).max()
            assert residual <= 1e-9 * size, (flow, name, pt, residual, size)


def _u_i_3b(G, G_p, mu, mu_e, zeta, H_p, H_f, beta_J=0.0):
    """verification.md 3b: the interface slip u_i.

    u_i = [G H_f/2 + (mu_e Q_D/delta) tanh(X/2)] / [mu_e coth X/delta + mu/H_f - beta_J mu/sqrt(k)].
    """
    delta, Q_D, k = math.sqrt(mu_e / zeta), G_p / zeta, mu / zeta
    X = H_p / delta
    return ((G * H_f / 2 + mu_e * Q_D / delta * math.tanh(X / 2))
            / (mu_e / (delta * math.tanh(X)) + mu / H_f - beta_J * mu / math.sqrt(k)))


def _couette_nn_6b(U, mu, mu_e, zeta, G_s, H_g, H_f):
    """verification.md 6b, NN closure: (W = u_i, tau, u_x(0))."""
    delta = math.sqrt(mu_e / zeta)
    W = (mu * U / H_f) / (mu / H_f + mu_e / (delta * math.tanh(H_g / delta)))
    tau = mu * (U - W) / H_f
    return W, tau, (tau * H_g - mu_e * W) / G_s


def test_references_transcribed_from_verification_md():
    """The reference formulas used below reproduce verification.md's own numbers."""
    ref = dict(G=1.0, G_p=1.0, mu=1.0, mu_e=1.0, zeta=1e3, H_p=1.0, H_f=1.0)
    assert _u_i_3b(**ref) == pytest.approx(0.01629606159, rel=1e-9)
    assert _u_i_3b(**ref, beta_J=0.7) == pytest.approx(0.05069431139, rel=1e-9)
    assert _u_i_3b(**dict(ref, mu_e=2.0, zeta=100.0, H_p=0.1)) == pytest.approx(0.0226198004, rel=1e-9)
    W, tau, u0 = _couette_nn_6b(U=1.0, mu=1.0, mu_e=1.0, zeta=100.0, G_s=10.0, H_g=1.0, H_f=1.0)
    assert (W, tau, u0) == pytest.approx((0.0909090906, 0.9090909094, 0.0818181819), rel=1e-8)


@pytest.mark.parametrize("case", [LayerCase("poiseuille"), LayerCase.table1("poiseuille"),
                                  LayerCase("couette"), LayerCase.table1("couette")],
                         ids=["poiseuille", "poiseuille-table1", "couette", "couette-table1"])
def test_tangential_closed_form_limits(case):
    """Neale-Nader closure and beta -> 0.

    verification.md 3b (beta_J = 0) and 6b (NN) continue the velocity across
    the interface and leave the network unloaded there: I16 with no slip
    (beta_fluid = 0) and I17 with a free network (beta_network = inf).  The
    model's mapping: mu = 1, mu_e = phi_f, zeta = xi phi_f phi_s, G_p = phi_f G,
    drained shear modulus G_s = phi_s.  With the model's single beta -> 0 the
    interface becomes a no-slip wall for the channel.
    """
    phi_s = case.phi_s0
    phi_f = 1 - phi_s
    nn = LayerClosedForm(case, beta_fluid=0.0, beta_network=math.inf)
    model = dict(mu=1.0, mu_e=phi_f, zeta=case.xi * phi_f * phi_s)
    if case.flow == "poiseuille":
        u_i = _u_i_3b(G=nn.G, G_p=phi_f * nn.G, H_p=case.H_g, H_f=case.H_f, **model)
        assert nn.U_i == pytest.approx(u_i, rel=1e-12)
        # verification.md 3b's profiles
        delta, Q_D, X = nn.delta, nn.G / (case.xi * phi_s), case.H_g / nn.delta
        y = np.linspace(-case.H_g, 0.0, 7)
        w = Q_D + (u_i - Q_D) * np.sinh((y + case.H_g) / delta) / np.sinh(X) - Q_D * np.sinh(-y / delta) / np.sinh(X)
        np.testing.assert_allclose(nn.gel(y)[0], w, rtol=1e-10, atol=1e-12 * abs(Q_D))
        y = np.linspace(0.0, case.H_f, 7)
        np.testing.assert_allclose(nn.fluid(y)[0], u_i * (1 - y / case.H_f) + nn.G / 2 * y * (case.H_f - y),
                                   rtol=1e-10, atol=1e-12 * abs(u_i))
    else:
        W, tau, u0 = _couette_nn_6b(U=nn.U_w, G_s=phi_s, H_g=case.H_g, H_f=case.H_f, **model)
        assert (nn.W, nn.U_i, nn.tau, nn.gel(0.0)[2]) == pytest.approx((W, W, tau, u0), rel=1e-12)
    # the model's own beta matters: neither closure is the model's
    assert abs(LayerClosedForm(case).U_i - nn.U_i) > 1e-3 * abs(nn.U_i)
    # beta -> 0: a no-slip wall for the channel; W, U_i = O(beta/phi_s^2)
    beta = 1e-14
    stuck = LayerClosedForm(dataclasses.replace(case, beta=beta))
    y = np.linspace(0.0, case.H_f, 7)
    wall = stuck.U_w * y / case.H_f + stuck.G / 2 * y * (case.H_f - y)
    np.testing.assert_allclose(stuck.fluid(y)[0], wall, rtol=0, atol=1e2 * beta / phi_s**2 * np.abs(wall).max())


def test_compression_closed_form_against_6a():
    """verification.md section 6 intro and 6a in the model's units.

    kappa = phi_f/(xi phi_s), M_d = phi_s (2 + lambda_s).

    With eta finite: Delta p_i = q phi_s^2/(eta phi_f^2), sigma_s,zz(0) =
    -q phi_s/(eta phi_f^2), u_z(0) = -(L/M_d)(Delta p_gel/2 + Delta p_i).
    eta -> inf: 6a's table (phi_s0 = 0.1, xi = 1, M_d = 3.5, i.e. lambda_s = 33 here).
    """
    for case in (LayerCase("compression"), LayerCase.table1("compression")):
        cf = LayerClosedForm(case)
        phi_s, q, L = case.phi_s0, cf.q, case.H_g
        phi_f = 1 - phi_s
        M_d = phi_s * (2 + case.lambda_s)
        dp_i = q * phi_s**2 / (case.eta * phi_f**2)
        assert cf.P - cf.gel(0.0)[4] == pytest.approx(dp_i, rel=1e-12)
        assert (2 + case.lambda_s) * cf.displacement_gradient(0.0)[1] == pytest.approx(
            -q * phi_s / (case.eta * phi_f**2), rel=1e-12)
        dp_gel = q * L * case.xi * phi_s / phi_f
        assert cf.gel(0.0)[3] == pytest.approx(-(L / M_d) * (dp_gel / 2 + dp_i), rel=1e-12)
    for q, u0 in ((0.36, -0.00571429), (3.6, -0.05714286)):
        cf = LayerClosedForm(LayerCase("compression", drive=q, phi_s0=0.1, xi=1.0, lambda_s=33.0, eta=1e30))
        assert cf.gel(0.0)[3] == pytest.approx(u0, rel=1e-6)
        assert cf.dp_i < 1e-28


# ----------------------------------------------------------------------------------------------
# 2. The partitioned device against the closed forms
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module", params=sorted(RATE_CASES))
def rate_study(request):
    """The device's default coupling (serial IQN-ILS to 1e-10) on the three meshes."""
    case = RATE_CASES[request.param]
    runs = []
    for n in MESHES:
        device = LayerDevice(case, n=n)
        result = device.solve()
        runs.append((result.converged, device.errors()))
    return request.param, case, runs


def test_tangential_flows_converge_at_the_element_orders(rate_study):
    """Poiseuille (3b) and Couette (6b) over the gel layer: errors at the expected rates.

    Asserted: every coupling converged; the fitted rate of every error is at
    least its order (ORDERS) minus 0.3 (order 3) or 0.2 (order 2); and on the
    finest mesh (delta/h = 8) the interface velocity and the two flow rates
    are within verification.md 3b's 1e-4.
    """
    name, case, runs = rate_study
    assert all(converged for converged, _ in runs), name
    h = case.H_g / np.array(MESHES)
    errors = {k: np.array([e[k] for _, e in runs]) for k in runs[0][1]}
    assert set(errors) == set(ORDERS)
    rates = {k: fitted_rate(h, v) for k, v in errors.items()}
    for k in ORDERS:
        print(f"{name:18s} {k:30s} errors {np.array2string(errors[k], precision=2)} rate {rates[k]:.2f}")
    for k, order in ORDERS.items():
        assert rates[k] >= order - MARGIN[order], (name, k, rates[k], errors[k])
    for k in ("Gamma1/velocity", "Q_f", "Q_p"):
        assert errors[k][-1] < 1e-4, (name, k, errors[k])


@pytest.mark.parametrize("table1", [False, True], ids=["resolvable", "table1"])
def test_compression_is_exact_up_to_the_neglected_strain(table1):
    """Flow-induced compression (6a with the model's Delta p_i).

    The exact V, v_f (uniform), p (linear) and u_s (quadratic) lie in the FE
    spaces, so there is no discretisation error: the coupled solution
    differs from the linear closed form by what the linearisation neglects,
    terms of relative size max|F - I| (docs/partitioning.md section 5), plus
    the coupling tolerance (1e-10).  As Ca -> 0 that size vanishes.
    """
    case = LayerCase.table1("compression") if table1 else LayerCase("compression")
    for Ca in (case.Ca, 1e-14):
        device = LayerDevice(dataclasses.replace(case, Ca=Ca), n=4)
        assert device.solve().converged
        errors = device.errors()
        bound = device.closed_form.max_strain() + 1e-9
        print(f"compression table1={table1} Ca={Ca:.0e}: strain {bound - 1e-9:.1e}, "
              f"errors {', '.join(f'{k} {v:.1e}' for k, v in errors.items())}")
        for k, v in errors.items():
            assert v <= bound, (Ca, k, v, bound)
