"""Weak forms of steady Stokes flow (pure UFL, shared with the monolithic reference).

Dimensionless Stokes equations (model.md section 2), in any stress unit:

    -div(Sigma - P I) = f,   div V = 0,   Sigma = mu (grad V + grad V^T)

with ``mu`` the viscosity in that stress unit (``Ca`` in units of the network
shear modulus, 1 in the viscous unit mu V0 / L0).
"""

from __future__ import annotations

import ufl

__all__ = ["strain_rate", "cauchy_stress", "bulk_residual", "robin_residual"]


def strain_rate(V):
    """D(V) = (grad V + grad V^T) / 2."""
    return ufl.sym(ufl.grad(V))


def cauchy_stress(V, P, viscosity):
    """Sigma - P I = 2 mu D(V) - P I."""
    return 2 * viscosity * strain_rate(V) - P * ufl.Identity(len(V))


def bulk_residual(V, P, v, q, viscosity, dx, body_force=None):
    """Bulk Stokes residual  int 2 mu D(V):D(v) - P div v - q div V - f.v dx.

    At a solution it equals  int_boundary t . v ds  with t = (Sigma - P I) n the
    traction exerted ON the fluid (n the fluid's outward normal): this is the
    consistent ("reaction") traction the solver returns.
    """
    r = (2 * viscosity * ufl.inner(strain_rate(V), strain_rate(v))
         - P * ufl.div(v) - q * ufl.div(V)) * dx
    if body_force is not None:
        r -= ufl.inner(body_force, v) * dx
    return r


def robin_residual(V, v, n, alpha_n, alpha_t, g_normal, g_tangential, ds):
    """Robin interface terms for  t.n + a_n V.n = g_N.n  and  t_tau + a_t V_tau = g_T,tau.

    ``t`` is the traction on the fluid and ``n`` its outward normal; the
    tangential parts are written without a tangent vector (w_tau = w - (w.n) n),
    so curved interfaces need nothing special.  a = 0 gives a traction
    (Neumann) condition.  Added to the bulk residual it yields

        bulk + int a_n (V.n)(v.n) + a_t V_tau.v_tau - (g_N.n)(v.n) - g_T,tau.v_tau ds = 0.
    """
    Vn, vn = ufl.dot(V, n), ufl.dot(v, n)
    Vt, vt = V - Vn * n, v - vn * n
    return (alpha_n * Vn * vn + alpha_t * ufl.dot(Vt, vt)
            - ufl.dot(g_normal, n) * vn - ufl.dot(g_tangential, vt)) * ds
