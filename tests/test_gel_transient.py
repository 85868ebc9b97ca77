"""Time-dependent gel solver alone: Terzaghi and Mandel consolidation (verification.md 4a, 4b).

Our equations (gel/forms.py) in the linear limit: the network carries the
partial stress phi_s sigma_s, so the drained oedometric modulus is
M_d = phi_s0 (2 + lambda_s) and the drained shear modulus G = phi_s0 (units
of mu_s); the fluid-phase equation without its viscous term is Darcy's law
phi_f (v_f - v_s) = -kappa grad p with kappa = phi_f0 / (xi Ca phi_s0); the
constituents are incompressible (Biot coefficient 1, Skempton B = 1).  Hence
the consolidation coefficient c_v = kappa M_d.  The viscous (Brinkman) stress
of the interstitial fluid is neglected by the closed forms; its relative size
is 1/(xi phi_s0 L^2) and Ca phi_f0/(M_d tau) (Kelvin-Voigt time over the
consolidation time), both ~1e-5 with the parameters below.

Units: the solver runs in s = d = Ca (stress unit Ca mu_s, displacement unit
Ca L0); time is in the paper's unit L0/V0.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from mpi4py import MPI

import ufl
from dolfinx import fem

from femtools.functions import integrate
from femtools.linalg import assemble_residual_vector
from femtools.mesh import BOTTOM, LEFT, RIGHT, TOP, rectangle_mesh
from gel.parameters import GelParameters
from gel.solver import PoroelasticGelSolver

COMM = MPI.COMM_WORLD
PRM = GelParameters.viscous_units(phi_s0=0.01, xi=1e7, lambda_s=1.0, Ca=1e-9)
KAPPA = PRM.darcy_mobility                                   # L0^2 / (mu_s time unit)
M_D = PRM.phi_s0 * (2.0 + PRM.lambda_s)                      # units of mu_s
C_V = KAPPA * M_D


def observed_order(errors):
    """log2 of successive error ratios for halved steps."""
    e = np.asarray(errors)
    return np.log2(e[:-1] / e[1:])


# --------------------------------------------------------------------------
# Terzaghi: a column 0 < z < L (z = depth below the drained, loaded top)
# --------------------------------------------------------------------------
def terzaghi_pressure(z_over_L, T, terms=200):
    """p / p0 of the series solution at depth z (drained at z = 0, impermeable at z = L)."""
    m = np.arange(terms)
    M = (2 * m + 1) * np.pi / 2
    return float(np.sum(2 / M * np.sin(M * z_over_L) * np.exp(-M**2 * T)))


def terzaghi_consolidation(T, terms=200):
    """Degree of consolidation U(T) = 1 - sum 2/M^2 exp(-M^2 T)."""
    m = np.arange(terms)
    M = (2 * m + 1) * np.pi / 2
    return float(1 - np.sum(2 / M**2 * np.exp(-M**2 * T)))


def test_terzaghi_series_values():
    """The series reproduces verification.md's table (T = 0.2: U = 0.504088, p(L) = 0.772312)."""
    assert terzaghi_consolidation(0.2) == pytest.approx(0.504088, abs=2e-6)
    assert terzaghi_pressure(1.0, 0.2) == pytest.approx(0.772312, abs=2e-6)
    assert terzaghi_pressure(0.5, 0.1) == pytest.approx(0.735651, abs=2e-6)


class TerzaghiColumn:
    """Gel column on [0, 0.1] x [-L, 0]: load p0 and p = 0 on top, fixed and impermeable at the bottom."""

    def __init__(self, ny=40, L=1.0, p0=1.0):
        self.L, self.p0 = L, p0
        msh, ft = rectangle_mesh(0.0, -L, 0.1, 0.0, 2, ny)
        self.mesh = msh
        self.gel = PoroelasticGelSolver(msh, ft, PRM, no_slip=BOTTOM, symmetry=[((LEFT, RIGHT), 0)],
                                        dirichlet=[(TOP, "p", 0.0)], tractions=[(TOP, (0.0, -p0))],
                                        transient=True)
        self.ds = ufl.Measure("ds", domain=msh, subdomain_data=ft)
        self.dx = ufl.Measure("dx", domain=msh)
        self.width = 0.1

    def run(self, t_end, n, scheme):
        """From rest to t_end in n equal steps; returns the state's (p at the bottom, settlement)."""
        gel = self.gel
        gel.reset()
        gel.push_history()                    # u^0 = 0: at rest
        dt = t_end / n
        for k in range(n):
            gel.set_time_step(dt, "be" if (k == 0 or scheme == "be") else "bdf2")
            gel.solve()
            gel.push_history()
        return self.observables()

    def observables(self):
        _, u, p = ufl.split(self.gel.state)
        p_bottom = integrate(p, self.ds(BOTTOM)) / self.width
        settlement = -integrate(u[1], self.ds(TOP)) / self.width
        return np.array([p_bottom / self.p0, settlement * M_D / (self.p0 * self.L)])


