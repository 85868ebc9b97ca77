"""Weak forms of the poroelastic gel (pure UFL, shared with the monolithic reference).

Fields: interstitial fluid velocity v_f, network displacement u (u_s) and
velocity v_s = du_s/dt, pore pressure p.  Model.md sections 2 and 8
(quasi-static: no inertia):

    div(phi_s v_s + phi_f v_f) = 0                                        (G2)
    div(phi_f sigma_f) - phi_f grad p + xi Ca phi_f phi_s (v_s - v_f) = 0   (G3)
    div(phi_f sigma_f + phi_s sigma_s - p I) = 0              (G3 + G4, mixture)
    sigma_f = Ca (grad v_f + grad v_f^T)
    sigma_s = J^-1 (F F^T - I) + lambda_s (J - 1) I,   F = I + grad u_s
    phi_s = phi_s0 / J  (G1 in Lagrangian form),  phi_f = 1 - phi_s

The forms are dimension-independent: the same UFL serves triangles (2D, plane
strain) and tetrahedra (3D); only ``femtools.continuum`` tells J and cof F apart.

Every form takes v_f and v_s as UFL expressions; ``v_s=None`` is the steady
state (v_s = 0).  The solvers' unknown is the relative velocity
w = v_f - v_s (v_f = w + v_s), so that v_f = v_s on the cell (Gamma2) and
v_f = v_s = 0 on the anchored walls are homogeneous Dirichlet conditions;
v_s is the time-discrete derivative of u (gel.solver: backward Euler, BDF2).

Steady reference-configuration approximation: the equations are posed on the
undeformed domain (gradients with respect to X, no mesh motion); the
geometric terms this drops are of relative size max|F - I|.

Units.  Lengths in L0, velocities in V0; stresses in a unit ``s`` (in units
of mu_s) and displacements in a unit ``d`` (in units of L0): u_s = d u_hat,
sigma = s sigma_hat.  With G = grad u_hat, theta = tr G + d det G:

    J = 1 + d theta
    sigma_hat_s = (d/s) [ (G + G^T + d G G^T) / J + lambda_s theta I ]
    sigma_hat_f = (Ca/s) (grad v_f + grad v_f^T)

which contains no cancellation however small d is.  The device runs use
s = d = Ca (stress unit mu V0/L0, displacement unit Ca L0); s = d = 1 is the
paper's unscaled form.

Weak form (test functions w for v_f, z for u, q for p), n the gel's outward
normal:

    R_w = int phi_f sigma_f : grad w - p div(phi_f w) + (Ca/s) xi phi_f phi_s (v_f - v_s).w dx
          - int phi_f (sigma_f - p I) n . w ds
    R_z = int (phi_f sigma_f + phi_s sigma_s) : grad z - p div z dx - int T . z ds
    R_q = - int q div(phi_f v_f + phi_s v_s) dx

where T = (phi_f sigma_f + phi_s sigma_s - p I) n is the total traction.
"""

from __future__ import annotations

import dataclasses

import ufl

from femtools.continuum import kinematics, neo_hookean_cauchy

__all__ = ["GelCoefficients", "kinematics", "solid_fraction", "network_stress",
           "fluid_stress", "total_stress", "relative_velocity", "mixture_flux", "fluid_phase_residual",
           "mixture_residual", "mass_residual", "bulk_residual", "fluid_interface_residual"]


@dataclasses.dataclass
class GelCoefficients:
    """The coefficients of the gel forms, as UFL objects (usually ``fem.Constant``).

    Attributes:
        phi_s0: reference solid volume fraction.
        xi: drag coefficient (dimensionless, xi L0^2 / mu).
        lambda_s: network Lame modulus in units of the network shear modulus.
        beta: slip coefficient of I16/I17 (beta mu / L0).
        eta: interfacial permeability coefficient of I15 (mu eta / L0).
        viscosity: Ca / s, the fluid viscosity in the stress unit s.
        stiffness: d / s, the network shear modulus times d, in the stress unit s.
        d: displacement unit in units of L0.
    """

    phi_s0: object
    xi: object
    lambda_s: object
    beta: object
    eta: object
    viscosity: object
    stiffness: object
    d: object


def solid_fraction(u, c: GelCoefficients):
    """phi_s = phi_s0 / J."""
    return c.phi_s0 / kinematics(u, c.d)[2]


def network_stress(u, c: GelCoefficients):
    """Scaled Cauchy stress of the neo-Hookean network, sigma_s / s (``femtools.continuum``)."""
    return c.stiffness * neo_hookean_cauchy(u, None, c.lambda_s, c.d)


