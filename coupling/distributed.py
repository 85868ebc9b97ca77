"""Participants in separate MPI process groups, exchanging interface data through MPI.

A :class:`Distribution` splits a world communicator into *groups* of ranks
and assigns every participant to one group (preCICE runs each participant
as its own executable; here a group plays that part, and the groups may
come from one ``mpirun`` or from ``mpirun -n A … : -n B …``, whose
``MPI_COMM_WORLD`` spans both).  Each rank constructs only the participants
of its own group, on :attr:`Distribution.group_comm`, and passes them to
``build_scheme(..., distribution=...)``.

The scheme itself runs on every rank of the world communicator, on
replicated interface arrays, as without a distribution: mappings,
convergence measures and the acceleration are computed identically on
every rank, so every rank takes the same decisions.  Each participant is
seen through a :class:`GroupParticipant`: on the ranks of its group it
calls the real participant; its outputs (and, at setup, its interface
points, triangles, initial data and Jacobian) are then broadcast from the
group's first rank to the world.  In a parallel scheme every group first
solves its own participants (:meth:`GroupParticipant.start`), and only then
are the outputs exchanged (:meth:`GroupParticipant.finish`), so the groups
compute at the same time; in a serial scheme they take turns.  A
participant that raises in its group raises a :class:`ParticipantGroupError`
with the same message on every rank, so the coupling stops everywhere.

Spec strings (``[coupling] distribute`` of an application, see
:func:`parse_distribution`)::

    "fluid:1,gel+cell:1"     # fluid on 1 rank, gel and cell together on the next 1
    "fluid,gel+cell"         # the ranks split evenly between the two groups
"""

from __future__ import annotations

import hashlib
import time as _time
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from coupling.parallel import default_comm
from coupling.participant import Participant, uses_advance

__all__ = ["Distribution", "GroupParticipant", "ParticipantGroupError", "parse_distribution", "group_sizes",
           "DISTRIBUTION_FORMS"]

#: the allowed forms of a spec string, for error messages
DISTRIBUTION_FORMS = ("'name[+name...][:ranks],...' e.g. 'fluid:1,gel+cell:1' "
                      "(ranks omitted: the ranks left split evenly)")

#: exception types re-raised as themselves on every rank (others become RuntimeError)
_PORTABLE_ERRORS = {cls.__name__: cls for cls in (NotImplementedError, ValueError, TypeError, KeyError,
                                                   RuntimeError, ArithmeticError, MemoryError)}


class ParticipantGroupError(RuntimeError):
    """A participant failed in its process group; raised with the same message on every rank."""


