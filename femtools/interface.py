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
import scipy.sparse
import scipy.sparse.linalg
import scipy.spatial

from mpi4py import MPI

import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

from femtools.mesh import as_tags, tagged_facets

__all__ = ["InterfaceNodes", "InterfaceMass", "global_dofs"]


def global_dofs(space: fem.FunctionSpace, local: np.ndarray, bcs=()) -> np.ndarray:
    """Global unrolled indices of local unrolled dofs of ``space`` (any shape); -1 where ``bcs`` fix them."""
    imap, bs = space.dofmap.index_map, space.dofmap.index_map_bs
    local = np.asarray(local)
    glob = imap.local_to_global((local // bs).ravel().astype(np.int32)).reshape(local.shape) * bs + local % bs
    fixed = np.zeros((imap.size_local + imap.num_ghosts) * bs, dtype=bool)
    for bc in bcs:
        fixed[bc.dof_indices()[0]] = True
    return np.where(fixed[local], -1, glob)


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
        self.tags = as_tags(tags, "InterfaceNodes tags")
        gdim = msh.geometry.dim
        fdim = msh.topology.dim - 1
        facets = tagged_facets(facet_tags, self.tags)
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
        self._space, self._facets, self._triangles = V, facets, None

    @property
    def size(self) -> int:
        """Number of interface nodes (global)."""
        return self.points.shape[0]

    def triangles(self) -> np.ndarray:
        """``(M, 6)`` P2 triangles of a surface interface (3D), as indices into ``points``, replicated.

        Nodes in the order of :mod:`coupling.surface_mapping`: the corners
        ``v0, v1, v2``, then the nodes on the edges ``(v1, v2)``, ``(v0, v2)``,
        ``(v0, v1)``.  Only for a P2 space on tetrahedra (its facet nodes are
        exactly the six nodes of a quadratic triangle).
        """
        if self._triangles is None:
            self._triangles = self._facet_triangles()
        return self._triangles

    def _facet_triangles(self) -> np.ndarray:
        V = self._space
        msh, layout = V.mesh, V.dofmap.dof_layout
        tdim = msh.topology.dim
        if tdim != 3 or layout.num_entity_closure_dofs(tdim - 1) != 6:
            raise ValueError(f"interface triangles need a P2 space on tetrahedra (got a {tdim}D mesh with "
                             f"{layout.num_entity_closure_dofs(tdim - 1)} nodes per facet)")
        msh.topology.create_connectivity(tdim - 1, tdim)
        msh.topology.create_connectivity(tdim, tdim - 1)
        f2c, c2f = msh.topology.connectivity(tdim - 1, tdim), msh.topology.connectivity(tdim, tdim - 1)
        row = dict(zip(self.local_blocks.tolist(), self.index.tolist()))
        n_owned = msh.topology.index_map(tdim - 1).size_local
        tri = []
        for f in self._facets[self._facets < n_owned]:
            cell = f2c.links(f)[0]
            local = int(np.flatnonzero(c2f.links(cell) == f)[0])
            blocks = V.dofmap.cell_dofs(cell)[layout.entity_closure_dofs(tdim - 1, local)]
            tri.append([row[int(b)] for b in blocks])      # 3 corners, then 3 edge nodes
        tri = np.array(tri, dtype=np.int64).reshape(-1, 6)
        if self.comm.size > 1:
            tri = np.vstack(self.comm.allgather(tri))
        # each edge node to the edge (v1, v2), (v0, v2), (v0, v1) whose midpoint it is nearest
        x = self.points
        mid = 0.5 * (x[tri[:, [1, 0, 0]]] + x[tri[:, [2, 2, 1]]])               # (M, 3 edges, gdim)
        dist = np.linalg.norm(x[tri[:, 3:]][:, None, :, :] - mid[:, :, None, :], axis=3)  # edge, node
        order = np.argmin(dist, axis=2)
        edges = np.take_along_axis(tri[:, 3:], order, axis=1)
        return np.ascontiguousarray(np.hstack([tri[:, :3], edges]))

    def dofs(self, component: int | None = None, parent: bool = False) -> np.ndarray:
        """Local unrolled dofs (owned and ghost), ``(n_local, bs)`` or one component."""
        d = self.local_blocks[:, None] * self.bs + np.arange(self.bs)[None, :]
        if parent:
            if self._parent is None:
                raise ValueError("no parent dof map was given")
            d = self._parent[d]
        return d if component is None else d[:, component]

    def global_dofs(self, space: fem.FunctionSpace, parent: bool = False, bcs=()) -> np.ndarray:
        """``(N, bs)`` global unrolled dofs of the interface nodes in ``space``, replicated.

        ``space``: ``V`` itself, or with ``parent=True`` the parent (mixed) space of the
        ``parent_dofs`` map.  Dofs that a Dirichlet condition of ``bcs`` fixes are -1.
        """
        glob = global_dofs(space, self.dofs(parent=parent), bcs)
        # gathered as floats: exact for any dof count below 2**53
        return np.rint(self.gather(glob.astype(float))).astype(np.int64)

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


class InterfaceMass:
    """The mass matrix of a vector Lagrange space over an interface, on its nodes, and solves with it.

    ``M[(i, c), (j, c)] = int_Gamma phi_i phi_j ds`` over the interface facets of
    ``measure``, with rows and columns in the order of ``nodes`` (row ``bs i + c``),
    replicated on every rank.  ``solve(R)`` returns ``lambda`` (N, bs) with
    ``M_kk lambda_k = R_k`` on the kept components (``keep``, (N, bs) booleans)
    and ``lambda = 0`` on the others: an L2 projection onto the interface trace,
    e.g. of a reaction (nodal forces) to a traction.  The system has the size of
    the interface, not of the mesh; it is factorised once (sparse LU).
    """

    def __init__(self, nodes: InterfaceNodes, V: fem.FunctionSpace, measure, keep: np.ndarray):
        comm, bs, n = nodes.comm, nodes.bs, nodes.size
        lam, s = ufl.TrialFunction(V), ufl.TestFunction(V)
        A = fem_petsc.assemble_matrix(fem.form(ufl.inner(lam, s) * measure))
        A.assemble()
        imap = V.dofmap.index_map
        comps = np.arange(bs)
        # global (unrolled) index of every local interface dof, and its row in the interface vector
        glob = (imap.local_to_global(nodes.local_blocks).astype(np.int64)[:, None] * bs + comps).ravel()
        row = (nodes.index[:, None] * bs + comps).ravel()
        keys, rows = (np.hstack(comm.allgather(x)) for x in (glob, row)) if comm.size > 1 else (glob, row)
        keys, first = np.unique(keys, return_index=True)
        rows = rows[first]
        # the owned interface rows of A: their entries in interface (row, column) numbering
        start = A.getOwnershipRange()[0]
        indptr, indices, values = A.getValuesCSR()
        owned = np.repeat(nodes.owned, bs)
        triplets = []
        for g, r in zip(glob[owned], row[owned]):
            lo, hi = indptr[g - start], indptr[g - start + 1]
            cols, vals = indices[lo:hi].astype(np.int64), values[lo:hi]
            pos = np.searchsorted(keys, cols)
            on = (pos < keys.size) & (keys[np.minimum(pos, keys.size - 1)] == cols)
            # the other columns (dofs of the facets' cells off the interface) vanish on the facets
            triplets.append((np.full(on.sum(), r), rows[pos[on]], vals[on]))
        A.destroy()
        local = [np.hstack([t[k] for t in triplets]) if triplets else np.empty(0) for k in range(3)]
        if comm.size > 1:
            local = [np.hstack(comm.allgather(x)) for x in local]
        self.matrix = scipy.sparse.csr_matrix((local[2], (local[0].astype(np.int64), local[1].astype(np.int64))),
                                              shape=(n * bs, n * bs))
        self.keep = np.asarray(keep, dtype=bool).reshape(n, bs)
        self._kept = np.flatnonzero(self.keep.ravel())
        kept = self.matrix[self._kept][:, self._kept].tocsc()
        self._lu = scipy.sparse.linalg.splu(kept) if self._kept.size else None
        self.size = n * bs

    def solve(self, R: np.ndarray) -> np.ndarray:
        """``lambda`` (N, bs) from the right-hand side ``R`` (N, bs), replicated."""
        R = np.asarray(R, dtype=float).ravel()
        out = np.zeros(self.size)
        if self._lu is not None:
            out[self._kept] = self._lu.solve(R[self._kept])
        return out.reshape(self.keep.shape)

    def solve_columns(self, R: np.ndarray) -> np.ndarray:
        """:meth:`solve` for several right-hand sides at once: columns of ``R`` (N bs, k), rows ``bs i + c``."""
        R = np.asarray(R, dtype=float)
        out = np.zeros((self.size, R.shape[1]))
        if self._lu is not None:
            out[self._kept] = self._lu.solve(np.asfortranarray(R[self._kept]))
        return out
