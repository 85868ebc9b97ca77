"""The gel solver on 3D tetrahedral meshes: the same code as in 2D (model.md sections 2, 8, 9 and 10).

* von Mises in 3D: the full formula of model.md section 10 on known stress
  states, and the solver's network measure on a homogeneous finite-strain state;
* Terzaghi consolidation of a 3D column (verification.md 4a) against the
  series, with a tolerance from the time-step and mesh errors seen by halving;
* a 3D manufactured solution (sources from the strong form by sympy, not from
  the code's weak forms), small and finite strain, with its convergence rates;
* the slab: a 3D box with symmetry on its z faces reproduces the 2D solution
  of the same problem to discretisation error (the difference shrinks with h).

Every test reduces over all ranks: ``./scripts/pytest-2-ranks tests/test_gel_3d.py``
runs them on 2 ranks with the same assertions.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from mpi4py import MPI

import ufl
from dolfinx import fem
from dolfinx.mesh import create_mesh, meshtags

from femtools.functions import integrate, von_mises
from femtools.interface import InterfaceNodes
from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, rectangle_mesh
from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver
from gel_cases import X0, X1, Y0, Y1, Z0, Z1, box_mesh
from mpi_run import run_mpi
from test_gel import l2, rates
from test_gel_jacobian import FLOOR as JACOBIAN_FLOOR, _check_second_order as check_second_order
from test_gel_transient import C_V, M_D, PRM as TERZAGHI_PRM, terzaghi_consolidation, terzaghi_pressure

COMM = MPI.COMM_WORLD


def _mean(expr, msh, degree=4) -> float:
    """Mean of a scalar UFL expression over the mesh."""
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": degree})
    return integrate(expr, dx) / integrate(fem.Constant(msh, 1.0), dx)


# --------------------------------------------------------------------------
# von Mises in 3D (model.md section 10) and 2D (the paper's formula)
# --------------------------------------------------------------------------
def _deviatoric_von_mises(S: np.ndarray) -> float:
    """sqrt(3/2 s:s) with s = S - tr(S)/3 I: the textbook definition, independent of the formula's form."""
    s = S - np.trace(S) / 3 * np.eye(3)
    return float(np.sqrt(1.5 * np.sum(s * s)))


@pytest.mark.parametrize("state,expected", [
    (np.diag([2.0, 0.0, 0.0]), 2.0),                                       # uniaxial: |s|
    (np.array([[0.0, 1.5, 0.0], [1.5, 0.0, 0.0], [0.0, 0.0, 0.0]]), 1.5 * np.sqrt(3.0)),   # shear: sqrt(3) tau
    (np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.7], [0.0, 0.7, 0.0]]), 0.7 * np.sqrt(3.0)),   # shear in yz
    (-3.0 * np.eye(3), 0.0),                                               # hydrostatic
    (np.array([[1.0, 0.4, -0.3], [0.4, -2.0, 0.5], [-0.3, 0.5, 0.6]]), None),    # general
])
def test_von_mises_3d_known_stress_states(state, expected):
    msh, _ = box_mesh((0, 0, 0), (1, 1, 1), (1, 1, 1))
    value = _mean(von_mises(ufl.as_matrix(state.tolist())), msh)
    reference = _deviatoric_von_mises(state) if expected is None else expected
    assert value == pytest.approx(reference, rel=1e-13, abs=1e-13)


def test_von_mises_2d_keeps_the_papers_formula():
    """2x2: sqrt(sxx^2 + syy^2 - sxx syy + 3 sxy^2) (the 3D formula with szz = syz = szx = 0)."""
    msh, _ = rectangle_mesh(0.0, 0.0, 1.0, 1.0, 1, 1)
    S = np.array([[1.0, 0.4], [0.4, -2.0]])
    paper = np.sqrt(S[0, 0]**2 + S[1, 1]**2 - S[0, 0] * S[1, 1] + 3 * S[0, 1]**2)
    plane = np.zeros((3, 3))
    plane[:2, :2] = S
    assert _mean(von_mises(ufl.as_matrix(S.tolist())), msh) == pytest.approx(paper, rel=1e-13)
    assert paper == pytest.approx(_deviatoric_von_mises(plane), rel=1e-13)


