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

from femtools.functions import integrate, von_mises
from femtools.interface import InterfaceNodes
from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, rectangle_mesh
from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver
from gel_cases import X0, X1, Y0, Y1, Z0, Z1, box_mesh
from test_gel import l2, rates
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
