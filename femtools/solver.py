"""The interface every field solver (fluid, gel, cell) presents to the outside.

A field solver owns its mesh, spaces, forms and linear solver.  The outside
world (tests, the coupling layer) only sees named interfaces, their points,
and data arrays of shape ``(N, k)`` on those points: it never touches a
dolfinx object of the solver.

    solver.interface_names()                  -> ["Gamma1", ...]
    solver.interface_points("Gamma1")         -> (N, 2) array, replicated on all ranks
    solver.interface_triangles("Gamma1")      -> (M, 6) P2 triangles of a 3D interface (indices)
    solver.input_names("Gamma1")              -> {"robin_normal": 2, ...}  (name -> components)
    solver.set_interface_data("Gamma1", robin_normal=..., ...)
    solver.solve()
    solver.interface_data("Gamma1")           -> {"traction": (N, 2), "velocity": (N, 2)}
"""

from __future__ import annotations

import abc
import time

import numpy as np

from femtools.interface import InterfaceNodes
from femtools.linalg import SingularSystemError
from femtools.mesh import settle_coordinate_element

__all__ = ["FieldSolver"]


class FieldSolver(abc.ABC):
    """Base class: interface bookkeeping, input validation and timing."""

    name: str = "field"
    #: the condition a singular system of this field most likely lacks (see SingularSystemError)
    singular_hint: str = ""

    def __init__(self, mesh=None):
        if mesh is not None:
            settle_coordinate_element(mesh)      # before any form: see its docstring
        self._interfaces: dict[str, InterfaceNodes] = {}
        self._inputs: dict[str, dict[str, int]] = {}
        self.timing = {"setup": 0.0, "solve": 0.0, "solves": 0}

    # -- declared by subclasses -------------------------------------------
    def _add_interface(self, name: str, nodes: InterfaceNodes, inputs: dict[str, int]) -> None:
        if name in self._interfaces:
            raise ValueError(f"{self.name}: interface {name!r} declared twice")
        self._interfaces[name] = nodes
        self._inputs[name] = dict(inputs)

    @abc.abstractmethod
    def _set_input(self, interface: str, key: str, values: np.ndarray) -> None:
        """Store one validated input array (N, k) for the next solve."""

    @abc.abstractmethod
    def _solve(self) -> None:
        """Solve the field problem with the current inputs."""

    @abc.abstractmethod
    def interface_data(self, name: str) -> dict[str, np.ndarray]:
        """Output arrays on the interface points of ``name``."""

    # -- public ------------------------------------------------------------
    def interface_names(self) -> list[str]:
        return list(self._interfaces)

    def interface_nodes(self, name: str) -> InterfaceNodes:
        try:
            return self._interfaces[name]
        except KeyError:
            raise KeyError(f"{self.name}: no interface {name!r}; it has {self.interface_names()}") from None

    def interface_points(self, name: str) -> np.ndarray:
        return self.interface_nodes(name).points

    def interface_triangles(self, name: str) -> np.ndarray:
        """``(M, 6)`` P2 triangles of a 3D interface, indices into its points (:meth:`InterfaceNodes.triangles`)."""
        return self.interface_nodes(name).triangles()

    def input_names(self, name: str) -> dict[str, int]:
        self.interface_nodes(name)
        return dict(self._inputs[name])

    def set_interface_data(self, name: str, **arrays: np.ndarray) -> None:
        """Set input data on interface ``name``; each array has shape (N, k)."""
        nodes = self.interface_nodes(name)
        allowed = self._inputs[name]
        for key, values in arrays.items():
            if key not in allowed:
                raise KeyError(f"{self.name}: interface {name!r} takes {sorted(allowed)}, not {key!r}")
            values = np.asarray(values, dtype=float)
            if values.ndim == 1 and allowed[key] == 1:
                values = values[:, None]
            if values.shape != (nodes.size, allowed[key]):
                raise ValueError(f"{self.name}: {name}/{key} must have shape {(nodes.size, allowed[key])}, "
                                 f"got {values.shape}")
            if not np.all(np.isfinite(values)):
                raise FloatingPointError(f"{self.name}: {name}/{key} contains NaN or Inf")
            self._set_input(name, key, values)

    def solve(self) -> None:
        t0 = time.perf_counter()
        try:
            self._solve()
        except SingularSystemError as exc:
            raise exc.add_hint(self.singular_hint) from None
        self.timing["solve"] += time.perf_counter() - t0
        self.timing["solves"] += 1