@pytest.fixture(scope="module")
def column():
    return TerzaghiColumn()


@pytest.mark.parametrize("T", [0.05, 0.2, 0.5])
def test_terzaghi_pressure_and_settlement(column, T):
    """BDF2 with 64 steps: p at the impermeable bottom and the settlement against the series.

    Tolerance 2e-3 p0 (resp. of the final settlement): P1 pressure on 40
    elements over the depth plus the BDF2 error at 64 steps, both ~1e-4 here
    (the Brinkman terms the series neglects are ~1e-5).
    """
    t = T * column.L**2 / C_V
    p_rel, s_rel = column.run(t, 64, "bdf2")
    assert p_rel == pytest.approx(terzaghi_pressure(1.0, T), abs=2e-3)
    assert s_rel == pytest.approx(terzaghi_consolidation(T), abs=2e-3)


@pytest.mark.parametrize("scheme,order", [("be", 1), ("bdf2", 2)])
def test_terzaghi_time_order(column, scheme, order):
    """Observed order in time at T = 0.2 (errors against a 512-step BDF2 run on the same mesh).

    The same-mesh reference isolates the time error; with 8, 16, 32 steps
    the errors of BE fall by ~2 per halving and those of BDF2 by ~4.
    """
    t = 0.2 * column.L**2 / C_V
    reference = column.run(t, 512, "bdf2")
    errors = [np.abs(column.run(t, n, scheme) - reference).max() for n in (8, 16, 32)]
    rates = observed_order(errors)
    assert np.all(np.abs(rates - order) < 0.25), (errors, rates)


# --------------------------------------------------------------------------
# Mandel: the pressure at the centre rises first (Mandel-Cryer effect)
# --------------------------------------------------------------------------
def mandel_pressure(x_over_a, t_star, nu, terms=60):
    """p / p0 of Mandel's problem with incompressible constituents (B = 1, nu_u = 1/2)."""
    k = 2 * (1 - nu) / (1 - 2 * nu)
    roots = []
    for n in range(terms):
        # tan(a) = k a has one root in each (n pi, n pi + pi/2)
        lo, hi = n * np.pi + 1e-12, n * np.pi + np.pi / 2 - 1e-12
        roots.append(scipy.optimize.brentq(lambda a: np.tan(a) - k * a, lo if n else 1e-6, hi))
    a = np.array(roots)
    if abs(np.tan(a[0]) - k * a[0]) > 1e-8:
        raise RuntimeError("Mandel root not found")
    return float(2 * np.sum(np.sin(a) / (a - np.sin(a) * np.cos(a)) * (np.cos(a * x_over_a) - np.cos(a))
                            * np.exp(-a**2 * t_star)))


def test_mandel_series_values():
    """The series reproduces verification.md's table for nu = 0.25."""
    for t_star, ref in ((0.01, 1.03875), (0.1, 1.07755), (0.5, 0.56099), (1.0, 0.23345)):
        assert mandel_pressure(0.0, t_star, 0.25) == pytest.approx(ref, abs=2e-5)
    assert mandel_pressure(0.5, 0.1, 0.25) == pytest.approx(0.84552, abs=2e-5)