def test_network_von_mises_of_a_homogeneous_finite_strain_state():
    """u = (F - I) X on the whole boundary, w = 0, p = 0 at one face, no load: the exact state is
    homogeneous (u in the P2 space, uniform phi_s, p = 0); sigma_s = J^-1 (F F^T - I) + lambda_s (J - 1) I."""
    F = np.array([[1.15, 0.2, 0.0], [0.05, 0.9, 0.1], [0.0, -0.12, 1.05]])
    prm = GelParameters(phi_s0=0.2, lambda_s=1.5, Ca=1.0)
    msh, ft = box_mesh((0, 0, 0), (1, 1, 1), (2, 2, 2))
    faces = (X0, X1, Y0, Y1, Z0, Z1)
    G = F - np.eye(3)
    gel = PoroelasticGelSolver(msh, ft, prm, kinematics="finite",
                               dirichlet=[(faces, "w", 0.0), (faces, "u", lambda x: G @ x), (X0, "p", 0.0)])
    gel.solve()
    J = np.linalg.det(F)
    sigma = (F @ F.T - np.eye(3)) / J + prm.lambda_s * (J - 1) * np.eye(3)
    vm = _mean(gel.network_von_mises(), msh)
    print(f"von Mises of the network: {vm:.12f}, closed form {_deviatoric_von_mises(sigma):.12f}")
    assert vm == pytest.approx(_deviatoric_von_mises(sigma), rel=1e-9)


# --------------------------------------------------------------------------
# Terzaghi consolidation of a 3D column (verification.md 4a)
# --------------------------------------------------------------------------
TERZAGHI_T = (0.05, 0.2, 0.5)


def _terzaghi_column(nz: int, n_steps: int, L=1.0, width=0.1, p0=1.0) -> np.ndarray:
    """Column [0, w]^2 x [-L, 0]: top z = 0 drained (p = 0) and loaded by -p0 e_z, bottom bonded
    (u = 0, v_f = 0), sides sealed rollers (symmetry).  BDF2 (one BE start) from rest to T = 0.5 in
    ``n_steps``; returns (p at the bottom / p0, settlement / final settlement) at ``TERZAGHI_T``."""
    msh, ft = box_mesh((0.0, 0.0, -L), (width, width, 0.0), (1, 1, nz))
    gel = PoroelasticGelSolver(msh, ft, TERZAGHI_PRM, no_slip=Z0, symmetry=[((X0, X1), 0), ((Y0, Y1), 1)],
                               dirichlet=[(Z1, "p", 0.0)], tractions=[(Z1, (0.0, 0.0, -p0))], transient=True)
    ds = ufl.Measure("ds", domain=msh, subdomain_data=ft)
    _, u, p = ufl.split(gel.state)
    area = width**2
    gel.push_history()                              # u^0 = 0: at rest
    t_end = TERZAGHI_T[-1] * L**2 / C_V
    dt = t_end / n_steps
    out = {}
    for k in range(1, n_steps + 1):
        gel.set_time_step(dt, "be" if k == 1 else "bdf2")
        gel.solve()
        gel.push_history()
        T = k * dt * C_V / L**2
        if any(np.isclose(T, Tr, rtol=1e-9) for Tr in TERZAGHI_T):
            out[round(T, 6)] = (integrate(p, ds(Z0)) / area / p0,
                                -integrate(u[2], ds(Z1)) / area * M_D / (p0 * L))
    return np.array([out[round(T, 6)] for T in TERZAGHI_T])