def parse_distribution(spec: str, names: Iterable[str] | None = None) -> list[tuple[tuple[str, ...], int | None]]:
    """Parse a spec string into ``[(participant names, ranks or None), ...]``, one entry per group.

    Args:
        spec: ``"name[+name...][:ranks],..."``, e.g. ``"fluid:1,gel+cell:1"``.
        names: If given, the participants that must each appear exactly once.

    Raises:
        ValueError: On a malformed spec, a rank count that is not a positive
            integer, a participant named twice, or (with ``names``) an unknown
            or missing participant; the message shows the allowed forms.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"distribute = {spec!r}: expected {DISTRIBUTION_FORMS}")
    groups: list[tuple[tuple[str, ...], int | None]] = []
    for part in spec.split(","):
        members, _, ranks = part.strip().partition(":")
        group = tuple(m.strip() for m in members.split("+"))
        if not all(group):
            raise ValueError(f"distribute = {spec!r}: group {part.strip()!r} has an empty participant name; "
                             f"expected {DISTRIBUTION_FORMS}")
        groups.append((group, _rank_count(spec, part, ranks) if ranks.strip() else None))
    _check_names(spec, [n for group, _ in groups for n in group], names)
    return groups


def _rank_count(spec: str, part: str, ranks: str) -> int:
    """The rank count of one group of a spec; ValueError unless a positive integer."""
    try:
        count = int(ranks)
    except ValueError:
        count = 0
    if count < 1:
        raise ValueError(f"distribute = {spec!r}: group {part.strip()!r} has rank count {ranks.strip()!r}, "
                         f"which must be a positive integer; expected {DISTRIBUTION_FORMS}")
    return count


def _check_names(spec: str, listed: list[str], names: Iterable[str] | None) -> None:
    """Every participant at most once, and (with ``names``) exactly the known ones."""
    twice = sorted({n for n in listed if listed.count(n) > 1})
    if twice:
        raise ValueError(f"distribute = {spec!r} names {twice} more than once; expected {DISTRIBUTION_FORMS}")
    if names is None:
        return
    known = list(names)
    unknown = [n for n in listed if n not in known]
    missing = [n for n in known if n not in listed]
    if unknown or missing:
        raise ValueError(f"distribute = {spec!r}: " + "; ".join(
            ([f"unknown participants {unknown}"] if unknown else [])
            + ([f"participants {missing} are in no group"] if missing else []))
            + f"; the participants are {known}; expected {DISTRIBUTION_FORMS}")


def group_sizes(spec: str, world_size: int, names: Iterable[str] | None = None) -> list[int]:
    """The rank count of every group of ``spec`` on ``world_size`` ranks (ValueError if they do not fit)."""
    return _group_sizes(spec, [c for _, c in parse_distribution(spec, names)], world_size)


def _group_sizes(spec: str, counts: Sequence[int | None], world_size: int) -> list[int]:
    """The rank count of every group: the given ones, the rest split evenly among those without one."""
    fixed = sum(c for c in counts if c is not None)
    free = [i for i, c in enumerate(counts) if c is None]
    left = world_size - fixed
    if (not free and left != 0) or (free and (left < len(free) or left % len(free))):
        raise ValueError(f"distribute = {spec!r} needs {fixed} ranks"
                         + (f" plus a multiple of {len(free)} for the groups without a count" if free else "")
                         + f", but the run has {world_size}; start it with a matching mpirun -n")
    return [c if c is not None else left // len(free) for c in counts]


class Distribution:
    """Which ranks of a world communicator run which participants.

    Args:
        groups: ``[(participant names, ranks or None), ...]`` (what
            :func:`parse_distribution` returns) or a spec string.  Groups
            take consecutive world ranks in the order given; ``None`` counts
            share the ranks left evenly.
        comm: The world communicator (default:
            :func:`coupling.parallel.default_comm`).
        names: If given, the participants that must each be in one group.

    Attributes:
        world: The world communicator, on which the scheme runs.
        group: Index of this rank's group.
        group_comm: The communicator of this rank's group (its participants' own).
        roots: World rank of every group's first rank.
        owners: Participant name -> index of its group.

    Example::

        dist = Distribution("fluid:1,gel+cell:1", MPI.COMM_WORLD)
        mine = [build(name, dist.group_comm) for name in dist.local_names]
        scheme = build_scheme(config, mine, data, distribution=dist)
    """

    def __init__(self, groups: str | Sequence[tuple[Sequence[str], int | None]], comm: Any = None,
                 names: Iterable[str] | None = None):
        spec = groups if isinstance(groups, str) else ",".join(
            "+".join(g) + ("" if c is None else f":{c}") for g, c in groups)
        parsed = parse_distribution(spec, names)
        self.spec = spec
        self.world = default_comm() if comm is None else comm
        self.members = [g for g, _ in parsed]
        self.sizes = _group_sizes(spec, [c for _, c in parsed], self.world.Get_size())
        self.roots = [int(r) for r in np.cumsum([0] + self.sizes[:-1])]
        rank = self.world.Get_rank()
        self.group = max(i for i, root in enumerate(self.roots) if root <= rank)
        self.owners = {name: i for i, group in enumerate(self.members) for name in group}
        self.group_comm = self.world if len(self.members) == 1 else self.world.Split(self.group, rank)

    @property
    def local_names(self) -> tuple[str, ...]:
        """The participants this rank constructs (those of its group)."""
        return self.members[self.group]

    def is_local(self, name: str) -> bool:
        """Whether participant ``name`` runs in this rank's group."""
        return self.owners[name] == self.group

    def root(self, name: str) -> int:
        """World rank of the first rank of ``name``'s group (where its outputs are broadcast from)."""
        return self.roots[self.owners[name]]

    def from_owner(self, name: str, compute: Callable[[], Any]) -> Any:
        """``compute()`` on ``name``'s group, its result on every world rank (collective on the world).

        An exception in the group is raised on every rank (:func:`_raise_shared`).
        """
        outcome = _run_in_group(self.group_comm, compute) if self.is_local(name) else None
        return _raise_shared(name, self.world.bcast(outcome, root=self.root(name)))

    def wrap(self, participants: Sequence[Participant], check_replicated: bool = False) -> list["GroupParticipant"]:
        """The :class:`GroupParticipant` of every participant of the distribution, in group order.

        Raises:
            ValueError: If ``participants`` are not exactly this rank's group's.
        """
        given = {p.name: p for p in participants}
        if sorted(given) != sorted(self.local_names):
            raise ValueError(f"distribution {self.spec!r}: rank {self.world.Get_rank()} is in group "
                             f"{'+'.join(self.local_names)} and must construct exactly its participants "
                             f"{list(self.local_names)}, got {sorted(given)}")
        return [GroupParticipant(name, given.get(name), self, check_replicated)
                for group in self.members for name in group]


