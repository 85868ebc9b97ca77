"""Weak forms of the poroelastic gel in total Lagrangian form (pure UFL; finite strain).

The model of ``gel.forms`` (model.md sections 2, 3, 8 and 9), posed on the
reference (undeformed) configuration without dropping any geometric term.
Derivation: docs/finite-strain.md.  X is the reference position, x = X + u_s
the current one, F = I + grad_X u_s, J = det F, and (femtools.continuum)

    cof F = J F^-T,   adj F = J F^-1,   grad_x a = grad_X a F^-1,
    dv = J dX,        n da = cof F N dA   (Nanson; j = da/dA, n the current normal).

Unknowns are those of ``gel.forms``: the relative velocity w = v_f - v_s of the
interstitial fluid (a spatial vector, as a function of X), u_s and p; v_s is
the time-discrete rate of u_s (``femtools.timestepping``), ``None`` if steady.

    mixture   (G3 + G4):  int P : grad_X z dX - (boundary) = 0,
              P = J (phi_f sigma_f + phi_s sigma_s - p I) F^-T
                = phi_s J sigma_s F^-T + phi_f sigma_f cof F - p cof F
    fluid phase (G3):     int J [phi_f sigma_f : grad_x w - p div_x(phi_f w)
                                 + xi Ca phi_f phi_s (v_f - v_s).w] dX - (boundary) = 0
                          = int phi_f sigma_f : (grad_X w adj F) - p grad_X(phi_f w) : cof F
                                 + xi Ca phi_f phi_s0 (v_f - v_s).w dX
    mass (G1 + G2):       - int q [dJ/dt + Div_X(phi_f adj F (v_f - v_s))] dX = 0

with phi_s = phi_s0/J (G1, the solid's mass, exactly), phi_f = 1 - phi_s,
sigma_s the neo-Hookean Cauchy stress and sigma_f = Ca (grad_x v_f + grad_x v_f^T),
whose gradient is spatial.  The mass balance is G2 multiplied by J:
J div_x(v_s + phi_f (v_f - v_s)) = dJ/dt + Div_X(J F^-1 phi_f (v_f - v_s)) (Piola
identity): the relative flux is pulled back by the Piola transform J F^-1.
dJ/dt is discretised like v_s (the same backward Euler / BDF2 coefficients
applied to J, so the gel's discrete volume obeys the same recursion as its
displacement); ``volume_rate``.  The Piola-transformed divergence is assembled
as grad_X(phi_f w) : cof F, equal to Div_X(phi_f adj F w) element by element.

Units as in ``gel.forms``: stresses in s (times mu_s), displacements in d
(times L0), u = d u_hat; every expression is written with the scaled,
cancellation-free kinematics of ``femtools.continuum``.

Interface terms on Gamma1/Gamma3 (I14 with I15 and I17, the split of
model.md section 6) hold on the CURRENT interface.  The traction they take,
``T0``, is NOMINAL: the fluid's force per unit REFERENCE length, area in 3D (T0 = j T with
T = (Sigma - P I) n the Cauchy traction), which is what a consistent reaction
on the fixed reference mesh is.  Pulled back with da = j dA:

    mixture (z):       - int T0 . z dA                                       (I14)
    fluid phase (w):   - int phi_f (T0.n) w.n + T0_t . w_t
                            + j (Ca phi_s/eta) (V - v_f).n w.n
                            - j (Ca phi_s^2/beta) (v_f - v_s)_t . w_t dA      (I14 + I15, I14 + I17)

with n the current normal and a_t = a - (a.n) n.  At small strain (j = 1,
n = N, cof F = adj F = I) every form reduces to the corresponding one of
``gel.forms`` to first order in the strain.
"""

from __future__ import annotations

import ufl

from femtools.continuum import cofactor, adjugate, kinematics, neo_hookean_cauchy, neo_hookean_piola, \
    spatial_gradient, surface_stretch
from gel.forms import GelCoefficients, mixture_flux, relative_velocity, solid_fraction

__all__ = ["network_stress", "fluid_stress", "total_stress", "first_piola", "fluid_phase_residual",
           "mixture_residual", "mass_residual", "bulk_residual", "fluid_interface_residual", "volume_rate",
           "normal_flux_load", "solid_fraction", "mixture_flux"]


def network_stress(u, c: GelCoefficients):
    """Scaled Cauchy stress of the network, sigma_s / s (the same law as ``gel.forms``)."""
    return c.stiffness * neo_hookean_cauchy(u, None, c.lambda_s, c.d)


def fluid_stress(v_f, u, c: GelCoefficients):
    """Scaled viscous stress sigma_f / s = (Ca/s) (grad_x v_f + grad_x v_f^T), spatial gradient."""
    L = spatial_gradient(v_f, u, c.d)
    return c.viscosity * (L + L.T)


def total_stress(v_f, u, p, c: GelCoefficients):
    """Scaled total Cauchy stress phi_f sigma_f + phi_s sigma_s - p I."""
    phi_s = solid_fraction(u, c)
    return (1 - phi_s) * fluid_stress(v_f, u, c) + phi_s * network_stress(u, c) - p * ufl.Identity(len(u))


