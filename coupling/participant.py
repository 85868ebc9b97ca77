"""Participants and the interface data they exchange.

A *participant* is anything that maps the interface data it reads to the
interface data it writes (:meth:`Participant.solve`).  A *data* is a named
array over the interface points of one participant (its writer), with
``dim`` components per point; each reader receives it mapped onto its own
points of the same mesh name.

Conventions:

* Every participant provides its own points for a mesh name
  (:meth:`Participant.interface_points`), as an ``(N, space_dim)`` array
  replicated on every MPI rank.
* A data's values live on its writer's points, shape ``(N_writer, dim)``.
* The mapping ``Data.mapping`` takes them to each reader's points.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Data", "Participant", "uses_advance", "MAPPINGS", "CURVES", "CURVE_ORDERS"]

MAPPINGS = ("matching", "nearest", "linear", "conservative", "surface", "surface-conservative")
CURVES = ("auto", "open", "closed")
CURVE_ORDERS = ("chain", "angle", "given")


@dataclass(frozen=True)
class Data:
    """A named coupling data: who writes it, who reads it, how it is mapped.

    Attributes:
        name: Unique name, e.g. ``"Gamma1/traction"``.
        mesh: Interface (mesh) name; each participant provides its points.
        dim: Number of components per point (1 for scalars).
        writer: Name of the participant that writes the data.
        readers: Names of the participants that read it (not the writer).
        mapping: ``"matching"`` (exact point-to-point lookup), ``"nearest"``,
            ``"linear"`` (interpolation along the interface curve) or
            ``"conservative"`` (transpose of the linear map from the reader's
            to the writer's points; preserves the sum, for nodal forces);
            ``"surface"`` and ``"surface-conservative"`` are their analogues
            on triangulated surfaces in 3-D (:mod:`coupling.surface_mapping`;
            they need :meth:`Participant.interface_triangles` of the writer,
            resp. of the reader).
        curve: For ``"linear"``/``"conservative"``: ``"open"``, ``"closed"``
            or ``"auto"`` (closed if the chain's end is as close to its start
            as its end segments are long).
        curve_order: How points are ordered along the curve: ``"chain"``
            (greedy nearest-neighbour chain, two passes so it starts at an
            end point), ``"angle"`` (polar angle about the centroid; closed,
            star-shaped 2-D curves) or ``"given"`` (the order returned by
            ``interface_points``).

    Example::

        Data(name="Gamma1/traction", mesh="Gamma1", dim=2, writer="fluid",
             readers=("gel",), mapping="matching")
    """

    name: str
    mesh: str
    dim: int
    writer: str
    readers: tuple[str, ...]
    mapping: str = "matching"
    curve: str = "auto"
    curve_order: str = "chain"

    def __post_init__(self) -> None:
        where = f"Data {self.name!r}"
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Data.name = {self.name!r} must be a non-empty string")
        if not isinstance(self.mesh, str) or not self.mesh:
            raise ValueError(f"{where}: mesh = {self.mesh!r} must be a non-empty string")
        if isinstance(self.dim, bool) or not isinstance(self.dim, (int, np.integer)) or self.dim < 1:
            raise ValueError(f"{where}: dim = {self.dim!r} must be a positive integer")
        object.__setattr__(self, "dim", int(self.dim))
        if not isinstance(self.writer, str) or not self.writer:
            raise ValueError(f"{where}: writer = {self.writer!r} must be a participant name")
        readers = (self.readers,) if isinstance(self.readers, str) else tuple(self.readers)
        if not readers:
            raise ValueError(f"{where}: readers must name at least one participant")
        if len(set(readers)) != len(readers):
            raise ValueError(f"{where}: readers = {readers!r} names a participant twice")
        if self.writer in readers:
            raise ValueError(f"{where}: the writer {self.writer!r} cannot also be a reader")
        object.__setattr__(self, "readers", readers)
        for key, value, allowed in (("mapping", self.mapping, MAPPINGS), ("curve", self.curve, CURVES),
                                    ("curve_order", self.curve_order, CURVE_ORDERS)):
            if value not in allowed:
                raise ValueError(f"{where}: {key} = {value!r} is not allowed; allowed values: "
                                 f"{', '.join(repr(a) for a in allowed)}")


class Participant(abc.ABC):
    """Abstract base class of a coupling participant.

    Subclasses set a unique ``name`` and implement :meth:`interface_points`
    and :meth:`solve`; every other method has a default that does nothing
    (or raises ``NotImplementedError`` where the scheme needs an answer).
    The calls a scheme makes (``docs/coupling.md``, "The participant's
    lifecycle")::

        p.initialize()                        # once, before the first window
        for each window [t, t + dt]:          # a steady solve: one window, no begin_window
            p.begin_window(t, dt)             # once: set the time level, shift the history
            state = p.save_state()            # implicit, state_reload = "iteration" only
            for k in 1, 2, ...:               # coupling iterations
                if k > 1:
                    p.load_state(state)       # implicit, state_reload = "iteration" only
                outputs = p.solve(inputs_k)
            p.end_window(accepted)            # once, when the window is accepted
        p.finalize()                          # once, when solve() or run() returns

    With ``state_reload = "window"`` neither ``save_state`` nor ``load_state``
    is called within a window: each solve continues from the previous one.
    Explicit schemes solve once per window and never save or load.

    A participant whose class overrides :meth:`advance` but not
    :meth:`begin_window` keeps the earlier protocol: ``save_state()`` before
    the window's first solve, and ``advance(t, dt)`` (idempotent: it *sets*
    the time level) after every ``load_state`` and before every solve.

    Example::

        class Doubler(Participant):
            name = "doubler"
            def interface_points(self, mesh_name):
                return np.zeros((1, 2))
            def solve(self, inputs):
                return {"out": 2.0 * inputs["in"]}
    """

    name: str = ""

    @abc.abstractmethod
    def interface_points(self, mesh_name: str) -> np.ndarray:
        """Return this participant's points of ``mesh_name``, shape ``(N, space_dim)``.

        The array must be replicated (identical) on every MPI rank; use
        :func:`coupling.parallel.gather_rows` if the points are distributed.
        """

    def interface_triangles(self, mesh_name: str) -> np.ndarray:
        """Return the triangles of this participant's surface ``mesh_name`` (needed by surface mappings).

        An ``(M, 3)`` or ``(M, 6)`` integer array of row indices into
        :meth:`interface_points` (``(M, 6)``: quadratic triangles, nodes
        ``v0, v1, v2`` then those on the edges ``(v1, v2)``, ``(v0, v2)``,
        ``(v0, v1)``); every point must be a node of a triangle.  Replicated
        on every MPI rank, like the points.
        """
        raise NotImplementedError(f"participant {self.name!r} does not implement interface_triangles()")

    @abc.abstractmethod
    def solve(self, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Solve with the given interface inputs; return every data this participant writes.

        Args:
            inputs: For each data this participant reads, its values mapped onto
                this participant's points of that data's mesh, shape ``(N, dim)``.

        Returns:
            For each data this participant writes, an array ``(N_own, dim)`` on
            its own points of that data's mesh (replicated on every rank).
        """

    def save_state(self) -> Any:
        """Return a copy of the state at the start of a time window (never an alias)."""
        raise NotImplementedError(f"participant {self.name!r} does not implement save_state()")

    def load_state(self, state: Any) -> None:
        """Restore a state returned by :meth:`save_state` (copying from it)."""
        raise NotImplementedError(f"participant {self.name!r} does not implement load_state()")

    def checkpoint_state(self) -> Any:
        """The state to write into a checkpoint file (default: :meth:`save_state`).

        Override it when :meth:`save_state` is tied to this process (e.g. the
        local arrays of a mesh partition that differs in the next run).
        """
        return self.save_state()

    def load_checkpoint_state(self, state: Any) -> None:
        """Restore a state returned by :meth:`checkpoint_state` (default: :meth:`load_state`)."""
        self.load_state(state)

    def initialize(self) -> None:
        """Called once before the scheme's first window (again after :meth:`finalize`)."""

    def begin_window(self, t: float, dt: float) -> None:
        """Start the time window ``[t, t + dt]``: called once, before its first solve.

        After it, :meth:`save_state` returns the state every iteration of the
        window starts from.  The default calls :meth:`advance` if the class
        overrides it (a participant of the earlier protocol), else does nothing.
        """
        if _overrides(self, "advance"):
            self.advance(t, dt)

    def end_window(self, accepted: dict[str, np.ndarray]) -> None:
        """The window was accepted: called once, after its last solve.

        Args:
            accepted: The values the window keeps (``accepted_value``) of every
                data this participant reads (mapped onto its points, as
                :meth:`solve` receives them) and writes (on its own points).
                The participant's state is the one its last solve reached.
        """

    def finalize(self) -> None:
        """Called once when :meth:`CouplingScheme.solve` or :meth:`~CouplingScheme.run` returns."""

    def advance(self, t: float, dt: float) -> None:
        """The earlier protocol's window start, called before each solve of the window.

        Must *set* (not increment) the time level, because it is called again
        after every :meth:`load_state`.  Override :meth:`begin_window` instead
        in a new participant.
        """
        raise NotImplementedError(f"participant {self.name!r} does not implement advance()")

    def initial_data(self, data_name: str) -> np.ndarray | None:
        """Initial value of a data this participant writes, or ``None`` for zeros."""
        return None


def _overrides(participant: Participant, method: str) -> bool:
    """Whether ``participant``'s class defines ``method`` itself rather than inheriting Participant's."""
    return getattr(type(participant), method) is not getattr(Participant, method)


def uses_advance(participant: Participant) -> bool:
    """Whether ``participant`` keeps the earlier protocol: ``advance`` before every solve.

    True when the most derived class defining ``advance`` or ``begin_window``
    (below :class:`Participant`) defines ``advance`` and not ``begin_window``.
    """
    for cls in type(participant).__mro__:
        if cls is Participant:
            return False
        own = {m: cls.__dict__.get(m) for m in ("begin_window", "advance")}
        if own["begin_window"] not in (None, Participant.begin_window):
            return False
        if own["advance"] not in (None, Participant.advance):
            return True
    return False
