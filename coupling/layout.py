"""Concatenation of several interface data into one vector.

The accelerated fixed-point vector ``x`` is the concatenation of the
flattened values (row-major: point by point, component by component) of
several data, in a fixed order.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

__all__ = ["VectorLayout"]


class VectorLayout:
    """Names, shapes and offsets of data concatenated into one vector.

    Args:
        names: Data names in concatenation order.
        shapes: For each name, the array shape ``(N, dim)`` of its values.

    Example::

        layout = VectorLayout(["a", "b"], [(3, 2), (4, 1)])
        x = layout.concat({"a": np.ones((3, 2)), "b": np.zeros((4, 1))})   # size 10
        parts = layout.split(x)                                           # back to arrays
    """

    def __init__(self, names: Sequence[str], shapes: Sequence[tuple[int, ...]]):
        if len(names) != len(shapes):
            raise ValueError("VectorLayout: names and shapes differ in length")
        if len(set(names)) != len(names):
            raise ValueError(f"VectorLayout: duplicate names in {list(names)!r}")
        self.names: tuple[str, ...] = tuple(names)
        self.shapes: tuple[tuple[int, ...], ...] = tuple(tuple(int(s) for s in sh) for sh in shapes)
        sizes = [int(np.prod(sh)) for sh in self.shapes]
        self.offsets: tuple[int, ...] = tuple(int(o) for o in np.concatenate([[0], np.cumsum(sizes)]))
        self.size: int = self.offsets[-1]

    @classmethod
    def single(cls, n: int, name: str = "x") -> "VectorLayout":
        """Layout of one data of ``n`` scalar values (for standalone use)."""
        return cls([name], [(n, 1)])

    def slice(self, name: str) -> slice:
        """Slice of ``name`` in the concatenated vector."""
        i = self.names.index(name)
        return slice(self.offsets[i], self.offsets[i + 1])

    def slices(self) -> list[slice]:
        """Slices of all data, in order."""
        return [slice(self.offsets[i], self.offsets[i + 1]) for i in range(len(self.names))]

    def concat(self, values: Mapping[str, np.ndarray]) -> np.ndarray:
        """Concatenate the flattened values of every data into a new vector."""
        if not self.names:
            return np.zeros(0)
        return np.concatenate([np.asarray(values[n], dtype=float).reshape(-1) for n in self.names])

    def split(self, vector: np.ndarray) -> dict[str, np.ndarray]:
        """Split a vector into copies of the per-data arrays."""
        vector = np.asarray(vector, dtype=float)
        if vector.shape != (self.size,):
            raise ValueError(f"VectorLayout.split: expected a vector of size {self.size}, got "
                             f"shape {vector.shape}")
        return {n: vector[s].reshape(sh).copy()
                for n, s, sh in zip(self.names, self.slices(), self.shapes)}

    def norms(self, vector: np.ndarray) -> np.ndarray:
        """Euclidean norm of each data's part of ``vector``."""
        return np.array([float(np.linalg.norm(vector[s])) for s in self.slices()])

    def __repr__(self) -> str:
        parts = ", ".join(f"{n}{sh}" for n, sh in zip(self.names, self.shapes))
        return f"VectorLayout({parts})"
