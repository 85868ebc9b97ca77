"""Weak form of the neo-Hookean cell (pure UFL, shared with the monolithic reference).

Cauchy stress (model.md section 2), plane strain in 2D, and the same law in 3D:

    sigma_c = mu_c J^-1 (F F^T - I) + lambda_c (J - 1) I,   F = I + grad u_c

It derives from  W = mu_c/2 (tr C - n) - mu_c ln J + lambda_c/2 (J - 1)^2 (n = 2 or 3),
with first Piola-Kirchhoff stress  P = J sigma F^-T = mu_c (F - F^-T) + lambda_c J (J - 1) F^-T.
The cell is solved in the total Lagrangian form  int P : grad v dX = int t0 . v dS.

Units: stresses in a unit ``s`` and displacements in a unit ``d`` (both in
units of the paper's scales); u_c = d u_hat.  With G = grad u_hat,
theta = (J - 1)/d and cof F = J F^-T (2D: theta = tr G + d det G, cof F = I + d (tr G I - G^T);
3D: ``femtools.continuum``):

    P / s = (d/s) { mu_c (J F - cof F) / (d J) + lambda_c theta cof F }
    (2D: (J F - cof F)/d = G + G^T + d (det G I + theta G))

free of cancellation however small d is (d = s = Ca in the device runs).
The kinematics and the neo-Hookean stresses are ``femtools.continuum``'s,
shared with the gel's network.
"""

from __future__ import annotations

import ufl

from femtools.continuum import green_lagrange, kinematics, neo_hookean_cauchy, neo_hookean_piola

__all__ = ["kinematics", "first_piola", "cauchy_stress", "green_lagrange", "residual"]


def first_piola(u, mu, lmbda, d, s):
    """Scaled first Piola-Kirchhoff stress P / s (``femtools.continuum.neo_hookean_piola``)."""
    return (d / s) * neo_hookean_piola(u, mu, lmbda, d)


def cauchy_stress(u, mu, lmbda, d, s):
    """Scaled Cauchy stress sigma_c / s = (d/s) [mu (G + G^T + d G G^T) / J + lambda theta I]."""
    return (d / s) * neo_hookean_cauchy(u, mu, lmbda, d)


def residual(u, v, mu, lmbda, d, s, dx):
    """Total Lagrangian residual  int P/s : grad v dX  (boundary loads added by the caller).

    At a solution it equals the nodal reaction forces exerted ON the cell
    by whatever holds its Dirichlet boundary.
    """
    return ufl.inner(first_piola(u, mu, lmbda, d, s), ufl.grad(v)) * dx
