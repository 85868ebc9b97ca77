"""Nodes of a Lagrange space on an interface, in an order every rank agrees on.

Interface data leave a field solver as plain arrays of shape ``(N, bs)`` over
the interface nodes, replicated on every rank and sorted lexicographically by
coordinates.  The order therefore depends neither on the partition nor on the
rank count, and two region meshes cut from one gmsh model list the nodes of
a shared interface in the same order.
"""

from __future__ import annotations

import typing

import numpy as np
import scipy.spatial

from mpi4py import MPI

from dolfinx import fem

__all__ = ["InterfaceNodes"]


class InterfaceNodes:
    """The nodes of a collapsed Lagrange space ``V`` on the facets tagged ``tags``.

    Args:
        V: a (collapsed) scalar or vector Lagrange space.
        facet_tags: facet tags of ``V.mesh``.
        tags: the tag value(s) of the interface facets.
        parent_dofs: optional map from ``V``'s unrolled dofs to the dofs of a
            parent (mixed) space, as returned by ``W.sub(i).collapse()[1]``.

    Attributes:
        points: ``(N, gdim)`` coordinates, replicated, sorted by (x, y).
        local_blocks: local block (node) indices of ``V`` on the interface,
            owned and ghost.
        index: row of ``points`` for each entry of ``local_blocks``.
        owned: mask of ``local_blocks`` owned by this rank.
    """

    def __init__(self, V: fem.FunctionSpace, facet_tags, tags: typing.Iterable[int] | int,
                 parent_dofs: typing.Sequence[int] | None = None):
        msh = V.mesh
        self.comm: MPI.Comm = msh.comm
        self.tags = [int(tags)] if np.isscalar(tags) else [int(t) for t in tags]
        gdim = msh.geometry.dim
        fdim = msh.topology.dim - 1
        facets = np.unique(np.hstack([facet_tags.find(t) for t in self.tags]).astype(np.int32))
        blocks = fem.locate_dofs_topological(V, fdim, facets)
        n_owned = V.dofmap.index_map.size_local
        self.bs = V.dofmap.index_map_bs
        coords = V.tabulate_dof_coordinates()[blocks, :gdim]
        owned = blocks < n_owned
        points = np.vstack(self.comm.allgather(coords[owned])) if self.comm.size > 1 else coords[owned]
        if points.shape[0] == 0:
            raise ValueError(f"no facets with tag(s) {self.tags} in this mesh")
        # sort on coordinates rounded to 1e-10 (relative): tabulated P2 node coordinates carry
        # cell-dependent rounding noise (x = -6e-19 or +5e-18 on the line x = 0), which must
        # not decide the order, or it changes with the partition
        tol = 1e-10 * (1.0 + np.abs(points).max())
        order = np.lexsort(np.round(points / tol).T[::-1])
        self.points = np.ascontiguousarray(points[order])
        dist, index = scipy.spatial.cKDTree(self.points).query(coords)
        if coords.shape[0] and dist.max() > 1e-12 * (1 + np.abs(self.points).max()):
            raise RuntimeError("interface node of a ghost cell not found among the owned nodes")
        self.local_blocks = blocks.astype(np.int32)
        self.index = index.astype(np.int64)
        self.owned = owned
        self._parent = None if parent_dofs is None else np.asarray(parent_dofs, dtype=np.int32)

    @property
    def size(self) -> int:
        """Number of interface nodes (global)."""
        return self.points.shape[0]

    def dofs(self, component: int | None = None, parent: bool = False) -> np.ndarray:
        """Local unrolled dofs (owned and ghost), ``(n_local, bs)`` or one component."""
        d = self.local_blocks[:, None] * self.bs + np.arange(self.bs)[None, :]
        if parent:
            if self._parent is None:
                raise ValueError("no parent dof map was given")
            d = self._parent[d]
        return d if component is None else d[:, component]

    def gather(self, local_values: np.ndarray) -> np.ndarray:
        """Replicated ``(N, bs)`` array from values given at ``local_blocks`` (owned rows used)."""
        local_values = np.asarray(local_values)
        if local_values.ndim != 2:
            # a rank without interface nodes has size 0: reshape(0, -1) is ambiguous
            local_values = local_values.reshape(len(self.local_blocks), -1 if local_values.size else self.bs)
        out = np.zeros((self.size, local_values.shape[1]))
        idx, vals = self.index[self.owned], local_values[self.owned]
        if self.comm.size > 1:
            idx = np.hstack(self.comm.allgather(idx))
            vals = np.vstack(self.comm.allgather(vals))
        out[idx] = vals
        return out

    def from_array(self, array: np.ndarray, parent: bool = False) -> np.ndarray:
        """Gather the interface rows of a local dof array (``Function.x.array`` or a PETSc ``Vec.array``).

        Only owned rows are read, so a PETSc vector holding owned entries only is fine.
        """
        d = self.dofs(parent=parent)
        local = np.zeros(d.shape)
        local[self.owned] = np.asarray(array)[d[self.owned]]
        return self.gather(local)

    def from_function(self, u: fem.Function) -> np.ndarray:
        """Values of ``u`` (a function on ``V``) at the interface nodes, ``(N, bs)``."""
        return self.from_array(u.x.array)

    def to_array(self, values: np.ndarray, array: np.ndarray, parent: bool = False) -> None:
        """Write replicated ``values`` ``(N, bs)`` into a local dof array, owned and ghost rows."""
        values = np.asarray(values, dtype=float).reshape(self.size, -1)
        if values.shape[1] != self.bs:
            raise ValueError(f"interface data have {values.shape[1]} components, the space has {self.bs}")
        array[self.dofs(parent=parent)] = values[self.index]

    def to_function(self, values: np.ndarray, u: fem.Function) -> None:
        """Set ``u`` at the interface nodes (owned and ghost) from replicated ``values``."""
        self.to_array(values, u.x.array)