def first_piola(v_f, u, p, c: GelCoefficients):
    """Scaled first Piola stress of the total stress, J (phi_f sigma_f + phi_s sigma_s - p I) F^-T / s."""
    phi_s = solid_fraction(u, c)
    cof = cofactor(u, c.d)
    network = c.stiffness * neo_hookean_piola(u, None, c.lambda_s, c.d)       # J sigma_s F^-T / s
    return phi_s * network + ((1 - phi_s) * fluid_stress(v_f, u, c) - p * ufl.Identity(len(u))) * cof


def fluid_phase_residual(v_f, u, p, w, c: GelCoefficients, dx, v_s=None):
    """The fluid phase (G3) tested with w, pulled back (no boundary terms)."""
    phi_s = solid_fraction(u, c)
    phi_f = 1 - phi_s
    adj, cof = adjugate(u, c.d), cofactor(u, c.d)
    return (phi_f * ufl.inner(fluid_stress(v_f, u, c), ufl.grad(w) * adj)
            - p * ufl.inner(ufl.grad(phi_f * w), cof)
            + c.viscosity * c.xi * phi_f * c.phi_s0 * ufl.dot(relative_velocity(v_f, v_s), w)) * dx


def mixture_residual(v_f, u, p, z, c: GelCoefficients, dx):
    """The mixture balance (G3 + G4) tested with z: int P : grad_X z dX (no boundary terms)."""
    return ufl.inner(first_piola(v_f, u, p, c), ufl.grad(z)) * dx


def volume_rate(u, past, rate_coefficients, d):
    """dJ/dt by the scheme of v_s: (c0 theta(u) + c1 theta(u^n) + c2 theta(u^{n-1})) with J = 1 + d theta.

    ``past`` = [u^n, u^{n-1}] and ``rate_coefficients`` = (c0, c1, c2) of a
    ``femtools.timestepping.RateHistory`` (c_k = d a_k / dt; the a_k sum to
    zero, so the 1 of J = 1 + d theta cancels exactly).
    """
    thetas = [kinematics(f, d)[1] for f in (u, *past)]
    return sum(ck * th for ck, th in zip(rate_coefficients, thetas))


def mass_residual(v_f, u, q, c: GelCoefficients, dx, v_s=None, dJdt=None):
    """- int q [dJ/dt + grad_X(phi_f (v_f - v_s)) : cof F] dX (G2 times J; ``dJdt`` None: steady)."""
    phi_f = 1 - solid_fraction(u, c)
    flux = ufl.inner(ufl.grad(phi_f * relative_velocity(v_f, v_s)), cofactor(u, c.d))
    return -q * (flux if dJdt is None else dJdt + flux) * dx


def bulk_residual(v_f, u, p, w, z, q, c: GelCoefficients, dx, body_forces=None, v_s=None, dJdt=None):
    """R_w + R_z + R_q on the reference configuration, without boundary terms.

    ``body_forces`` = optional ``(f_w, f_z, f_q)``, loads per unit REFERENCE
    volume subtracted as ``f_w.w + f_z.z + f_q q`` (manufactured solutions);
    ``v_s`` and ``dJdt`` (``volume_rate``) the time-discrete rates (None: steady).
    """
    r = (fluid_phase_residual(v_f, u, p, w, c, dx, v_s) + mixture_residual(v_f, u, p, z, c, dx)
         + mass_residual(v_f, u, q, c, dx, v_s, dJdt))
    if body_forces is not None:
        f_w, f_z, f_q = body_forces
        r -= (ufl.dot(f_w, w) + ufl.dot(f_z, z) + f_q * q) * dx
    return r


def fluid_interface_residual(v_f, u, w, z, T0, V, N, c: GelCoefficients, ds, v_s=None):
    """Boundary terms on a fluid-gel interface on the current configuration (module docstring).

    ``T0`` is the fluid's NOMINAL traction on the gel (force per unit
    reference length or area), ``V`` the fluid velocity, ``N`` the reference outward
    normal of the gel (``ufl.FacetNormal``).
    """
    j, n = surface_stretch(u, c.d, N)
    phi_s = solid_fraction(u, c)
    k_n = c.viscosity * phi_s / c.eta
    k_t = c.viscosity * phi_s**2 / c.beta
    rel = relative_velocity(v_f, v_s)
    wn, Tn = ufl.dot(w, n), ufl.dot(T0, n)
    w_t = w - wn * n
    partial_traction_w = ((1 - phi_s) * Tn * wn + ufl.dot(T0, w_t)
                          + j * (k_n * ufl.dot(V - v_f, n) * wn - k_t * ufl.dot(rel - ufl.dot(rel, n) * n, w_t)))
    return -(partial_traction_w + ufl.dot(T0, z)) * ds


def normal_flux_load(v_f, u, s, N, c: GelCoefficients, ds, v_s=None):
    """int j (phi_f v_f + phi_s v_s).n (s.n) dA: the gel's volume flux through the current interface
    tested with s (nodal values: the consistent load with which the fluid enforces I13)."""
    j, n = surface_stretch(u, c.d, N)
    return j * ufl.dot(mixture_flux(v_f, u, c, v_s), n) * ufl.dot(s, n) * ds