def fluid_stress(v_f, c: GelCoefficients):
    """Scaled viscous stress of the interstitial fluid, sigma_f / s."""
    return c.viscosity * (ufl.grad(v_f) + ufl.grad(v_f).T)


def total_stress(v_f, u, p, c: GelCoefficients):
    """Scaled total (mixture) stress phi_f sigma_f + phi_s sigma_s - p I."""
    phi_s = solid_fraction(u, c)
    return (1 - phi_s) * fluid_stress(v_f, c) + phi_s * network_stress(u, c) - p * ufl.Identity(len(u))


def relative_velocity(v_f, v_s):
    """v_f - v_s (v_f itself in the steady state, ``v_s=None``)."""
    return v_f if v_s is None else v_f - v_s


def fluid_phase_residual(v_f, u, p, w, c: GelCoefficients, dx, v_s=None):
    """R_w without boundary terms: the fluid-phase momentum balance (G3) tested with w."""
    phi_s = solid_fraction(u, c)
    phi_f = 1 - phi_s
    return (phi_f * ufl.inner(fluid_stress(v_f, c), ufl.grad(w)) - p * ufl.div(phi_f * w)
            + c.viscosity * c.xi * phi_f * phi_s * ufl.dot(relative_velocity(v_f, v_s), w)) * dx


def mixture_residual(v_f, u, p, z, c: GelCoefficients, dx):
    """R_z without boundary terms: the mixture momentum balance (G3 + G4) tested with z."""
    phi_s = solid_fraction(u, c)
    return (ufl.inner((1 - phi_s) * fluid_stress(v_f, c) + phi_s * network_stress(u, c), ufl.grad(z))
            - p * ufl.div(z)) * dx


def mixture_flux(v_f, u, c: GelCoefficients, v_s=None):
    """phi_f v_f + phi_s v_s: the volume-averaged velocity of the mixture (phi_f v_f if steady)."""
    phi_s = solid_fraction(u, c)
    flux = (1 - phi_s) * v_f
    return flux if v_s is None else flux + phi_s * v_s


def mass_residual(v_f, u, q, c: GelCoefficients, dx, v_s=None):
    """R_q: the volume balance (G2) tested with q."""
    return -q * ufl.div(mixture_flux(v_f, u, c, v_s)) * dx


def bulk_residual(v_f, u, p, w, z, q, c: GelCoefficients, dx, body_forces=None, v_s=None):
    """R_w + R_z + R_q without boundary terms (see the module docstring).

    ``body_forces`` = optional ``(f_w, f_z, f_q)`` UFL expressions subtracted
    as ``f_w.w + f_z.z + f_q q`` (manufactured solutions); ``v_s`` the
    network velocity (``None``: steady).
    """
    r = (fluid_phase_residual(v_f, u, p, w, c, dx, v_s) + mixture_residual(v_f, u, p, z, c, dx)
         + mass_residual(v_f, u, q, c, dx, v_s))
    if body_forces is not None:
        f_w, f_z, f_q = body_forces
        r -= (ufl.dot(f_w, w) + ufl.dot(f_z, z) + f_q * q) * dx
    return r


def fluid_interface_residual(v_f, u, w, z, T, V, n, c: GelCoefficients, ds, v_s=None):
    """Boundary terms on a fluid-gel interface (Gamma1, Gamma3).

    The gel enforces (I14) both components, (I15) and (I17) given the fluid's
    traction on the gel ``T`` = (Sigma - P I) n and velocity ``V``:

        mixture (z):      T_total = T                                         (I14)
        fluid phase (w):  phi_f (sigma_f - p I) n . n = phi_f T.n + phi_s (Ca/eta) (V - v_f).n
                          phi_f sigma_f n . t         = T.t - (Ca phi_s^2 / beta) (v_f - v_s).t

    (the fluid-phase partial traction follows from I14 with I15 for the
    normal and I17 for the tangential part).  Returned as a residual to add
    to ``bulk_residual``.
    """
    phi_s = solid_fraction(u, c)
    k_n = c.viscosity * phi_s / c.eta
    k_t = c.viscosity * phi_s**2 / c.beta
    rel = relative_velocity(v_f, v_s)
    wn, Tn = ufl.dot(w, n), ufl.dot(T, n)
    partial_traction_w = ((1 - phi_s) * Tn * wn + ufl.dot(T, w - wn * n)
                          + k_n * ufl.dot(V - v_f, n) * wn - k_t * ufl.dot(rel - ufl.dot(rel, n) * n, w - wn * n))
    return -(partial_traction_w + ufl.dot(T, z)) * ds
