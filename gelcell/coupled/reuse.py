"""The coupling state carried from one solve to the next of a sweep of one scaled problem.

In solver units the interface data of a Ca sweep depend on Ca only through
the strain-sized nonlinearity, so the last solves' states, extrapolated in
Ca, start the next solve close to its answer.
"""

from __future__ import annotations

import typing

import numpy as np

import coupling as cp

__all__ = ["ReuseStore"]


class ReuseStore:
    """The coupling state carried from one solve to the next of a sweep (see :func:`solve_partitioned`).

    Attributes:
        key: What identifies the scaled problem (and the coupling configuration) of the states.
        states: ``[(Ca, scheme.reuse_state()), ...]`` of the last three solves with that key.
    """

    def __init__(self) -> None:
        self.key: typing.Any = None
        self.states: list[tuple[float, dict]] = []

    @property
    def state(self) -> dict | None:
        """The newest reusable state (None if none)."""
        return self.states[-1][1] if self.states else None

    def add(self, key: typing.Any, ca: float, state: dict) -> None:
        if key != self.key:
            self.key, self.states = key, []
        self.states = [(c, st) for c, st in self.states if c != float(ca)]
        self.states = (self.states + [(float(ca), state)])[-3:]

    def prediction(self, ca: float) -> dict | None:
        """The newest state with its interface data and participant states extrapolated to ``ca``.

        Lagrange polynomial in Ca through the last two (linear) or three
        (quadratic) solves; the newest state as it is with only one (or far
        outside the known values).  In
        solver units the data and fields depend on Ca only through the
        strain-sized nonlinearity, smooth in Ca: the extrapolation removes
        its first- (second-) order part.  None without a state.
        """
        if not self.states:
            return None
        newest = self.states[-1][1]
        # far outside the known values a polynomial amplifies the states' 1e-10 convergence noise:
        # fall back to fewer points (linear beyond 2x their span, none beyond 10x)
        cs = [c for c, _ in self.states]
        reach = abs(float(ca) - cs[-1]) / max(max(cs) - min(cs), 1e-300)
        used = self.states if reach <= 2.0 else self.states[-2:] if reach <= 10.0 else self.states[-1:]
        if len(used) < 2:
            return newest
        weights = cp.lagrange_weights([c for c, _ in used], ca)

        def combine(parts):
            first = parts[0]
            if isinstance(first, dict):
                return {k: combine([p[k] for p in parts]) for k in first}
            if isinstance(first, np.ndarray) and first.dtype.kind == "f" and \
                    all(isinstance(p, np.ndarray) and p.shape == first.shape for p in parts):
                return sum(w * p for w, p in zip(weights, parts))
            return parts[-1]

        states = [st for _, st in used]
        out = dict(newest)
        out["values"] = combine([st["values"] for st in states])
        out["participants"] = combine([st.get("participants") or {} for st in states])
        return out