def test_terzaghi_column_3d():
    """p at the sealed bottom and the settlement against the series at T = 0.05, 0.2, 0.5.

    Tolerance per value: 2 (|q(h, dt) - q(h, dt/2)| + |q(h, dt) - q(h/2, dt)|) + 1e-4, i.e. the
    time-step and mesh errors estimated by halving (the factor 2 bounds the error of any method of
    order >= 1 by its halving difference) plus ten times the Brinkman terms the series neglects
    (relative size 1/(xi phi_s0 L^2) = 1e-5, see tests/test_gel_transient.py).
    """
    base, half_dt, half_h = _terzaghi_column(8, 40), _terzaghi_column(8, 80), _terzaghi_column(16, 40)
    series = np.array([(terzaghi_pressure(1.0, T), terzaghi_consolidation(T)) for T in TERZAGHI_T])
    tol = 2 * (np.abs(base - half_dt) + np.abs(base - half_h)) + 1e-4
    err = np.abs(base - series)
    for k, T in enumerate(TERZAGHI_T):
        print(f"Terzaghi 3D T = {T}: p(L) error {err[k, 0]:.2e} (tol {tol[k, 0]:.2e}), settlement error "
              f"{err[k, 1]:.2e} (tol {tol[k, 1]:.2e}); halving dt {np.abs(base - half_dt)[k]}, "
              f"halving h {np.abs(base - half_h)[k]}")
    assert np.all(err <= tol), (err, tol)
    assert np.all(np.abs(half_h - series) <= tol), "the finer mesh must be as close"


# --------------------------------------------------------------------------
# manufactured solution in 3D, sources from the strong form (numpy, not the code's forms)
# --------------------------------------------------------------------------
def _fields(amp):
    """Exact v_f, u_hat, p_hat on the unit cube and their gradients, lambdified from sympy.

    u_x has no y or z derivative on x = 1, so the current normal there stays e_x."""
    X, Y, Z = Xs = sp.symbols("X Y Z", real=True)
    av, au, ap = amp
    v = av * sp.Matrix([sp.sin(sp.pi * Y) * sp.cos(X) * sp.cos(Z), sp.exp(X) * Y * (1 + Z) / 2,
                        sp.sin(sp.pi * Z) * X * Y + Z / 3])
    u = au * sp.Matrix([sp.sin(sp.Rational(3, 2) * X) + (1 - X)**2 * (Y / 2 + 2 * sp.sin(Z) / 5),
                        sp.Rational(4, 5) * (X * sp.cos(X - Y) + sp.sin(Z) / 2),
                        sp.Rational(3, 5) * (X * sp.sin(Y + Z) + sp.cos(X) * Z)])
    p = sp.Matrix([ap * (sp.cos(sp.pi * X) * sp.sin(sp.pi * Y) * sp.cos(sp.pi * Z / 2) + X)])
    for e in (sp.diff(u[0], Y), sp.diff(u[0], Z)):
        assert abs(float(e.subs({X: 1, Y: 0.37, Z: 0.61}))) < 1e-14
    exprs = {"v": v, "u": u, "p": p, "grad_v": v.jacobian(Xs), "grad_u": u.jacobian(Xs), "grad_p": p.jacobian(Xs)}
    fns = {k: sp.lambdify(Xs, e, "numpy") for k, e in exprs.items()}

    def at(name, x):
        """(rows, cols, n) values at the points x (3, n)."""
        out = np.array(fns[name](x[0], x[1], x[2]), dtype=object)
        return np.array([[np.broadcast_to(np.asarray(a, dtype=float), x.shape[1]) for a in row] for row in out])
    return at


def _material(at, x, prm: GelParameters, finite: bool) -> dict:
    """The model's fields at x (model.md section 2; units of mu_s and L0): F, J, the inverse map of
    the gradients, phi_s, sigma_f, sigma_s, the total stress; finite: grad_x = grad_X F^-1, small:
    grad_X."""
    d, s = prm.displacement_scale, prm.stress_scale
    n = x.shape[1]
    I = np.repeat(np.eye(3)[:, :, None], n, axis=2)
    F = I + d * at("grad_u", x)
    Fm = np.moveaxis(F, 2, 0)                                       # (n, 3, 3)
    J = np.linalg.det(Fm)
    Finv = np.moveaxis(np.linalg.inv(Fm), 0, 2) if finite else I
    L = np.einsum("ikn,kjn->ijn", at("grad_v", x), Finv)
    sigma_f = prm.Ca * (L + L.transpose(1, 0, 2))
    sigma_s = np.einsum("ikn,jkn->ijn", F, F) / J - I / J + prm.lambda_s * (J - 1) * I
    phi_s = prm.phi_s0 / J
    p = s * at("p", x)[0, 0]
    total = (1 - phi_s) * sigma_f + phi_s * sigma_s - p * I
    return dict(F=F, J=J, Finv=Finv, phi_s=phi_s, sigma_f=sigma_f, sigma_s=sigma_s, total=total, p=p)


