"""Global reductions and small UFL helpers shared by the field solvers."""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import fem, geometry, la

from femtools import continuum, jitcache

# every field solver and the monolithic reference import this module after dolfinx (and so ffcx)
jitcache.install()

#: the names ufl gives a (continuous) Lagrange family; a VectorElement reports its sub-element's
LAGRANGE_FAMILIES = ("Lagrange", "P", "CG", "Q")

__all__ = ["LAGRANGE_FAMILIES", "integrate", "gather_owned_rows", "owned_values", "global_max", "values_at_points",
           "interpolate",
           "set_function", "NodalAverage", "von_mises", "green_lagrange", "quadrature_measure"]


def integrate(expr, measure, comm: MPI.Comm | None = None) -> float:
    """Integral of a scalar UFL expression, summed over all ranks."""
    form = fem.form(expr * measure)
    comm = comm or form.mesh.comm
    return comm.allreduce(fem.assemble_scalar(form), op=MPI.SUM)


def gather_owned_rows(comm: MPI.Comm, start: int, rows: np.ndarray, total: int, root: int = 0) -> np.ndarray | None:
    """The rows ``rows`` of each rank, placed at its offset ``start`` in a ``total``-row array on ``root``.

    For owned entries of an index map (rank r owns the global indices
    [start_r, start_r + len(rows_r))): the global array in index order on
    ``root``, ``None`` on the other ranks.
    """
    parts = comm.gather((start, np.asarray(rows)), root=root)
    if comm.rank != root:
        return None
    out = np.zeros((total,) + parts[0][1].shape[1:], dtype=parts[0][1].dtype)
    for first, piece in parts:
        out[first:first + len(piece)] = piece
    return out


def owned_values(u: fem.Function) -> np.ndarray:
    """Owned nodal values of ``u`` as ``(n_owned, bs)``."""
    imap, bs = u.function_space.dofmap.index_map, u.function_space.dofmap.index_map_bs
    return u.x.array[: imap.size_local * bs].reshape(-1, bs)


def global_max(values: np.ndarray, comm: MPI.Comm) -> float:
    """Maximum of a local array over all ranks (``-inf`` if empty everywhere)."""
    local = float(np.max(values)) if np.size(values) else -np.inf
    return comm.allreduce(local, op=MPI.MAX)


def values_at_points(u: fem.Function, points: np.ndarray) -> np.ndarray:
    """Values of ``u`` at ``points`` (n x gdim, the same small set on every rank: probes, sections).

    Each point is evaluated by the lowest rank one of whose owned cells contains it, and the
    values summed over ranks, so every rank returns the same (n, value size) array; NaN where
    no cell contains the point.
    """
    msh, comm = u.function_space.mesh, u.function_space.mesh.comm
    x = np.zeros((len(points), 3))
    x[:, : np.shape(points)[1]] = points
    tdim = msh.topology.dim
    owned = np.arange(msh.topology.index_map(tdim).size_local, dtype=np.int32)
    tree = geometry.BoundingBoxTree(msh, tdim, owned)
    colliding = geometry.compute_colliding_cells(msh, geometry.compute_collisions(tree, x), x)
    cells = np.array([c[0] if len(c) else -1 for c in (colliding.links(i) for i in range(len(x)))], dtype=np.int32)
    size = int(np.prod(u.ufl_shape))
    owner = np.empty(len(x), dtype=np.int64)      # (a buffer reduction: the pickled MIN cannot take arrays)
    comm.Allreduce(np.where(cells >= 0, comm.rank, comm.size).astype(np.int64), owner, op=MPI.MIN)
    mine = (owner == comm.rank) & (cells >= 0)
    values = np.zeros((len(x), size))
    if mine.any():
        values[mine] = np.reshape(u.eval(x[mine], cells[mine]), (-1, size))
    values = comm.allreduce(values, op=MPI.SUM)
    values[owner == comm.size] = np.nan
    return values


