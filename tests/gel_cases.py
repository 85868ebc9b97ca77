"""Helpers of the gel tests (``tests/test_gel*.py``, ``tests/mpi_scripts/gel_mpi.py``); no physics here.

* ``line_weights``: the P2 (Simpson) weights of nodes on a straight interface,
  i.e. the consistent nodal load of a unit traction and the quadrature that
  integrates a P2 trace exactly.
* ``box_mesh``: a tagged box of tetrahedra, the 3D analogue of the rectangle.

The tagged rectangle the 2D gel tests run on is :func:`femtools.mesh.rectangle_mesh`.
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

from dolfinx.mesh import CellType, create_box, locate_entities_boundary, meshtags

__all__ = ["line_weights", "box_mesh", "X0", "X1", "Y0", "Y1", "Z0", "Z1"]

#: facet tags of the faces of :func:`box_mesh`: x = x0, x = x1, y = y0, y = y1, z = z0, z = z1
X0, X1, Y0, Y1, Z0, Z1 = 1, 2, 3, 4, 5, 6


def box_mesh(lower, upper, n, comm=MPI.COMM_WORLD):
    """Box [lower, upper] with n = (nx, ny, nz) cubes of 6 tetrahedra each; returns ``(mesh, facet_tags)``.

    Facet tags X0 .. Z1 (1 .. 6) on its faces, in the order of :func:`femtools.mesh.rectangle_mesh`'s
    sides (LEFT = X0, RIGHT = X1, BOTTOM = Y0, TOP = Y1) followed by z = z0, z = z1.
    """
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    msh = create_box(comm, [lower, upper], list(n), CellType.tetrahedron)
    tol = 1e-10 * float(np.max(upper - lower))
    idx, val = [], []
    for tag, (axis, coord) in enumerate([(a, c) for a in range(3) for c in (lower[a], upper[a])], start=1):
        facets = locate_entities_boundary(msh, 2, lambda x, a=axis, c=coord: np.isclose(x[a], c, rtol=0.0, atol=tol))
        idx.append(facets)
        val.append(np.full(facets.size, tag, dtype=np.int32))
    idx, val = np.hstack(idx), np.hstack(val)
    order = np.argsort(idx)
    return msh, meshtags(msh, 2, idx[order].astype(np.int32), val[order])


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