def _divergences(fun, x, Finv, delta=2e-3):
    """The spatial divergences sum_jk d a_ij / dX_k Finv_kj of each array a of ``fun(x)`` (a tensor,
    or a vector with i dropped), each dX_k by the fourth-order central difference (error ~delta^4)."""
    out = None
    for k in range(3):
        e = np.zeros((3, 1))
        e[k] = delta
        for c, shift in ((-1, 2), (8, 1), (-8, -1), (1, -2)):
            terms = [c / (12 * delta) * np.einsum("...jn,jn->...n", a, Finv[k]) for a in fun(x + shift * e)]
            out = terms if out is None else [o + t for o, t in zip(out, terms)]
    return out


def _manufactured_3d(prm: GelParameters, kinematics: str, amp) -> dict:
    """Functions x -> values of the exact (v_f, u_hat, p_hat), the loads and the data of the fluid
    interface x = 1, in the solver's units (u = d u_hat, p = s p_hat, stresses / s).

    Loads from the steady strong form (finite: per unit REFERENCE volume, times J):
        f_z = -J div_x(total),  f_w = -J [div_x(phi_f sigma_f) - phi_f grad_x p - xi Ca phi_f phi_s v_f],
        f_q = -J div_x(phi_f v_f).
    On x = 1 (current normal e_x; the tangential v_f are Dirichlet data, so the fluid phase sees its
    normal condition only): T the total traction (finite: nominal, J sigma F^-T e_x) and
    V_x = v_x + phi_f eta (sigma_f,xx - sigma_s,xx) / Ca (I15).
    """
    at = _fields(amp)
    finite = kinematics == "finite"
    s = prm.stress_scale

    def m(x):
        return _material(at, x, prm, finite)

    def fluxes(y):
        q = m(y)
        return q["total"], (1 - q["phi_s"]) * q["sigma_f"], (1 - q["phi_s"]) * at("v", y)[:, 0]

    cache = {}

    def loads(x):
        key = (x.shape, hash(x.tobytes()))
        if key not in cache:              # one evaluation for the three loads on the same points
            q = m(x)
            phi_f, vol = 1 - q["phi_s"], q["J"] if finite else 1.0
            grad_p = s * np.einsum("kn,kjn->jn", at("grad_p", x)[0], q["Finv"])
            r_m, div_f, r_q = _divergences(fluxes, x, q["Finv"])
            r_f = div_f - phi_f * grad_p - prm.xi * prm.Ca * phi_f * q["phi_s"] * at("v", x)[:, 0]
            cache.clear()
            cache[key] = {"f_w": -vol * r_f / s, "f_z": -vol * r_m / s, "f_q": -vol * r_q[None]}
        return cache[key]

    def traction(x):
        q = m(x)
        cof = q["J"] * q["Finv"].transpose(1, 0, 2) if finite else q["Finv"]     # J F^-T (small: I)
        return np.einsum("ikn,kn->in", q["total"], cof[:, 0]) / s

    def velocity(x):
        q = m(x)
        v = at("v", x)[:, 0]
        V = v.copy()
        V[0] += (1 - q["phi_s"]) * prm.eta * (q["sigma_f"][0, 0] - q["sigma_s"][0, 0]) / prm.Ca
        return V
    out = {"v": lambda x: at("v", x)[:, 0], "u": lambda x: at("u", x)[:, 0], "p": lambda x: at("p", x)[0],
           "T": traction, "V": velocity}
    out.update({k: (lambda x, k=k: loads(x)[k]) for k in ("f_w", "f_z", "f_q")})
    return out


