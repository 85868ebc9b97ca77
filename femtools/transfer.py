"""Copy a Lagrange function between two meshes whose nodes coincide.

The region meshes and the whole-device mesh are cut from one gmsh model, so
every node of a region mesh is a node of the whole mesh with bit-identical
coordinates.  A field on the whole mesh is transferred to a region mesh by
matching node coordinates: an exact copy, no interpolation.  Works for any
partition of either mesh (source values are gathered on every rank).

The source may also live on a sub-communicator of the destination's (a
process group of :class:`coupling.Distribution`, whose ranks mesh the same
gmsh model): give the destination's communicator as ``comm`` and ``None``
for the source on the ranks outside its group.
"""

from __future__ import annotations

import numpy as np
import scipy.spatial

from mpi4py import MPI

from dolfinx import fem

__all__ = ["NodalTransfer"]


class NodalTransfer:
    """Map the nodes of ``V_dst`` onto the nodes of ``V_src`` (same element, coinciding nodes).

    Args:
        V_src: source space (e.g. on the whole mesh), or ``None`` on the ranks
            of ``comm`` where it does not live.
        V_dst: destination space (e.g. on a region mesh); every node of it
            must be a node of ``V_src``.
        tol: largest accepted distance between matched nodes.
        comm: the communicator the nodes are matched over (collective on
            it); default the source mesh's.  Give it (the destination mesh's)
            when the source lives on a sub-communicator of it.

    Example::

        # u on the fluid group's mesh (None elsewhere), V on the world's fluid mesh
        NodalTransfer(u.function_space if u else None, V, comm=MPI.COMM_WORLD).apply(u, fem.Function(V))
    """

    def __init__(self, V_src: fem.FunctionSpace | None, V_dst: fem.FunctionSpace, tol: float = 1e-10,
                 comm=None):
        self.comm = V_src.mesh.comm if comm is None else comm
        self.bs = V_dst.dofmap.index_map_bs
        if V_src is not None and V_src.dofmap.index_map_bs != self.bs:
            raise ValueError("source and destination spaces have different block sizes")
        gdim = V_dst.mesh.geometry.dim
        self.n_src_owned = 0 if V_src is None else V_src.dofmap.index_map.size_local
        x_src = (np.zeros((0, gdim)) if V_src is None
                 else V_src.tabulate_dof_coordinates()[:self.n_src_owned, :gdim])
        x_all = np.vstack(self.comm.allgather(x_src))
        x_dst = V_dst.tabulate_dof_coordinates()[:, :gdim]
        dist, self.index = scipy.spatial.cKDTree(x_all).query(x_dst)
        worst = self.comm.allreduce(float(dist.max()) if dist.size else 0.0, op=MPI.MAX)  # raised on every rank
        if worst > tol:
            raise ValueError(f"a destination node has no source node within {tol} (distance {worst:.3e})")

    def apply(self, src: fem.Function | None, dst: fem.Function) -> fem.Function:
        """Copy ``src`` (``None`` where the source space is) into ``dst`` (owned and ghost entries); returns ``dst``.

        Collective on :attr:`comm`.
        """
        owned = (np.zeros((0, self.bs)) if src is None
                 else src.x.array[: self.n_src_owned * self.bs].reshape(-1, self.bs))
        values = np.vstack(self.comm.allgather(owned))
        dst.x.array.reshape(-1, self.bs)[:] = values[self.index]
        return dst