def set_function(g: fem.Function, value, what: str) -> fem.Function:
    """Set ``g`` from a number (every component), one number per component, or a callable
    ``x -> values`` as for ``Function.interpolate``; returns ``g``.

    ``what`` names the input in the errors: ValueError for another size,
    FloatingPointError for NaN or Inf (boundary data, loads).
    """
    bs = g.function_space.dofmap.index_map_bs
    if callable(value):
        g.interpolate(value)
    else:
        try:
            val = np.asarray(value, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            val = None
        if val is None or val.size not in (1, bs):
            raise ValueError(f"{what}: must be a number, {bs} numbers or a callable x -> values, got {value!r}")
        g.x.array.reshape(-1, bs)[:] = val
    if not np.all(np.isfinite(g.x.array)):
        raise FloatingPointError(f"{what}: contains NaN or Inf")
    g.x.scatter_forward()
    return g


def interpolate(expr, V: fem.FunctionSpace, name: str | None = None) -> fem.Function:
    """Interpolate a UFL expression into ``V`` (at its interpolation points)."""
    f = fem.Function(V, name=name) if name else fem.Function(V)
    f.interpolate(fem.Expression(expr, V.element.interpolation_points()))
    f.x.scatter_forward()
    return f


def von_mises(s):
    """Von Mises measure of a symmetric tensor (model.md sections 2 and 10).

    2x2 (the paper's formula (8)): sqrt(sxx^2 + syy^2 - sxx syy + 3 sxy^2);
    3x3: sqrt(((sxx - syy)^2 + (syy - szz)^2 + (szz - sxx)^2)/2 + 3 (sxy^2 + syz^2 + szx^2)).
    """
    if s.ufl_shape == (2, 2):
        return ufl.sqrt(s[0, 0]**2 + s[1, 1]**2 - s[0, 0]*s[1, 1] + 3*s[0, 1]**2)
    if s.ufl_shape != (3, 3):
        raise ValueError(f"von_mises takes a 2x2 or 3x3 tensor, got shape {s.ufl_shape}")
    normal = (s[0, 0] - s[1, 1])**2 + (s[1, 1] - s[2, 2])**2 + (s[2, 2] - s[0, 0])**2
    return ufl.sqrt(0.5 * normal + 3 * (s[0, 1]**2 + s[1, 2]**2 + s[2, 0]**2))


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


class NodalAverage:
    """Nodal values of a cellwise (discontinuous) expression in a continuous Lagrange space ``V``.

    Interpolating such an expression straight into ``V`` leaves at each node
    shared by several cells the value of whichever cell comes last, which
    depends on the cell order and so on the partition.  Here every cell
    evaluates it at its own nodes (a discontinuous space of the same element,
    whose interpolation points are ``V``'s) and each node takes the mean over
    the cells around it, on any number of ranks:

        f(x_i) = (1/|K_i|) sum_{K in K_i} e|_K(x_i),   K_i the cells with node i.

    A continuous expression is reproduced exactly (every cell gives the same
    value).  ``expression`` arguments of ``__call__`` are ``fem.Expression``s
    compiled at ``V.element.interpolation_points()``.
    """

    def __init__(self, V: fem.FunctionSpace):
        msh = V.mesh
        family, degree = V.ufl_element().family(), V.ufl_element().degree()
        if V.dofmap.index_map_bs != 1 or family not in LAGRANGE_FAMILIES:
            raise ValueError(f"NodalAverage: V must be a scalar continuous Lagrange space, got {V.ufl_element()}")
        self.V = V
        self._cellwise = fem.Function(fem.FunctionSpace(msh, ("DG", degree)))
        n_cells = msh.topology.index_map(msh.topology.dim).size_local
        width = V.dofmap.dof_layout.num_dofs
        self._dofs = V.dofmap.list.array.reshape(-1, width)[:n_cells].ravel()
        self._cell_dofs = self._cellwise.function_space.dofmap.list.array.reshape(-1, width)[:n_cells].ravel()
        count = fem.Function(V)
        np.add.at(count.x.array, self._dofs, 1.0)
        count.x.scatter_reverse(la.ScatterMode.add)
        count.x.scatter_forward()
        self._count = count.x.array.copy()

    def __call__(self, expression: fem.Expression, out: fem.Function) -> fem.Function:
        """``out`` (a Function of ``V``) = the nodal mean of ``expression`` over the cells around each node."""
        self._cellwise.interpolate(expression)
        out.x.array[:] = 0.0
        np.add.at(out.x.array, self._dofs, self._cellwise.x.array[self._cell_dofs])
        out.x.scatter_reverse(la.ScatterMode.add)
        out.x.array[:] /= self._count
        out.x.scatter_forward()
        return out
