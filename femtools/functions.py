"""Global reductions and small UFL helpers shared by the field solvers."""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import fem

from femtools import continuum, jitcache

# every field solver and the monolithic reference import this module after dolfinx (and so ffcx)
jitcache.install()

__all__ = ["integrate", "owned_values", "global_max", "interpolate", "von_mises",
           "green_lagrange", "quadrature_measure"]


def integrate(expr, measure, comm: MPI.Comm | None = None) -> float:
    """Integral of a scalar UFL expression, summed over all ranks."""
    form = fem.form(expr * measure)
    comm = comm or form.mesh.comm
    return comm.allreduce(fem.assemble_scalar(form), op=MPI.SUM)


def owned_values(u: fem.Function) -> np.ndarray:
    """Owned nodal values of ``u`` as ``(n_owned, bs)``."""
    imap, bs = u.function_space.dofmap.index_map, u.function_space.dofmap.index_map_bs
    return u.x.array[: imap.size_local * bs].reshape(-1, bs)


def global_max(values: np.ndarray, comm: MPI.Comm) -> float:
    """Maximum of a local array over all ranks (``-inf`` if empty everywhere)."""
    local = float(np.max(values)) if np.size(values) else -np.inf
    return comm.allreduce(local, op=MPI.MAX)


def interpolate(expr, V: fem.FunctionSpace, name: str | None = None) -> fem.Function:
    """Interpolate a UFL expression into ``V`` (at its interpolation points)."""
    f = fem.Function(V, name=name) if name else fem.Function(V)
    f.interpolate(fem.Expression(expr, V.element.interpolation_points()))
    f.x.scatter_forward()
    return f


def von_mises(s):
    """2D von Mises measure of a 2x2 tensor: sqrt(sxx^2 + syy^2 - sxx syy + 3 sxy^2)."""
    return ufl.sqrt(s[0, 0]**2 + s[1, 1]**2 - s[0, 0]*s[1, 1] + 3*s[0, 1]**2)


def green_lagrange(u, scale=1.0):
    """E = (F^T F - I)/2 of the displacement ``scale*u``, written without cancellation."""
    return continuum.green_lagrange(u, scale)


def quadrature_measure(kind: str, msh, subdomain_data=None, degree: int = 4):
    """A UFL measure with a fixed quadrature degree.

    Fixing the degree makes the partitioned and the monolithic assemblies use
    the same quadrature for the nonlinear terms, whose estimated degree would
    otherwise differ between the two.
    """
    return ufl.Measure(kind, domain=msh, subdomain_data=subdomain_data,
                       metadata={"quadrature_degree": degree})