def _run_in_group(group_comm: Any, compute: Callable[[], Any]) -> tuple:
    """``("ok", value)`` or ``("failed", error type, message)``, the same on every rank of the group."""
    try:
        outcome: tuple = ("ok", compute())
    except Exception as exc:  # noqa: BLE001  (reported to every rank, then raised there)
        outcome = ("failed", type(exc).__name__, str(exc))
    failures = [o for o in group_comm.allgather(None if outcome[0] == "ok" else outcome) if o is not None]
    return failures[0] if failures else outcome


def _raise_shared(name: str, outcome: tuple) -> Any:
    """The value of a :func:`_run_in_group` outcome, or its error raised (as a portable type)."""
    if outcome[0] == "ok":
        return outcome[1]
    _, kind, message = outcome
    cls = _PORTABLE_ERRORS.get(kind, RuntimeError)
    raise cls(f"participant {name!r} (in its process group): {kind}: {message}" if cls is RuntimeError
              else message)


class GroupParticipant(Participant):
    """A participant as every rank of a distributed scheme sees it: real in its group, a proxy elsewhere.

    Collective calls (every world rank makes them in the same order, as the
    scheme does): :meth:`interface_points`, :meth:`interface_triangles`,
    :meth:`initial_data`, :meth:`jacobian`, :meth:`jacobian_key`,
    :meth:`solve`, :meth:`finish`.  Local calls (the real participant's,
    nothing on other groups): :meth:`start`, the window calls and the states
    (``None`` outside the group).

    Args:
        name: The participant's name.
        local: The participant on this rank, or ``None`` if it runs in another group.
        distribution: The :class:`Distribution`.
        check_replicated: Check, within the group, that its outputs are the
            same on all of its ranks (``coupling.check_replicated``).
    """

    def __init__(self, name: str, local: Participant | None, distribution: Distribution,
                 check_replicated: bool = False):
        self.name, self.local, self.distribution = name, local, distribution
        self.check_replicated = check_replicated
        self._window: tuple[float, float] | None = None
        self._pending: tuple | None = None
        # which optional methods the real one has: the same answer on every rank
        self._has = distribution.from_owner(name, lambda: {
            **{m: _implements(local, m) for m in ("save_state", "load_state")},
            **{m: callable(getattr(local, m, None)) for m in ("jacobian", "jacobian_key")}})

    # ------------------------------------------------------------------ setup (collective)
    def interface_points(self, mesh_name: str) -> np.ndarray:
        return self._from_owner(lambda: np.asarray(self.local.interface_points(mesh_name)))

    def interface_triangles(self, mesh_name: str) -> np.ndarray:
        return self._from_owner(lambda: self.local.interface_triangles(mesh_name))

    def initial_data(self, data_name: str) -> np.ndarray | None:
        return self._from_owner(lambda: self.local.initial_data(data_name))

    def jacobian(self) -> Mapping[tuple[str, str], np.ndarray]:
        """The real participant's ``jacobian()`` (coupling.linearization), on every rank."""
        if not self._has["jacobian"]:
            raise TypeError(f"participant {self.name!r} has no jacobian()")
        return self._from_owner(lambda: self.local.jacobian())

    def jacobian_key(self) -> Any:
        """The real participant's ``jacobian_key()`` (None if it has none), on every rank."""
        return self._from_owner(lambda: self.local.jacobian_key()) if self._has["jacobian_key"] else None

    def _from_owner(self, compute: Callable[[], Any]) -> Any:
        return self.distribution.from_owner(self.name, compute)

    # ------------------------------------------------------------------ solve
    def solve(self, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Solve in the group and share the outputs (collective: a serial scheme's turn)."""
        self.start(inputs)
        return self.finish()

    def start(self, inputs: dict[str, np.ndarray]) -> None:
        """Solve the real participant on its group (nothing elsewhere); :meth:`finish` shares the outputs."""
        if self.local is None:
            return
        began = _time.perf_counter()
        self._pending = _run_in_group(self.distribution.group_comm, lambda: self._solve_local(inputs))
        self._elapsed = _time.perf_counter() - began

    def _solve_local(self, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        if self._window is not None and uses_advance(self.local):
            self.local.advance(*self._window)       # the earlier protocol: before every solve
        outputs = self.local.solve(inputs)
        if self.check_replicated:
            _check_group_replicated(self.distribution.group_comm, self.name, outputs)
        return outputs

    def finish(self) -> dict[str, np.ndarray]:
        """The outputs of the last :meth:`start`, on every rank (collective on the world).

        Raises:
            ParticipantGroupError: On every rank, if the participant raised in its group.
        """
        outcome = None
        if self.local is not None:
            outcome, self._pending = (self._pending, self._elapsed), None
        (result, self.elapsed) = self.distribution.world.bcast(outcome, root=self.distribution.root(self.name))
        if result[0] == "ok":
            return result[1]
        raise ParticipantGroupError(f"{result[1]}: {result[2]} (in the process group "
                                    f"{'+'.join(self.distribution.members[self.distribution.owners[self.name]])})")

    # ------------------------------------------------------------------ lifecycle and states (local)
    def initialize(self) -> None:
        if self.local is not None:
            self.local.initialize()

    def begin_window(self, t: float, dt: float) -> None:
        self._window = (t, dt)
        if self.local is not None and not uses_advance(self.local):
            self.local.begin_window(t, dt)

    def end_window(self, accepted: dict[str, np.ndarray]) -> None:
        if self.local is not None:
            self.local.end_window(accepted)

    def finalize(self) -> None:
        self._window = None
        if self.local is not None:
            self.local.finalize()

    def save_state(self) -> Any:
        if not self._has["save_state"]:
            raise NotImplementedError(f"participant {self.name!r} does not implement save_state()")
        return self.local.save_state() if self.local is not None else None

    def load_state(self, state: Any) -> None:
        if not self._has["load_state"]:
            raise NotImplementedError(f"participant {self.name!r} does not implement load_state()")
        if self.local is not None:
            self.local.load_state(state)

    def checkpoint_state(self) -> Any:
        return self.local.checkpoint_state() if self.local is not None else None

    def load_checkpoint_state(self, state: Any) -> None:
        if self.local is not None:
            self.local.load_checkpoint_state(state)


def _implements(participant: Participant | None, method: str) -> bool:
    """Whether ``participant``'s class overrides ``method`` of :class:`Participant`."""
    return participant is not None and getattr(type(participant), method) is not getattr(Participant, method)


def _check_group_replicated(group_comm: Any, name: str, outputs: Mapping[str, Any]) -> None:
    """RuntimeError if ``outputs`` differ between the ranks of the group."""
    if group_comm.Get_size() == 1 or not isinstance(outputs, Mapping):
        return
    for key in sorted(outputs):
        arr = np.ascontiguousarray(outputs[key])
        if len(set(group_comm.allgather((arr.shape, hashlib.sha1(arr.tobytes()).hexdigest())))) > 1:
            raise RuntimeError(f"participant {name!r} returned different values of {key!r} on different "
                               f"ranks of its group; outputs must be replicated (coupling.parallel.gather_rows)")