class MandelQuarter:
    """Quarter specimen [0, a] x [0, b]: symmetry on x = 0 and y = 0, drained free side x = a,
    rigid frictionless impermeable plate on y = b carrying the force F (per half width a).

    The plate is a uniform vertical displacement -delta whose value makes the
    plate's reaction equal F at every step.  The problem is linear (the
    strains are ~1e-8 in these units), so each step is the superposition
    state = state_0 + delta state_1 of two solves: state_0 with the history
    and the plate held (delta = 0), state_1 with no history and delta = 1.
    """

    def __init__(self, nx=24, ny=6, a=1.0, b=0.25, force=1.0):
        self.a, self.b, self.F = a, b, force
        msh, ft = rectangle_mesh(0.0, 0.0, a, b, nx, ny)
        self.plate = fem.Constant(msh, 0.0)
        self.gel = PoroelasticGelSolver(msh, ft, PRM, symmetry=[(LEFT, 0), (BOTTOM, 1)],
                                        dirichlet=[(RIGHT, "p", 0.0), (TOP, "w", 0.0, 1),
                                                   (TOP, "u", self._plate_value, 1)],
                                        transient=True)
        self._plate_bc = self.gel._bc_functions[-1]
        V_uy, to_parent = self.gel.W.sub(1).sub(1).collapse()
        top = fem.locate_dofs_topological((self.gel.W.sub(1).sub(1), V_uy), 1, ft.find(TOP))[0]
        owned = self.gel.W.dofmap.index_map.size_local * self.gel.W.dofmap.index_map_bs
        self._top_rows = top[top < owned]
        self._residual = fem.form(self.gel.residual_form)
        self.ds = ufl.Measure("ds", domain=msh, subdomain_data=ft)

    _delta = 0.0

    def _plate_value(self, x):
        return np.full(x.shape[1], -self._delta)

    def _set_plate(self, delta):
        self._delta = delta
        self._plate_bc.interpolate(self._plate_value)
        self._plate_bc.x.scatter_forward()

    def _plate_force(self):
        """Vertical force on the specimen through the plate: the sum of the u_y reactions on top.

        The residual of the mixture equation without boundary conditions is
        int (total stress) n . z ds at a solution, so its u_y rows on the plate
        sum to the force the plate exerts (negative: it pushes down).
        """
        R = assemble_residual_vector(self._residual)
        force = COMM.allreduce(float(R.array[self._top_rows].sum()), op=MPI.SUM)
        R.destroy()
        return force

    def step(self, dt, scheme, dt_previous=None):
        gel = self.gel
        gel.set_time_step(dt, scheme, dt_previous)
        saved = gel.get_state()
        # unit plate displacement with no history
        empty = {k: np.zeros_like(v) for k, v in saved.items()}
        empty["length"] = saved["length"]
        gel.set_state(empty)
        self._set_plate(1.0)
        gel.solve()
        unit, f_unit = gel.get_state(), self._plate_force()
        # the history with the plate held
        gel.set_state(saved)
        self._set_plate(0.0)
        gel.solve()
        held, f_held = gel.get_state(), self._plate_force()
        delta = (-self.F - f_held) / f_unit          # the plate pushes down with the force F
        combined = dict(saved)
        combined["state"] = held["state"] + delta * unit["state"]
        gel.set_state(combined)
        gel.push_history()
        return delta

    def centre_pressure(self):
        _, _, p = ufl.split(self.gel.state)
        return integrate(p, self.ds(LEFT)) / self.b     # p is uniform in y in Mandel's solution


@pytest.mark.slow
def test_mandel_cryer_overshoot():
    """p(0, t*)/p0 against Mandel's series within 1 % of p0 for t* in [0.05, 1] (nu = 0.25).

    The quarter's plate carries F on the half width a, so the whole specimen
    carries 2F on its width 2a and p0 = F/(2a) (undrained plane strain with
    incompressible constituents: p0 is half the mean plate stress F/a).
    """
    q = MandelQuarter()
    G = PRM.phi_s0                                 # drained shear modulus (units of mu_s)
    lam = PRM.phi_s0 * PRM.lambda_s
    nu = lam / (2 * (lam + G))
    c = KAPPA * (lam + 2 * G)
    p0 = q.F / (2 * q.a)
    t_of = lambda ts: ts * q.a**2 / c   # noqa: E731
    q.gel.reset()
    q.gel.push_history()
    times = [0.05, 0.1, 0.2, 0.5, 1.0]
    # BDF2 with a fine first stretch: the undrained start has a layer at the drained side
    grid = np.concatenate([np.linspace(0.0, 0.05, 41)[1:], np.linspace(0.05, 1.0, 191)[1:]])
    t_prev, dt_prev, results = 0.0, None, {}
    for k, ts in enumerate(grid):
        dt = t_of(ts) - t_of(t_prev)
        q.step(dt, "be" if k == 0 else "bdf2", dt_prev)
        t_prev, dt_prev = ts, dt
        for target in times:
            if abs(ts - target) < 1e-9:
                results[target] = q.centre_pressure() / p0
    for ts in times:
        assert results[ts] == pytest.approx(mandel_pressure(0.0, ts, nu), abs=0.01), (ts, results)
    assert results[0.1] > 1.0          # the Mandel-Cryer overshoot itself
