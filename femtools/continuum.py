"""Continuum kinematics and neo-Hookean stresses, scaled and free of cancellation (pure UFL).

One module for every solid and every moving domain: the cell (``cell.forms``),
the gel's network (``gel.forms``, ``gel.lagrangian``) and the fluid's mesh
motion (``fluid.ale``).

Units.  A displacement is ``d`` times its unknown, u = d u_hat (d the
displacement unit in units of L0); G = grad_X u_hat, with the invariants
I1 = tr G, I2 = ((tr G)^2 - tr(G G))/2 and I3 = det G.  In two dimensions

    F = I + d G,         J = det F = 1 + d theta,    theta = tr G + d det G
    cof F = J F^-T = (1 + d tr G) I - d G^T,         adj F = J F^-1 = (cof F)^T

and in three (Cayley-Hamilton: cof G = (G^T)^2 - I1 G^T + I2 I)

    theta = I1 + d I2 + d^2 I3,     cof F = I + d (I1 I - G^T) + d^2 cof G

Nothing here subtracts two O(1) numbers to produce an O(d) one, so the same
expressions hold for d = Ca ~ 3e-10 (the device's unit Ca L0) and for d = 1.

Neo-Hookean law (model.md section 2, plane strain or 3D), stress in units of the
shear modulus mu_s of the material law it multiplies (mu = 1 for the gel's
network, whose modulus is the stress unit of the paper):

    sigma = mu J^-1 (F F^T - I) + lambda (J - 1) I                 (Cauchy)
    P     = J sigma F^-T = mu (F - F^-T) + lambda J (J - 1) F^-T     (first Piola-Kirchhoff)

derived from W = mu/2 (tr C - 2) - mu ln J + lambda/2 (J - 1)^2.  Scaled:

    sigma / d = mu (G + G^T + d G G^T) / J + lambda theta I
    P / d     = mu [G + G^T + d (det G I + theta G)] / J + lambda theta cof F               (2D)
    P / d     = mu [G + G^T + d ((I2 + d I3) I + theta G - cof G)] / J + lambda theta cof F     (3D)

(P = mu (J F - cof F)/J + lambda (J - 1) cof F, with J F - cof F expanded in d).

Surfaces (Nanson's formula): a reference facet with unit normal N and length
dA is mapped to a current facet with unit normal n and length da,

    n da = cof F N dA,    j = da/dA = |cof F N|,   n = cof F N / j

In 2D cof F N = R F T for the unit tangent T = R^T N (R the rotation by 90
degrees), and in 3D cof F N = F T1 x F T2 for unit tangents with T1 x T2 = N,
so j and n depend only on the derivatives of u ALONG the facet: the two sides
of an interface whose displacements share their trace agree on them.
"""

from __future__ import annotations

import ufl

__all__ = ["kinematics", "cofactor", "adjugate", "neo_hookean_cauchy", "neo_hookean_piola",
           "green_lagrange", "spatial_gradient", "surface_stretch"]


def _second_invariant(G):
    """I2 = ((tr G)^2 - tr(G G)) / 2 (the sum of the principal 2x2 minors of G)."""
    return 0.5 * (ufl.tr(G)**2 - ufl.tr(G * G))


def _cofactor_of(G):
    """cof G = det(G) G^-T of a 3x3 tensor, (G^T)^2 - I1 G^T + I2 I (Cayley-Hamilton; no inverse)."""
    return G.T * G.T - ufl.tr(G) * G.T + _second_invariant(G) * ufl.Identity(3)


def kinematics(u, d):
    """``(G, theta, J)`` with G = grad u_hat, J = det(I + d G) = 1 + d theta,
    theta = tr G + d det G (2D) or tr G + d I2 + d^2 det G (3D)."""
    G = ufl.grad(u)
    if len(u) == 2:
        theta = ufl.tr(G) + d * ufl.det(G)
    else:
        theta = ufl.tr(G) + d * (_second_invariant(G) + d * ufl.det(G))
    return G, theta, 1 + d * theta


def cofactor(u, d):
    """cof F = J F^-T: I + d (tr G I - G^T) in 2D, plus d^2 cof G in 3D."""
    G = ufl.grad(u)
    I = ufl.Identity(len(u))
    linear = I + d * (ufl.tr(G) * I - G.T)
    return linear if len(u) == 2 else linear + d**2 * _cofactor_of(G)


def adjugate(u, d):
    """adj F = J F^-1 = (cof F)^T."""
    return cofactor(u, d).T


def neo_hookean_cauchy(u, mu, lmbda, d):
    """sigma / d = mu (G + G^T + d G G^T) / J + lambda theta I  (``mu=None``: mu = 1)."""
    G, theta, J = kinematics(u, d)
    I = ufl.Identity(len(u))
    shear = G + G.T + d * G * G.T
    return (shear if mu is None else mu * shear) / J + lmbda * theta * I


def neo_hookean_piola(u, mu, lmbda, d):
    """P / d = mu [G + G^T + d (det G I + theta G)] / J + lambda theta cof F in 2D; in 3D
    mu [G + G^T + d ((I2 + d det G) I + theta G - cof G)] / J + lambda theta cof F
    (``mu=None``: mu = 1)."""
    G, theta, J = kinematics(u, d)
    I = ufl.Identity(len(u))
    cof = cofactor(u, d)
    if len(u) == 2:
        shear = G + G.T + d * (ufl.det(G) * I + theta * G)
    else:
        shear = G + G.T + d * ((_second_invariant(G) + d * ufl.det(G)) * I + theta * G - _cofactor_of(G))
    return (shear if mu is None else mu * shear) / J + lmbda * theta * cof


def green_lagrange(u, d):
    """Green-Lagrange strain E = (F^T F - I)/2 of u = d u_hat (dimensionless), without cancellation."""
    H = d * ufl.grad(u)
    return 0.5 * (H + H.T + H.T * H)


def spatial_gradient(v, u, d):
    """grad_x v = grad_X v F^-1 = grad_X v adj F / J of a field v on the reference configuration."""
    _, _, J = kinematics(u, d)
    return ufl.grad(v) * adjugate(u, d) / J


def surface_stretch(u, d, N):
    """``(j, n)``: the length ratio da/dA = |cof F N| and the current unit normal cof F N / j."""
    m = ufl.dot(cofactor(u, d), N)
    j = ufl.sqrt(ufl.dot(m, m))
    return j, m / j