def _interpolated(f, V):
    """Interpolate a function x (3, n) -> (bs, n) into V."""
    g = fem.Function(V)
    g.interpolate(f)
    g.x.scatter_forward()
    return g


def _mms_errors_3d(prm, kinematics, fns, N):
    """Relative L2 errors of (v_f, u, p) on the unit cube with N^3 cubes (6 tetrahedra each).

    Dirichlet v_f and u on every face but x = 1, a fluid interface fed with the exact T and V (and
    v_f,y, v_f,z Dirichlet there).  Loads interpolated in P4 (error O(h^5), far below the
    discretisation error), the exact fields in P5."""
    msh, ft = box_mesh((0, 0, 0), (1, 1, 1), (N, N, N))
    V4, Q4 = fem.VectorFunctionSpace(msh, ("Lagrange", 4)), fem.FunctionSpace(msh, ("Lagrange", 4))
    loads = (_interpolated(fns["f_w"], V4), _interpolated(fns["f_z"], V4), _interpolated(fns["f_q"], Q4))

    def field(name, c=None):
        return fns[name] if c is None else (lambda x: fns[name](x)[c])
    walls = (X0, Y0, Y1, Z0, Z1)
    gel = PoroelasticGelSolver(msh, ft, prm, fluid_interfaces={"right": X1}, kinematics=kinematics,
                               dirichlet=[(walls, "v_f", field("v")), (walls, "u", field("u")),
                                          (X1, "v_f", field("v", 1), 1), (X1, "v_f", field("v", 2), 2)],
                               body_forces=loads)
    V2 = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
    nodes = InterfaceNodes(V2, ft, X1)
    gel.set_interface_data("right", traction=nodes.from_function(_interpolated(fns["T"], V2)),
                           velocity=nodes.from_function(_interpolated(fns["V"], V2)))
    gel.solve()
    V5, Q5 = fem.VectorFunctionSpace(msh, ("Lagrange", 5)), fem.FunctionSpace(msh, ("Lagrange", 5))
    exact = [_interpolated(fns["v"], V5), _interpolated(fns["u"], V5), _interpolated(fns["p"], Q5)]
    computed = [gel.interstitial_velocity(), gel.displacement(), gel.pore_pressure()]
    return [l2(c - e, msh) / l2(e, msh) for c, e in zip(computed, exact)]


MMS_N = (2, 3, 4)
MMS_CASES = {
    # device scaling s = d = Ca: strains ~1e-7, phi_s(J) and the network effectively linear
    "small": (GelParameters.viscous_units(phi_s0=0.3, xi=5.0, lambda_s=1.5, beta=0.7, eta=0.4, Ca=1e-6),
              (0.5, 0.1, 1.0)),
    # paper units s = d = 1, displacement gradients up to ~0.2
    "finite": (GelParameters(phi_s0=0.3, xi=5.0, lambda_s=1.5, beta=0.7, eta=0.4, Ca=0.5), (0.05, 0.1, 0.1)),
}


@pytest.fixture(scope="module", params=list(MMS_CASES))
def mms_3d(request):
    prm, amp = MMS_CASES[request.param]
    fns = _manufactured_3d(prm, request.param, amp)
    return request.param, np.array([_mms_errors_3d(prm, request.param, fns, N) for N in MMS_N])


def test_mms_3d_rates(mms_3d):
    """Observed L2 rates of (v_f, u, p) on N = 2, 3, 4 against the P2/P2/P1 element's orders.

    small (tiny strain): 3, 3, 2 (as in 2D, tests/test_gel.py); finite (~20 % strain): 2 for all,
    the P2 u_h's second derivatives entering phi_f(J(grad u_h)) (docs/finite-strain.md); asserted
    with a margin of 0.3 for the coarse levels.
    """
    kinematics, errors = mms_3d
    h = 1.0 / np.array(MMS_N)
    r = np.array([rates(h, errors[:, i]) for i in range(3)])
    expected = np.array([3.0, 3.0, 2.0]) if kinematics == "small" else np.array([2.0, 2.0, 2.0])
    msg = f"{kinematics}: rates v_f, u, p = {np.round(r, 2)}; errors {errors.tolist()}"
    print("mms 3D", msg)
    assert np.all(r >= expected - 0.3), msg


