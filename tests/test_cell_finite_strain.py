"""The cell at large strain: a thick ring under a large radial dead load against the radially
symmetric neo-Hookean solution, and Newton's quadratic convergence (the standard of
tests/test_gel_finite_strain.py for the gel).

Reference: plane strain, r = r(R), lambda_r = r', lambda_t = r/R, J = lambda_r lambda_t; the
first Piola stress of model.md's law in polar components,

    P_RR = mu (lambda_r - 1/lambda_r) + lambda lambda_t (J - 1)
    P_TT = mu (lambda_t - 1/lambda_t) + lambda lambda_r (J - 1)

and equilibrium dP_RR/dR + (P_RR - P_TT)/R = 0, i.e. the ODE

    r'' = -[(P_RR - P_TT) + lambda (2 J - 1)(lambda_r - lambda_t)] / (R dP_RR/dlambda_r),
    dP_RR/dlambda_r = mu (1 + 1/lambda_r^2) + lambda lambda_t^2,

with P_RR(a) = 0 (free inner face) and P_RR(b) = t0 (the nominal radial traction on the outer
face), solved by shooting on r(a) with scipy (DOP853, rtol 1e-13; the boundary condition to 1e-12).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate
import scipy.optimize

from mpi4py import MPI
from petsc4py import PETSc

import ufl
from dolfinx import fem

from cell import NeoHookeanCellSolver, meshes
from femtools.functions import integrate

MU, LMBDA, A, B = 1.0, 1.5, 0.5, 1.0
T0 = 0.6          # nominal radial traction, 60 % of mu: hoop stretches 1.77 (inner face), 1.33 (outer)


def p_rr(lr, lt):
    return MU * (lr - 1 / lr) + LMBDA * lt * (lr * lt - 1)


def p_tt(lr, lt):
    return MU * (lt - 1 / lt) + LMBDA * lr * (lr * lt - 1)


def _rhs(R, y):
    r, lr = y
    lt = r / R
    J = lr * lt
    stiff = MU * (1 + 1 / lr**2) + LMBDA * lt**2
    return [lr, -((p_rr(lr, lt) - p_tt(lr, lt)) + LMBDA * (2 * J - 1) * (lr - lt)) / (R * stiff)]


def _shoot(s, dense=False):
    """Integrate from R = a with lambda_t(a) = s and P_RR(a) = 0."""
    lr = scipy.optimize.brentq(lambda x: p_rr(x, s), 1e-3, 50.0, xtol=1e-15, rtol=1e-15)
    return scipy.integrate.solve_ivp(_rhs, (A, B), [s * A, lr], method="DOP853", rtol=1e-13, atol=1e-15,
                                     dense_output=dense)


def radial_solution():
    """``r(R)`` (a callable) of the ring loaded by T0, and the outer traction's residual."""
    def miss(s):
        sol = _shoot(s)
        r, lr = sol.y[:, -1]
        return p_rr(lr, r / B) - T0
    s = scipy.optimize.brentq(miss, 1.0, 3.0, xtol=1e-15, rtol=1e-15)
    sol = _shoot(s, dense=True)
    return (lambda R: sol.sol(R)[0]), abs(miss(s))


@pytest.fixture(scope="module")
def reference():
    r, residual = radial_solution()
    assert residual < 1e-12
    return r


def ring(h, load=1.0, reuse="adaptive"):
    msh, ft = meshes.annulus(A, B, h, quarter=True)
    t = fem.Constant(msh, PETSc.ScalarType(load * T0))
    s = NeoHookeanCellSolver(msh, ft, mu=MU, lmbda=LMBDA, tractions=[(meshes.OUTER, t * ufl.FacetNormal(msh))],
                             symmetry=[(meshes.XAXIS, 1), (meshes.YAXIS, 0)], reuse=reuse, newton_rtol=1e-13)
    return s, t


def solve_stepped(s, t, steps=4):
    """Dead load applied in ``steps`` equal increments (Newton from the previous state)."""
    for k in range(1, steps + 1):
        t.value = k / steps * T0
        s.solve()


def exact_displacement(r, V):
    """u = (r(R) - R) X / R interpolated into V (a P5 space: its error is far below the P2 one)."""
    f = fem.Function(V)

    def values(x):
        R = np.hypot(x[0], x[1])
        return np.vstack([(r(R) - R) * x[0] / R, (r(R) - R) * x[1] / R])
    f.interpolate(values)
    return f


def test_ring_under_large_radial_traction(reference):
    """P2 errors against the ODE: L2 rate ~3, radial displacement of both faces within 1e-5 at 32 elements
    per inner quarter circumference."""
    hs = [np.pi * A / 2 / n for n in (8, 16, 32)]
    errors, faces = [], []
    for h in hs:
        s, t = ring(h)
        solve_stepped(s, t)
        msh = s.mesh
        u_ex = exact_displacement(reference, fem.VectorFunctionSpace(msh, ("Lagrange", 5)))
        dx = ufl.dx(domain=msh, metadata={"quadrature_degree": 10})
        e = s.displacement - u_ex
        errors.append(np.sqrt(integrate(ufl.inner(e, e), dx) / integrate(ufl.inner(u_ex, u_ex), dx)))
        n = s.V.dofmap.index_map.size_local
        X = s.V.tabulate_dof_coordinates()[:n, :2]
        R = np.linalg.norm(X, axis=1)
        ur = np.sum(s.displacement.x.array.reshape(-1, 2)[:n] * X, axis=1) / R
        face = [np.abs(ur[np.abs(R - Rf) < 1e-9] - (reference(Rf) - Rf)).max(initial=0.0) / (reference(Rf) - Rf)
                for Rf in (A, B)]
        faces.append(s.comm.allreduce(max(face), op=MPI.MAX))
    rate = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    r_a, r_b = reference(A) / A, reference(B) / B
    print(f"\nring, T0 = {T0}: hoop stretch {r_a:.4f} (inner), {r_b:.4f} (outer); L2 errors {errors}, "
          f"rate {rate:.2f}; nodal u_r error on the faces {faces}")
    assert r_a > 1.3 and r_b > 1.2                 # a large deformation indeed
    assert rate >= 2.7, (rate, errors)
    assert faces[-1] < 1e-5 and errors[-1] < 1e-5, (faces, errors)


def test_cell_exact_newton_converges_quadratically():
    """The full load in one step, a factorisation per iteration: log e_(k+1) / log e_k >= 1.8 in the basin."""
    s, t = ring(np.pi * A / 2 / 8, reuse="never")
    s.solve()
    e = np.array(s.newton_history)
    orders = [np.log(b) / np.log(a) for a, b in zip(e[:-1], e[1:]) if a < 0.05 and b > 1e-12]
    print(f"\ncell Newton corrections: {e}; orders {np.round(orders, 2)}")
    # the solver stops once the contraction says the error left (~e_k^2 here) is below its rtol
    assert e[-1] < 1e-8 and len(orders) >= 2, e
    assert min(orders) >= 1.8, orders
