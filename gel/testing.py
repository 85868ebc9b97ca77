"""Small helpers for the gel's verification tests and demos (no physics here).

* ``rectangle``: a triangulated rectangle with its four sides tagged.
* ``line_weights``: the P2 (Simpson) weights of nodes on a straight interface,
  i.e. the consistent nodal load of a unit traction and the quadrature that
  integrates a P2 trace exactly.
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

from dolfinx import mesh as dmesh

__all__ = ["LEFT", "RIGHT", "BOTTOM", "TOP", "rectangle", "line_weights"]

LEFT, RIGHT, BOTTOM, TOP = 1, 2, 3, 4


def rectangle(x0: float, y0: float, x1: float, y1: float, nx: int, ny: int,
              comm: MPI.Comm = MPI.COMM_WORLD,
              diagonal: dmesh.DiagonalType = dmesh.DiagonalType.right):
    """Rectangle [x0, x1] x [y0, y1] with nx x ny cell pairs; returns ``(mesh, facet_tags)``.

    Facet tags: LEFT (x = x0) = 1, RIGHT (x = x1) = 2, BOTTOM (y = y0) = 3, TOP (y = y1) = 4.
    """
    msh = dmesh.create_rectangle(comm, [np.array([x0, y0]), np.array([x1, y1])], [nx, ny],
                                 dmesh.CellType.triangle, diagonal=diagonal)
    tol = 1e-10 * max(x1 - x0, y1 - y0)
    sides = ((LEFT, 0, x0), (RIGHT, 0, x1), (BOTTOM, 1, y0), (TOP, 1, y1))
    idx, val = [], []
    for tag, axis, coord in sides:
        facets = dmesh.locate_entities_boundary(
            msh, 1, lambda x, a=axis, c=coord: np.isclose(x[a], c, rtol=0.0, atol=tol))
        idx.append(facets)
        val.append(np.full(facets.size, tag, dtype=np.int32))
    idx, val = np.hstack(idx), np.hstack(val)
    order = np.argsort(idx)
    return msh, dmesh.meshtags(msh, 1, idx[order].astype(np.int32), val[order])


def line_weights(points: np.ndarray, axis: int) -> np.ndarray:
    """P2 weights w_i = int psi_i ds of the nodes of a straight interface along ``axis``.

    ``points`` are the interface nodes (vertices and edge midpoints, as listed
    by ``InterfaceNodes``) of a straight line x[axis] = var.  Sorted along the
    line, even entries are vertices and odd ones midpoints; on an edge of
    length h the vertex weights are h/6 and the midpoint weight 2h/3
    (Simpson's rule).  ``sum(w * f)`` integrates the P2 interpolant of f
    exactly, and ``w * t`` is the consistent nodal load of a uniform traction t.
    """
    s = np.asarray(points)[:, axis]
    order = np.argsort(s)
    if order.size % 2 != 1:
        raise ValueError(f"a P2 line has an odd number of nodes, got {order.size}")
    w = np.zeros(order.size)
    for k in range(0, order.size - 2, 2):
        a, m, b = order[k], order[k + 1], order[k + 2]
        h = s[b] - s[a]
        if not np.isclose(s[m], 0.5 * (s[a] + s[b]), rtol=0.0, atol=1e-12 * (1 + abs(h))):
            raise ValueError("interface nodes are not vertex/midpoint pairs of a straight P2 line")
        w[a] += h / 6
        w[b] += h / 6
        w[m] += 2 * h / 3
    return w