# --------------------------------------------------------------------------
# the slab: symmetry on the z faces reproduces the 2D (plane-strain) solution
# --------------------------------------------------------------------------
SLAB_CASES = {
    "small": (GelParameters.viscous_units(phi_s0=0.2, xi=50.0, lambda_s=1.0, Ca=1e-6), 1.0),
    "finite": (GelParameters(phi_s0=0.2, xi=50.0, lambda_s=1.0, Ca=0.3), 0.02),
}
SLAB_H = 0.125


def _slab_data(X, amp):
    """The fluid interface's traction and velocity at the points X (their first two components):
    the tangential traction odd and the normal parts even about x = 0 and x = 1, so that the
    symmetry planes there meet the interface without a corner singularity."""
    c, s = np.cos(np.pi * X[:, 0]), np.sin(np.pi * X[:, 0])
    return amp * np.column_stack([0.3 * s, -1.0 - 0.5 * c]), np.column_stack([0.0 * c, -0.02 * c])


def _slab_solution(kinematics, n, dim):
    """[0, 1] x [0, 0.5] (x [0, H] in 3D, z faces symmetry planes): bonded bottom, a fluid interface
    on top (nonuniform traction and normal velocity), symmetry at x = 0 and x = 1.  Returns
    {field: (points (N, 2), values (N, dim))} of v_f, u and p at the owned nodes of all ranks."""
    prm, amp = SLAB_CASES[kinematics]
    if dim == 2:
        msh, ft = rectangle_mesh(0.0, 0.0, 1.0, 0.5, n, n // 2)
        bottom, top, sides, extra = BOTTOM, TOP, (LEFT, RIGHT), []
    else:
        msh, ft = box_mesh((0.0, 0.0, 0.0), (1.0, 0.5, SLAB_H), (n, n // 2, max(1, round(n * SLAB_H))))
        bottom, top, sides, extra = Y0, Y1, (X0, X1), [((Z0, Z1), 2)]
    gel = PoroelasticGelSolver(msh, ft, prm, no_slip=bottom, symmetry=[(sides, 0)] + extra, kinematics=kinematics,
                               fluid_interfaces={"top": top})
    X = gel.interface_points("top")
    T, V = _slab_data(X, amp)
    pad = np.zeros((X.shape[0], dim - 2))
    gel.set_interface_data("top", traction=np.hstack([T, pad]), velocity=np.hstack([V, pad]))
    gel.solve()
    out = {}
    for name, f in (("v_f", gel.interstitial_velocity()), ("u", gel.displacement()), ("p", gel.pore_pressure())):
        V = f.function_space
        owned, bs = V.dofmap.index_map.size_local, V.dofmap.index_map_bs
        points = np.vstack(COMM.allgather(V.tabulate_dof_coordinates()[:owned, :2]))
        out[name] = points, np.vstack(COMM.allgather(f.x.array[:owned * bs].reshape(-1, bs)))
    out["phi_f v_f on top"] = X[:, :2], gel.interface_data("top")["superficial_velocity"]   # replicated
    return out


def _slab_difference(kinematics, n) -> dict:
    """max |3D - 2D| / max |2D| over the 3D nodes, each matched with the 2D node at its (x, y) (every
    P2 node of the box lies above one of the rectangle's), for v_f, u, p, the superficial velocity on the
    fluid interface (its nodal phi_f: facet-weighted in 2D, psi^2-weighted in 3D), and the z components."""
    two, three = _slab_solution(kinematics, n, 2), _slab_solution(kinematics, n, 3)
    out = {}
    for key in ("v_f", "u", "p", "phi_f v_f on top"):
        (X2, d2), (X3, d3) = two[key], three[key]
        index = {tuple(k): i for i, k in enumerate(np.rint(X2 * 2 * n).astype(int).tolist())}
        match = np.array([index[tuple(k)] for k in np.rint(X3 * 2 * n).astype(int).tolist()])
        scale = np.abs(d2).max()
        out[key] = np.abs(d2[match] - d3[:, :d2.shape[1]]).max() / scale
        if key in ("v_f", "u"):
            out[key + " z"] = np.abs(d3[:, 2]).max() / scale
    return out


@pytest.mark.parametrize("kinematics", list(SLAB_CASES))
def test_slab_reproduces_the_2d_solution(kinematics):
    """The 3D solution of the slab is independent of z and equals the 2D one (model.md section 10):
    on two meshes (the same sizes in x, y; h = 1/8 and 1/16) the difference, pure discretisation
    error, must shrink at least like h (P2/P1: about h^2 or better is expected) and be below
    0.5 % on the finer one.
    """
    coarse, fine = _slab_difference(kinematics, 8), _slab_difference(kinematics, 16)
    for key in coarse:
        print(f"slab {kinematics} {key}: 3D - 2D {coarse[key]:.2e} (h = 1/8), {fine[key]:.2e} (h = 1/16), "
              f"rate {np.log2(coarse[key] / fine[key]):.2f}")
    for key in coarse:
        assert fine[key] < 5e-3 and fine[key] <= coarse[key] / 2, (key, coarse[key], fine[key])


# --------------------------------------------------------------------------
# the interface Jacobian in 3D against central differences of the solver
# --------------------------------------------------------------------------
@pytest.mark.parametrize("kinematics,dt", [("small", None), ("finite", 0.5)], ids=["small-steady", "finite-step"])
def test_interface_jacobian_3d_against_central_differences(kinematics, dt):
    """A box with a fluid interface on top and a cell interface (random SPD stiffness) at y = 0:
    central differences of the outputs for all inputs at once at eps and eps/2 against J @ delta,
    the criteria of tests/test_gel_jacobian.py (O(eps^2) error, Richardson far better).  The solves
    converge to 1e-13 with the kept linearisation at rest (the solver's default), so no exact 3D
    Jacobian is compiled for them."""
    prm = GelParameters(phi_s0=0.2, xi=50.0, lambda_s=1.0, beta=0.5, eta=0.5, Ca=0.5)
    msh, ft = box_mesh((0.0, 0.0, 0.0), (1.0, 0.5, 0.25), (4, 2, 1))
    gel = PoroelasticGelSolver(msh, ft, prm, no_slip=Z0, symmetry=[(X0, 0)], kinematics=kinematics,
                               fluid_interfaces={"top": Z1}, cell_interfaces={"cell": Y0},
                               newton_rtol=1e-13, transient=dt is not None)
    if dt is not None:
        gel.set_time_step(dt)                 # reset() keeps it: every solve is one step from rest
    rng = np.random.default_rng(7)
    n = 3 * gel.interface_points("cell").shape[0]
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    gel.set_interface_stiffnesses({"cell": (Q * rng.uniform(0.1, 1.0, n)) @ Q.T})
    J = gel.interface_jacobian()
    scale = {"traction": 0.05, "velocity": 0.05, "force": 0.0005, "displacement": 0.001}
    data = {(name, key): scale[key] * rng.uniform(-1.0, 1.0, (gel.interface_points(name).shape[0], 3))
            for name in ("top", "cell") for key in gel.input_names(name)}
    d1, d2 = (_central_difference(gel, data, eps) for eps in (1.0, 0.5))
    for key_out in d1:
        if key_out[1] == "pressure":
            continue
        lin = sum(J[key_out, key_in] @ delta.ravel() for key_in, delta in data.items())
        ref = np.abs(lin).max()
        e1, e2 = (np.abs(d[key_out] - lin).max() / ref for d in (d1, d2))
        rich = np.abs((4 * d2[key_out] - d1[key_out]) / 3 - lin).max() / ref
        print(f"3D Jacobian {kinematics} {key_out}: errors {e1:.1e} (eps), {e2:.1e} (eps/2), Richardson {rich:.1e}")
        if key_out[1] == "traction":
            assert e1 <= JACOBIAN_FLOOR and e2 <= JACOBIAN_FLOOR, key_out
        else:
            check_second_order(f"{kinematics}: {key_out}", e1, e2, rich)


def _central_difference(gel, data, eps) -> dict:
    """(outputs(+eps data) - outputs(-eps data)) / (2 eps), each solve from rest."""
    out = []
    for sign in (1.0, -1.0):
        gel.reset()
        for (name, key), values in data.items():
            gel.set_interface_data(name, **{key: sign * eps * values})
        gel.solve()
        out.append({(name, key): np.array(v).ravel() for name in gel.interface_names()
                    for key, v in gel.interface_data(name).items()})
    return {k: (out[0][k] - out[1][k]) / (2 * eps) for k in out[0]}


# --------------------------------------------------------------------------
# 1 and 2 ranks
# --------------------------------------------------------------------------
@pytest.mark.mpi
@pytest.mark.parametrize("kinematics", ["small", "finite"])
def test_same_answer_on_one_and_two_ranks(kinematics):
    """A 3D box with fluid and cell interfaces, two time steps: the interface outputs (replicated,
    in the rank-independent node order) on 1 and 2 ranks agree to the solver's tolerance."""
    one = run_mpi("gel3d_mpi.py", 1, [kinematics])
    two = run_mpi("gel3d_mpi.py", 2, [kinematics])
    assert np.allclose(one["points"], two["points"], rtol=0.0, atol=1e-12)      # the same node order
    for key in ("interstitial", "mixture", "pressure", "displacement"):
        a, b = np.array(one[key]), np.array(two[key])
        err = np.abs(a - b).max() / np.abs(a).max()
        print(f"3D {kinematics}: {key} 1 vs 2 ranks {err:.1e}")
        assert a.shape == b.shape and err < 1e-9, f"{key}: 1 vs 2 ranks differ by {err:.2e}"
    for key, value in one["norms"].items():
        assert abs(value - two["norms"][key]) <= 1e-9 * abs(value), key


# --------------------------------------------------------------------------
# bad 3D input
# --------------------------------------------------------------------------
def test_bad_3d_input_is_refused_naming_it():
    prm = GelParameters.viscous_units()
    msh, ft = box_mesh((0, 0, 0), (1, 1, 1), (1, 1, 1))
    with pytest.raises(ValueError, match="component must be in 0..2"):
        PoroelasticGelSolver(msh, ft, prm, no_slip=Z0, symmetry=[(X0, 3)])
    gel = PoroelasticGelSolver(msh, ft, prm, no_slip=Z0, fluid_interfaces={"top": Z1}, cell_interfaces={"side": X1})
    n = gel.interface_points("side").shape[0]
    with pytest.raises(ValueError, match=r"stiffness of 'side' must be \(%d, %d\)" % (3 * n, 3 * n)):
        gel.set_interface_stiffnesses({"side": np.eye(2 * n)})
    with pytest.raises(ValueError, match="shape"):
        gel.set_interface_data("top", traction=np.zeros((gel.interface_points("top").shape[0], 2)))
    # triangles in space (a surface mesh) are neither a plane-strain nor a 3D gel
    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.Cell("triangle", geometric_dimension=3), 1))
    cells = np.array([[0, 1, 2]], dtype=np.int64) if COMM.rank == 0 else np.empty((0, 3), dtype=np.int64)
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]) if COMM.rank == 0 else np.empty((0, 3))
    surface = create_mesh(COMM, cells, x, domain)
    with pytest.raises(ValueError, match="mesh must be"):
        PoroelasticGelSolver(surface, meshtags(surface, 1, np.empty(0, np.int32), np.empty(0, np.int32)), prm)
