"""Lagrange extrapolation weights: the initial guess of a time window from the last windows.

``lagrange_weights(nodes, x)`` are the weights w_i of the polynomial through
the values at ``nodes`` evaluated at ``x``: p(x) = sum_i w_i f(nodes_i).
Two nodes give linear, three quadratic extrapolation (preCICE's
``extrapolation-order`` 1 and 2); unequal spacing is allowed.
"""

from __future__ import annotations

from typing import Sequence

__all__ = ["lagrange_weights"]


def lagrange_weights(nodes: Sequence[float], x: float) -> list[float]:
    """w_i = prod_{j != i} (x - t_j) / (t_i - t_j) for distinct ``nodes`` t_i (they sum to 1)."""
    nodes = [float(t) for t in nodes]
    if len(set(nodes)) != len(nodes):
        raise ValueError(f"lagrange_weights: the nodes must be distinct, got {nodes}")
    weights = []
    for i, ti in enumerate(nodes):
        w = 1.0
        for j, tj in enumerate(nodes):
            if j != i:
                w *= (float(x) - tj) / (ti - tj)
        weights.append(w)
    return weights
