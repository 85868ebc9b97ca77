"""Continuum kinematics and neo-Hookean stresses, scaled and free of cancellation (pure UFL).

One module for every solid and every moving domain: the cell (``cell.forms``),
the gel's network (``gel.forms``, ``gel.lagrangian``) and the fluid's mesh
motion (``fluid.ale``).

Units.  A displacement is ``d`` times its unknown, u = d u_hat (d the
displacement unit in units of L0); G = grad_X u_hat.  In two dimensions

    F = I + d G,         J = det F = 1 + d theta,    theta = tr G + d det G
    cof F = J F^-T = (1 + d tr G) I - d G^T,         adj F = J F^-1 = (cof F)^T

and in three (the characteristic polynomial of G: I1 = tr G,
I2 = ((tr G)^2 - tr G^2)/2, I3 = det G, and cof G = (G^2 - I1 G + I2 I)^T by
Cayley-Hamilton)

    theta = I1 + d (I2 + d I3),    cof F = I + d (I1 I - G^T) + d^2 cof G.

Both are written  theta = tr G + d q  and  cof F = I + d (tr G I - G^T) + d^2 C
with q = det G, C = 0 in 2D and q = I2 + d I3, C = cof G in 3D.

Nothing here subtracts two O(1) numbers to produce an O(d) one, so the same
expressions hold for d = Ca ~ 3e-10 (the device's unit Ca L0) and for d = 1.

Neo-Hookean law (model.md section 2, plane strain), stress in units of the
shear modulus mu_s of the material law it multiplies (mu = 1 for the gel's
network, whose modulus is the stress unit of the paper):

    sigma = mu J^-1 (F F^T - I) + lambda (J - 1) I                 (Cauchy)
    P     = J sigma F^-T = mu (F - F^-T) + lambda J (J - 1) F^-T     (first Piola-Kirchhoff)

derived from W = mu/2 (tr C - 2) - mu ln J + lambda/2 (J - 1)^2.  Scaled:

    sigma / d = mu (G + G^T + d G G^T) / J + lambda theta I
    P / d     = mu [G + G^T + d (q I + theta G - C)] / J + lambda theta cof F

(2D: q I - C = det G I).

Surfaces (Nanson's formula): a reference facet with unit normal N and length
dA is mapped to a current facet with unit normal n and length da,

    n da = cof F N dA,    j = da/dA = |cof F N|,   n = cof F N / j

In 2D cof F N = R F T for the unit tangent T = R^T N (R the rotation by 90
degrees), in 3D cof F N = (F T1) x (F T2) for unit tangents with T1 x T2 = N,
so j and n depend only on the derivatives of u ALONG the facet: the two sides
of an interface whose displacements share their trace agree on them.
"""

from __future__ import annotations

import ufl

__all__ = ["kinematics", "cofactor", "adjugate", "neo_hookean_cauchy", "neo_hookean_piola",
           "green_lagrange", "spatial_gradient", "surface_stretch"]


def _higher_order(G, d):
    """``(q, C)``: theta = tr G + d q and cof F = I + d (tr G I - G^T) + d^2 C (C None in 2D)."""
    if G.ufl_shape == (2, 2):
        return ufl.det(G), None
    I2 = 0.5 * (ufl.tr(G)**2 - ufl.tr(G * G))
    cof_G = (G * G - ufl.tr(G) * G + I2 * ufl.Identity(3)).T
    return I2 + d * ufl.det(G), cof_G


def kinematics(u, d):
    """``(G, theta, J)`` with G = grad u_hat, theta = (J - 1)/d = tr G + d q, J = det(I + d G)."""
    G = ufl.grad(u)
    theta = ufl.tr(G) + d * _higher_order(G, d)[0]
    return G, theta, 1 + d * theta


def _cofactor(G, d):
    """cof F = I + d (tr G I - G^T) [+ d^2 cof G in 3D]."""
    I = ufl.Identity(G.ufl_shape[0])
    cof = I + d * (ufl.tr(G) * I - G.T)
    C = _higher_order(G, d)[1]
    return cof if C is None else cof + d**2 * C


def cofactor(u, d):
    """cof F = J F^-T: I + d (tr G I - G^T) in 2D, plus d^2 cof G in 3D."""
    return _cofactor(ufl.grad(u), d)


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
    """P / d = mu [G + G^T + d (q I + theta G - C)] / J + lambda theta cof F  (``mu=None``: mu = 1)."""
    G, theta, J = kinematics(u, d)
    I = ufl.Identity(len(u))
    q, C = _higher_order(G, d)
    shear = G + G.T + d * (q * I + theta * G if C is None else q * I + theta * G - C)
    return (shear if mu is None else mu * shear) / J + lmbda * theta * _cofactor(G, d)


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
