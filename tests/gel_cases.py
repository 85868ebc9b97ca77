"""Helpers of the gel tests (``tests/test_gel*.py``, ``tests/mpi_scripts/gel_mpi.py``); no physics here.

* ``line_weights``: the P2 (Simpson) weights of nodes on a straight interface,
  i.e. the consistent nodal load of a unit traction and the quadrature that
  integrates a P2 trace exactly.

The tagged rectangle the gel tests run on is :func:`femtools.mesh.rectangle_mesh`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["line_weights"]


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
