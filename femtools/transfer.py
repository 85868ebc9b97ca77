"""Copy a Lagrange function between two meshes whose nodes coincide.

The region meshes and the whole-device mesh are cut from one gmsh model, so
every node of a region mesh is a node of the whole mesh with bit-identical
coordinates.  A field on the whole mesh is transferred to a region mesh by
matching node coordinates: an exact copy, no interpolation.  Works for any
partition of either mesh (source values are gathered on every rank).
"""

from __future__ import annotations

import numpy as np
import scipy.spatial

from dolfinx import fem

__all__ = ["NodalTransfer"]


class NodalTransfer:
    """Map the nodes of ``V_dst`` onto the nodes of ``V_src`` (same element, coinciding nodes).

    Args:
        V_src: source space (e.g. on the whole mesh).
        V_dst: destination space (e.g. on a region mesh); every node of it
            must be a node of ``V_src``.
        tol: largest accepted distance between matched nodes.
    """

    def __init__(self, V_src: fem.FunctionSpace, V_dst: fem.FunctionSpace, tol: float = 1e-10):
        self.comm = V_src.mesh.comm
        self.bs = V_src.dofmap.index_map_bs
        if V_dst.dofmap.index_map_bs != self.bs:
            raise ValueError("source and destination spaces have different block sizes")
        gdim = V_src.mesh.geometry.dim
        n_src = V_src.dofmap.index_map.size_local
        self.n_src_owned = n_src
        x_src = V_src.tabulate_dof_coordinates()[:n_src, :gdim]
        x_all = np.vstack(self.comm.allgather(x_src))
        x_dst = V_dst.tabulate_dof_coordinates()[:, :gdim]
        dist, self.index = scipy.spatial.cKDTree(x_all).query(x_dst)
        if dist.size and dist.max() > tol:
            raise ValueError(f"a destination node has no source node within {tol} (distance {dist.max():.3e})")

    def apply(self, src: fem.Function, dst: fem.Function) -> fem.Function:
        """Copy ``src`` into ``dst`` (owned and ghost entries); returns ``dst``."""
        owned = src.x.array[: self.n_src_owned * self.bs].reshape(-1, self.bs)
        values = np.vstack(self.comm.allgather(owned))
        dst.x.array.reshape(-1, self.bs)[:] = values[self.index]
        return dst
