"""Field values in an order that does not depend on the mesh partition (checkpoints, frames).

The partitioner of dolfinx distributes the cells differently from one run to
the next under MPI, so a rank's local dof array cannot be read back by
another process.  :class:`CanonicalOrder` lists the nodes of a Lagrange
space sorted by their coordinates (rounded, as ``InterfaceNodes`` does):
``gather`` turns a local array into the global array in that order, the same
on every rank and for every partition and rank count; ``scatter`` puts a
global array back into the local layout of the current partition.
:class:`MixedCanonical` does the same for each field of a mixed space.
"""

from __future__ import annotations

import numpy as np
import scipy.spatial

from dolfinx import fem

__all__ = ["CanonicalOrder", "MixedCanonical"]


class CanonicalOrder:
    """The nodes of a (collapsed) Lagrange space ``V`` in a partition-independent order."""

    def __init__(self, V: fem.FunctionSpace):
        comm = V.mesh.comm
        self.comm = comm
        self.bs = V.dofmap.index_map_bs
        gdim = V.mesh.geometry.dim
        imap = V.dofmap.index_map
        self.n_owned = imap.size_local
        local = V.tabulate_dof_coordinates()[:, :gdim]
        owned = local[: self.n_owned]
        points = np.vstack(comm.allgather(owned)) if comm.size > 1 else owned
        tol = 1e-10 * (1.0 + (np.abs(points).max() if points.size else 0.0))
        order = np.lexsort(np.round(points / tol).T[::-1])
        self.points = points[order]
        self.size = self.points.shape[0]
        dist, self._index = scipy.spatial.cKDTree(self.points).query(local)
        if dist.size and dist.max() > tol:
            raise RuntimeError("a node of the space is not among the gathered nodes")
        # which canonical rows this rank owns, for gather
        self._owned_index = self._index[: self.n_owned]

    def gather(self, values: np.ndarray) -> np.ndarray:
        """The global (size, bs) array in canonical order, from this rank's local array (owned + ghost)."""
        values = np.asarray(values, dtype=float).reshape(-1, self.bs)[: self.n_owned]
        if self.comm.size > 1:
            idx = np.hstack(self.comm.allgather(self._owned_index))
            vals = np.vstack(self.comm.allgather(values))
        else:
            idx, vals = self._owned_index, values
        out = np.empty((self.size, self.bs))
        out[idx] = vals
        return out

    def scatter(self, canonical: np.ndarray) -> np.ndarray:
        """This rank's local array (owned + ghost, flattened) from a canonical (size, bs) array."""
        canonical = np.asarray(canonical, dtype=float).reshape(self.size, self.bs)
        return canonical[self._index].ravel()


class MixedCanonical:
    """Every field of a mixed space (``W.sub(i).collapse()``) in canonical order.

    Args:
        W: the mixed space.
        names: a name for each sub-space, in order.
    """

    def __init__(self, W: fem.FunctionSpace, names):
        self.parts = []
        for i, name in enumerate(names):
            space, parent = W.sub(i).collapse()
            self.parts.append((name, np.asarray(parent, dtype=np.int32), CanonicalOrder(space)))

    def gather(self, values: np.ndarray) -> dict[str, np.ndarray]:
        """``{name: (size, bs) array}`` from the local array of a Function on W."""
        return {name: order.gather(values[parent]) for name, parent, order in self.parts}

    def scatter(self, arrays, out: np.ndarray) -> None:
        """Fill the local array ``out`` of a Function on W from ``gather``'s arrays."""
        for name, parent, order in self.parts:
            out[parent] = order.scatter(arrays[name])
