"""Coupling schemes: serial (Gauss–Seidel) and parallel (Jacobi), implicit and explicit.

A scheme owns the current value of every coupling data (on its writer's
points) and runs the participants:

* **Serial** schemes run the participants in the configured ``order``; each
  reads the newest values.  A data is *backward* if some reader precedes its
  writer in the order (it is read before it is written within a sweep); the
  backward data form the fixed-point vector ``x`` that is accelerated.  In
  each sweep all readers of a backward data that precede its writer read the
  (accelerated) ``x``; readers after the writer read the fresh value.
  Forward data are always used fresh; their residual is the change since the
  previous iteration.
* **Parallel** schemes run every participant on the same values (those of
  the previous iteration); ``x`` is the vector of *all* exchanged data.
* **Implicit** schemes iterate each window until the convergence measures are
  met; **explicit** schemes do one sweep per window.

Time-dependent runs (:meth:`CouplingScheme.run`) split ``[t, t_end]`` into
windows of length ``dt``.  Each window starts with every participant's
``begin_window(t, dt)``; in an implicit scheme every participant's state is
then saved (``save_state``) and restored (``load_state``) before every
further iteration (``state_reload = "iteration"``, the default; with
``"window"`` each solve continues from the previous iteration's state and
states are restored only when a window is retaken); an accepted window ends
with every participant's ``end_window(accepted)`` (the call sequence:
:class:`coupling.participant.Participant`).  The initial
guess of a window is the last value of the previous one (constant
extrapolation; ``extrapolation_order = 1``: linear, ``2``: quadratic, from the last
two or three windows).  A window keeps, for its accelerated data, the last
values the participants wrote (``x̃``, ``accepted_value = "output"``) or read
(``x``, ``"input"``).

With a residual ``r = x̃ - x``, the iteration stops with
:class:`CouplingDivergedError` if a data's values or residual are not finite,
or if ``‖r_k‖ > divergence_factor * max(‖r_1‖, 1e-6 ‖x̃_1‖)`` for a data.

MPI: all arrays are replicated on every rank; after each iteration the next
iterate and the decision (continue, converged, diverged) are broadcast from
rank 0 so that every rank takes the same decision.  With a ``distribution``
(:mod:`coupling.distributed`) each participant runs in its own process
group and its outputs are broadcast from there; a parallel scheme solves
all groups before it exchanges their outputs.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import math
import os
import sys
import time as _time
from typing import Any, Mapping, Sequence, TextIO

import numpy as np

from coupling.acceleration import Acceleration, build_acceleration
from coupling.config import CouplingConfig, load_config
from coupling.convergence import ConvergenceMeasure, MeasureValue, build_measure
from coupling.distributed import Distribution, GroupParticipant, ParticipantGroupError
from coupling.errors import CouplingDivergedError, CouplingNotConvergedError
from coupling.extrapolation import lagrange_weights
from coupling.layout import VectorLayout
from coupling.linearization import LinearizedPrior
from coupling.mapping import Mapping as DataMapping
from coupling.mapping import as_points, build_mapping
from coupling.parallel import default_comm
from coupling.participant import Data, Participant, uses_advance
from coupling.records import (CouplingResult, IterationRecord, RecordedSolve, Recording,
                              WindowRecord, format_progress, write_records)
from coupling.serialization import decode_text, encode_text, load_npz, save_npz
from coupling.surface_mapping import participant_triangles, triangle_owner

__all__ = ["CouplingScheme", "SerialImplicitScheme", "ParallelImplicitScheme",
           "SerialExplicitScheme", "ParallelExplicitScheme", "build_scheme"]

_DIVERGENCE_VALUE_FLOOR = 1e-6
_CHECKPOINT_FORMAT = "coupling-checkpoint"
_CHECKPOINT_VERSION = 2


class CouplingScheme:
    """Base class of the coupling schemes (use :func:`build_scheme`).

    Args:
        config: A :class:`CouplingConfig` or a ``[coupling]`` table (dict).
        participants: The participants (a sequence, or a mapping name -> participant).
        data: The coupling data.
        comm: MPI communicator (default: :func:`coupling.parallel.default_comm`,
            ``MPI.COMM_WORLD`` under MPI, else serial without importing mpi4py).
        stream: Where progress lines go (default: ``sys.stdout``).
        surrogate: Optional surrogate model of the same coupled problem for
            the quasi-Newton accelerations: an object with
            ``inverse_jacobian(r)`` (the prior ``J0 r`` on the accelerated
            vector, see :mod:`coupling.acceleration`), or a function of the
            scheme that returns one (for a surrogate that needs the scheme's
            points and layout, e.g. :meth:`coupling.CoarseSurrogate.on_surfaces`).
            Its prediction, if any, is given with :meth:`set_values`.
        distribution: Participants in separate process groups
            (:class:`coupling.distributed.Distribution`): ``participants``
            are then this rank's group's only, and the scheme runs on
            ``distribution.world`` (``comm`` must be it or ``None``).

    Attributes:
        config: The validated configuration.
        order: Participant names in execution order.
        data: Data name -> :class:`Data`.
        accelerated: Names of the data in the fixed-point vector ``x``.
        layout: Layout of ``x``.
        acceleration: The :class:`Acceleration`.
        time: Start of the next time window.
        window: Index of the next window.
        history: Records of every window run since construction (a checkpoint carries them).
        recording: The :class:`Recording` if ``record_data`` is set, else ``None``.
        result: The result of the last :meth:`solve` / :meth:`run`.
    """

    scheme_name = ""
    serial = True
    implicit = True

    def __init__(self, config: CouplingConfig | Mapping[str, Any],
                 participants: Sequence[Participant] | Mapping[str, Participant],
                 data: Sequence[Data], comm: Any = None, stream: TextIO | None = None,
                 surrogate: Any = None, distribution: Distribution | None = None):
        if isinstance(config, Mapping) and "scheme" not in config:
            config = {**config, "scheme": self.scheme_name}
        self.config = load_config(config)
        if self.config.scheme != self.scheme_name:
            raise ValueError(f"coupling.scheme = {self.config.scheme!r} does not match "
                             f"{type(self).__name__} ({self.scheme_name!r}); use build_scheme()")
        self.distribution = distribution
        self.comm = self._world(comm)
        self._stream = stream
        if distribution is not None:
            participants = distribution.wrap(self._check_participants(participants).values(),
                                             self.config.check_replicated)
        self.participants = self._check_participants(participants)
        self.order = self._check_order()
        self.data = self._check_data(data)
        self._reads = {p: [d.name for d in self.data.values() if p in d.readers] for p in self.order}
        self._writes = {p: [d.name for d in self.data.values() if d.writer == p] for p in self.order}
        self._points: dict[tuple[str, str], np.ndarray] = {}
        self._mappings = self._build_mappings()
        self.values: dict[str, np.ndarray] = {name: self._initial_value(d)
                                              for name, d in self.data.items()}
        self.accelerated = self._accelerated_data()
        self.layout = VectorLayout(self.accelerated,
                                   [self.values[n].shape for n in self.accelerated])
        self.acceleration: Acceleration = build_acceleration(self.config.acceleration, self.layout)
        self._attach_prior(surrogate)
        self.measures = self._build_measures()
        self.time = 0.0
        self.window = 0
        # converged values at the end of the last windows, with their times (extrapolation)
        self.window_ends: list[tuple[float, dict[str, np.ndarray]]] = []
        self.history: list[WindowRecord] = []
        self._encoded_history: list[tuple[WindowRecord, str]] = []     # (record, its text) for checkpoints
        self.recording: Recording | None = Recording() if self.config.record_data else None
        self.result: CouplingResult | None = None
        self._initialized = False      # initialize() called, finalize() not yet

    # ------------------------------------------------------------------ setup checks
    def _world(self, comm: Any) -> Any:
        """The communicator the scheme runs on: ``comm``, or the distribution's world."""
        if self.distribution is None:
            if self.config.distribute:
                raise ValueError(f"coupling.distribute = {self.config.distribute!r}: pass build_scheme the "
                                 f"coupling.Distribution of it and this rank's group's participants")
            return default_comm() if comm is None else comm
        if comm is not None and comm is not self.distribution.world:
            raise ValueError("build_scheme: with a distribution the scheme runs on distribution.world; "
                             "pass comm=None or that communicator")
        return self.distribution.world

    def _check_participants(self, participants: Any) -> dict[str, Participant]:
        items = list(participants.values()) if isinstance(participants, Mapping) else list(participants)
        if not items:
            raise ValueError("build_scheme: no participants given")
        out: dict[str, Participant] = {}
        for p in items:
            if not isinstance(p, Participant):
                raise TypeError(f"participant {p!r} is not a coupling.Participant")
            name = getattr(p, "name", "")
            if not isinstance(name, str) or not name:
                raise ValueError(f"participant {p!r} has no name (set the attribute 'name')")
            if name in out:
                raise ValueError(f"two participants are named {name!r}; names must be unique")
            out[name] = p
        if isinstance(participants, Mapping):
            for key, p in participants.items():
                if key != p.name:
                    raise ValueError(f"participant mapping key {key!r} differs from its name {p.name!r}")
        return out

    def _check_order(self) -> tuple[str, ...]:
        names = tuple(self.participants)
        order = self.config.order or names
        unknown = [o for o in order if o not in self.participants]
        if unknown:
            raise ValueError(f"coupling.order = {list(order)!r} names unknown participants "
                             f"{unknown}; participants: {list(names)}")
        missing = [n for n in names if n not in order]
        if missing:
            raise ValueError(f"coupling.order = {list(order)!r} misses participants {missing}")
        return tuple(order)

    def _check_data(self, data: Sequence[Data]) -> dict[str, Data]:
        out: dict[str, Data] = {}
        for d in data:
            if not isinstance(d, Data):
                raise TypeError(f"{d!r} is not a coupling.Data")
            if d.name in out:
                raise ValueError(f"two data are named {d.name!r}; names must be unique")
            for who in (d.writer,) + d.readers:
                if who not in self.participants:
                    raise ValueError(f"data {d.name!r} names participant {who!r}, which is not "
                                     f"among the participants {list(self.participants)}")
            out[d.name] = d
        if not out:
            raise ValueError("build_scheme: no coupling data given")
        return out

    def _build_mappings(self) -> dict[tuple[str, str], DataMapping]:
        """The mapping of every data to each of its readers, between the participants' points."""
        mappings: dict[tuple[str, str], DataMapping] = {}
        for d in self.data.values():
            writer_points = self.points(d.writer, d.mesh)
            for reader in d.readers:
                mappings[(d.name, reader)] = build_mapping(
                    d.mapping, writer_points, self.points(reader, d.mesh), data_name=d.name,
                    reader=reader, curve=d.curve, curve_order=d.curve_order,
                    triangles=self._triangles(d, reader))
        return mappings

    def _triangles(self, d: Data, reader: str) -> np.ndarray | None:
        """The triangles a surface mapping of ``d`` to ``reader`` projects onto (``None`` for the others)."""
        owner = triangle_owner(d.mapping, d.writer, reader)
        if owner is None:
            return None
        what = f"data {d.name!r} (reader {reader!r}, mapping {d.mapping!r})"
        tri = participant_triangles(self.participants[owner], d.mesh, what)
        if self.config.check_replicated:
            self._check_replicated(owner, {f"interface_triangles({d.mesh!r})": tri})
        return tri

    def _attach_prior(self, surrogate: Any) -> None:
        """Give the quasi-Newton acceleration its prior: the linearized one, or the ``surrogate``."""
        if self.config.acceleration.jacobian_prior == "linearized":
            if surrogate is not None:
                raise ValueError("coupling.acceleration.jacobian_prior = 'linearized' is itself the prior: "
                                 "do not pass a surrogate as well")
            # the participants' linearisations, composed along this scheme's sweep (coupling.linearization)
            surrogate = LinearizedPrior(self)
        if surrogate is not None and not hasattr(surrogate, "inverse_jacobian") and callable(surrogate):
            surrogate = surrogate(self)                 # a factory of the scheme's surrogate
        if surrogate is not None:
            if not hasattr(self.acceleration, "surrogate"):
                raise ValueError(f"a surrogate needs a quasi-Newton acceleration (iqn-ils, iqn-imvj), "
                                 f"not {self.config.acceleration.type!r}")
            if not callable(getattr(surrogate, "inverse_jacobian", None)):
                raise TypeError("surrogate must have a method inverse_jacobian(r)")
            self.acceleration.surrogate = surrogate

    def points(self, participant: str, mesh: str) -> np.ndarray:
        """The interface points of ``participant`` on ``mesh`` (cached, read-only copy)."""
        key = (participant, mesh)
        if key not in self._points:
            raw = self.participants[participant].interface_points(mesh)
            pts = np.array(as_points(raw, f"participant {participant!r}: interface_points({mesh!r})"))
            if self.config.check_replicated:
                self._check_replicated(participant, {f"interface_points({mesh!r})": pts})
            pts.setflags(write=False)
            self._points[key] = pts
        return self._points[key]

    def _shape(self, name: str) -> tuple[int, int]:
        d = self.data[name]
        return (self.points(d.writer, d.mesh).shape[0], d.dim)

    def _as_data_array(self, name: str, value: Any, what: str) -> np.ndarray:
        shape = self._shape(name)
        arr = np.array(value, dtype=float)
        if arr.shape == shape[:1] and shape[1] == 1:
            arr = arr.reshape(shape)
        if arr.shape != shape:
            raise ValueError(f"{what}: data {self.data[name].name!r} must have shape {shape} "
                             f"(writer points x dim), got {arr.shape}")
        return arr

    def _initial_value(self, d: Data) -> np.ndarray:
        value = self.participants[d.writer].initial_data(d.name)
        if value is None:
            return np.zeros(self._shape(d.name))
        return self._as_data_array(d.name, value, f"participant {d.writer!r}: initial_data")

    def _accelerated_data(self) -> tuple[str, ...]:
        if not self.implicit:
            return ()
        if not self.serial:
            return tuple(self.data)
        pos = {name: i for i, name in enumerate(self.order)}
        return tuple(name for name, d in self.data.items()
                     if any(pos[r] < pos[d.writer] for r in d.readers))

    def _build_measures(self) -> list[ConvergenceMeasure]:
        measures: list[ConvergenceMeasure] = []
        for i, m in enumerate(self.config.convergence):
            if m.data == "*":
                targets = list(self.data)
            elif m.data == "accelerated":
                targets = list(self.accelerated) if self.implicit else list(self.data)
            elif m.data in self.data:
                targets = [m.data]
            else:
                raise ValueError(f"coupling.convergence[{i}].data = {m.data!r} is not a coupling "
                                 f"data; allowed values: '*', 'accelerated', "
                                 f"{', '.join(repr(n) for n in self.data)}")
            measures += [build_measure(m.type, name, m.limit, m.suffices) for name in targets]
        if self.implicit and not measures:
            raise ValueError("coupling.convergence: an implicit scheme needs at least one "
                             "convergence measure ([[coupling.convergence]] with type and limit)")
        return measures

    # ------------------------------------------------------------------ helpers
    def latest(self, data_name: str) -> np.ndarray:
        """Latest value of a data on its writer's points (a copy), shape ``(N, dim)``."""
        if data_name not in self.data:
            raise KeyError(f"unknown data {data_name!r}; data: {list(self.data)}")
        return self.values[data_name].copy()

    def mapped(self, data_name: str, reader: str) -> np.ndarray:
        """Latest value of a data mapped onto ``reader``'s points."""
        return self._mappings[(data_name, reader)](self.values[data_name])

    def mapping(self, data_name: str, reader: str) -> DataMapping:
        """The :class:`coupling.mapping.Mapping` of a data to one reader."""
        return self._mappings[(data_name, reader)]

    def _is_root(self) -> bool:
        return self.comm.Get_rank() == 0

    def _print(self, line: str) -> None:
        if self.config.verbose and self._is_root():
            print(line, file=self._stream if self._stream is not None else sys.stdout, flush=True)

    def _call(self, participant: str, method: str, *args: Any) -> Any:
        try:
            return getattr(self.participants[participant], method)(*args)
        except NotImplementedError as exc:
            raise TypeError(f"participant {participant!r} must implement {method}() for "
                            f"time-dependent {'implicit' if self.implicit else 'explicit'} coupling "
                            f"({exc})") from exc

    def _check_replicated(self, participant: str, outputs: dict[str, np.ndarray]) -> None:
        if self.comm.Get_size() == 1:
            return
        for name, arr in outputs.items():
            digest = hashlib.sha1(np.ascontiguousarray(arr).tobytes()).hexdigest()
            digests = self.comm.allgather((arr.shape, digest))
            if len(set(digests)) > 1:
                raise RuntimeError(f"participant {participant!r} returned different values of "
                                   f"{name!r} on different MPI ranks; interface points and outputs "
                                   f"must be replicated (use coupling.parallel.gather_rows)")

    def _solve_participant(self, name: str, window: int, iteration: int, t: float | None,
                           dt: float | None, states: dict[str, Any],
                           solve_time: dict[str, float]) -> dict[str, np.ndarray]:
        inputs = self._participant_inputs(name, iteration, t, dt, states)
        start = _time.perf_counter()
        try:
            raw = self.participants[name].solve(inputs)
        except Exception as exc:  # noqa: BLE001  (any solver failure ends the coupling cleanly)
            raise _ParticipantFailure(name, iteration, exc) from exc
        # distributed: the owner group's time, the same on every rank
        participant = self.participants[name]
        solve_time[name] = (participant.elapsed if isinstance(participant, GroupParticipant)
                            else _time.perf_counter() - start)
        return self._participant_outputs(name, window, iteration, t, dt, inputs, raw)

    def _participant_inputs(self, name: str, iteration: int, t: float | None, dt: float | None,
                            states: dict[str, Any]) -> dict[str, np.ndarray]:
        """Restore ``name``'s window state where needed and return its inputs on its points."""
        if t is not None:
            if self.implicit and iteration > 1 and self.config.state_reload == "iteration":
                self._call(name, "load_state", states[name])
            if uses_advance(self.participants[name]):    # the earlier protocol: before every solve
                self._call(name, "advance", t, dt)
        return {d: self._mappings[(d, name)](self.values[d]) for d in self._reads[name]}

    def _participant_outputs(self, name: str, window: int, iteration: int, t: float | None,
                             dt: float | None, inputs: dict[str, np.ndarray],
                             raw: Any) -> dict[str, np.ndarray]:
        """Check what ``name``'s solve returned and record it; its outputs as data arrays."""
        recorded_inputs = {k: v.copy() for k, v in inputs.items()} if self.recording else None
        if not isinstance(raw, Mapping):
            raise TypeError(f"participant {name!r}: solve() must return a dict data name -> array, "
                            f"got {type(raw).__name__}")
        expected = set(self._writes[name])
        if set(raw) != expected:
            raise ValueError(f"participant {name!r}: solve() returned data {sorted(raw)} but must "
                             f"return exactly the data it writes: {sorted(expected)}")
        outputs = {d: self._as_data_array(d, raw[d], f"participant {name!r}: solve()")
                   for d in self._writes[name]}
        if self.config.check_replicated and self.distribution is None:   # distributed: in the group
            self._check_replicated(name, outputs)
        if self.recording is not None:
            self.recording.add(RecordedSolve(window, iteration, name, t, dt, recorded_inputs, outputs))
        return outputs

    def _sweep(self, window: int, iteration: int, t: float | None, dt: float | None,
               states: dict[str, Any]) -> dict[str, float]:
        solve_time: dict[str, float] = {}
        if self.distribution is not None and not self.serial:
            self.values.update(self._concurrent_sweep(window, iteration, t, dt, states, solve_time))
        elif self.serial:
            for name in self.order:
                outputs = self._solve_participant(name, window, iteration, t, dt, states, solve_time)
                self.values.update(outputs)
        else:
            new_values: dict[str, np.ndarray] = {}
            for name in self.order:
                new_values.update(self._solve_participant(name, window, iteration, t, dt, states,
                                                          solve_time))
            self.values.update(new_values)
        return solve_time

    def _concurrent_sweep(self, window: int, iteration: int, t: float | None, dt: float | None,
                          states: dict[str, Any], solve_time: dict[str, float]) -> dict[str, np.ndarray]:
        """A parallel sweep of distributed participants: every group solves its own from the same
        values, and only then are the outputs exchanged (so the groups compute at the same time)."""
        proxies: dict[str, GroupParticipant] = self.participants       # type: ignore[assignment]
        inputs = {name: self._participant_inputs(name, iteration, t, dt, states) for name in self.order}
        for name in self.order:
            proxies[name].start(inputs[name])
        new_values: dict[str, np.ndarray] = {}
        failure: _ParticipantFailure | None = None
        for name in self.order:                 # every rank takes part in every exchange
            try:
                raw = proxies[name].finish()
            except ParticipantGroupError as exc:
                failure = failure or _ParticipantFailure(name, iteration, exc)
                continue
            solve_time[name] = proxies[name].elapsed
            new_values.update(self._participant_outputs(name, window, iteration, t, dt, inputs[name], raw))
        if failure is not None:
            raise failure
        return new_values

    # ------------------------------------------------------------------ one window
    def _measure_values(self, evals: list[MeasureValue], rnorm: dict[str, float],
                        vnorm: dict[str, float]) -> dict[str, float]:
        out: dict[str, float] = {}
        for m in evals:
            out.setdefault(m.data, m.value)
        for name in self.data:
            if name not in out:
                out[name] = 0.0 if rnorm[name] == 0.0 else (
                    rnorm[name] / vnorm[name] if vnorm[name] > 0.0 else math.inf)
        return {name: out[name] for name in self.data}

    def _divergence(self, k: int, rnorm: dict[str, float], vnorm: dict[str, float],
                    first_r: dict[str, float], first_v: dict[str, float]) -> str | None:
        factor = self.config.divergence_factor
        for name in self.data:
            if not (math.isfinite(rnorm[name]) and math.isfinite(vnorm[name])):
                return f"data {name!r} is not finite (NaN/Inf) in iteration {k}"
        worst, worst_growth, worst_ref = None, 0.0, 0.0
        for name in self.data:
            ref = max(first_r[name], _DIVERGENCE_VALUE_FLOOR * first_v[name])
            if ref > 0.0 and rnorm[name] > factor * ref:
                growth = rnorm[name] / ref
                if growth > worst_growth:
                    worst, worst_growth, worst_ref = name, growth, ref
        if worst is not None:
            return (f"residual of data {worst!r} grew to {rnorm[worst]:.3e}, {worst_growth:.3e} "
                    f"times its reference {worst_ref:.3e} (divergence_factor {factor:g}) "
                    f"in iteration {k}")
        return None

    def _history_text(self, rec: WindowRecord, name: str, norms: bool = False) -> str:
        values = [r.residual_norms[name] if norms else r.measure_values[name] for r in rec.records]
        shown = values if len(values) <= 12 else values[:4] + ["..."] + values[-7:]
        return "[" + ", ".join(v if isinstance(v, str) else f"{v:.2e}" for v in shown) + "]"

    def _where(self, rec: WindowRecord) -> str:
        if rec.time is None:
            return "steady solve"
        return f"window {rec.window} (t = {rec.time:.6g}, dt = {rec.dt:.3g})"

    def _not_converged_message(self, rec: WindowRecord) -> str:
        last = rec.records[-1]
        unmet = [m for m in last.measures if not m.met]
        worst = max(unmet, key=lambda m: m.ratio) if unmet else None
        text = (f"coupling did not converge in {rec.iterations} iterations "
                f"(max_iterations) in the {self._where(rec)}")
        if worst is not None:
            text += (f"; worst data {worst.data!r}: {worst.kind} measure {worst.value:.3e} > limit "
                     f"{worst.limit:.1e}; its history: {self._history_text(rec, worst.data)}")
        return text

    def _diverged_message(self, rec: WindowRecord, reason: str) -> str:
        name = None
        for candidate in self.data:
            if f"data {candidate!r}" in reason:
                name = candidate
                break
        text = f"coupling diverged in the {self._where(rec)}: {reason}"
        if name is None and rec.records:
            # e.g. a participant failed: report the data that was worst at the last iteration
            last = rec.records[-1].measure_values
            name = max(last, key=lambda n: last[n]) if last else None
        if name is not None:
            text += (f"; residual norms of {name!r}: {self._history_text(rec, name, norms=True)}"
                     f"; its convergence measure: {self._history_text(rec, name)}")
        return text

    def _extrapolate(self, t: float, dt: float) -> None:
        """The initial guess of the window [t, t + dt]: the Lagrange polynomial through the last
        ``extrapolation_order + 1`` windows' end values (fewer at the start) evaluated at t + dt."""
        ends = self.window_ends[-(self.config.extrapolation_order + 1):]
        if len(ends) < 2 or abs(ends[-1][0] - t) > 1e-12 * max(abs(t), dt):
            return
        times = [te for te, _ in ends]
        if any(b <= a for a, b in zip(times[:-1], times[1:])):
            return
        weights = lagrange_weights(times, t + dt)
        self.values = {n: sum(w * v[n] for w, (_, v) in zip(weights, ends)) for n in self.values}

    def _window_end(self, t_end: float) -> None:
        kept = max(self.config.extrapolation_order + 1, 2)
        self.window_ends = (self.window_ends + [(t_end, {n: v.copy() for n, v in self.values.items()})])[-kept:]

    def _run_window(self, t: float | None, dt: float | None) -> WindowRecord:
        """Iterate one time window (``t is None``: a steady solve) until its status ends it."""
        transient = t is not None
        rec = WindowRecord(window=self.window, time=t, dt=dt)
        self._initialize()
        if transient:
            self._initial_guess(t, dt)
            self._begin_window(t, dt)
        states = self._save_window_states(transient)
        x = self.layout.concat(self.values)
        first_r: dict[str, float] = {}
        first_v: dict[str, float] = {}
        max_iterations = self.config.max_iterations if self.implicit else 1
        for k in range(1, max_iterations + 1):
            before = {n: v.copy() for n, v in self.values.items()}
            try:
                solve_time = self._sweep(self.window, k, t, dt, states)
            except _ParticipantFailure as failure:
                self._participant_failed(rec, k, failure)
                return rec
            rnorm = {n: float(np.linalg.norm(self.values[n] - before[n])) for n in self.data}
            vnorm = {n: float(np.linalg.norm(self.values[n])) for n in self.data}
            if k == 1:
                first_r, first_v = dict(rnorm), dict(vnorm)
            evals = [m.evaluate(rnorm[m.data], vnorm[m.data], first_r[m.data]) for m in self.measures]
            itrec = IterationRecord(window=self.window, iteration=k, time=t, dt=dt,
                                    residual_norms=rnorm, value_norms=vnorm,
                                    measure_values=self._measure_values(evals, rnorm, vnorm),
                                    measures=evals, solve_time=solve_time)
            rec.records.append(itrec)
            rec.iterations = k
            status = self._status(k, evals, rnorm, vnorm, first_r, first_v)
            if self.comm.Get_size() > 1:
                status = self.comm.bcast(status, root=0)
            if status != "continue" or k == max_iterations:
                self._end_window(rec, itrec, status, x, transient)
                return rec
            x = self._accelerate(x, itrec, transient)
        return rec

    def _initial_guess(self, t: float, dt: float) -> None:
        """Extrapolate the values from the last windows' ends (the initial values are the start time's)."""
        if not self.window_ends:
            self._window_end(t)
        self._extrapolate(t, dt)

    def _initialize(self) -> None:
        """Call every participant's ``initialize()`` before the first window (or the first after finalize)."""
        if not self._initialized:
            for name in self.order:
                self.participants[name].initialize()
            self._initialized = True

    def _begin_window(self, t: float, dt: float) -> None:
        """Call ``begin_window(t, dt)`` once on every participant but those of the earlier protocol."""
        for name in self.order:
            if not uses_advance(self.participants[name]):
                self.participants[name].begin_window(t, dt)

    def _accept_window(self, x: np.ndarray) -> None:
        """Keep the window's ``accepted_value`` and tell every participant (``end_window``)."""
        if self.config.accepted_value == "input" and self.layout.size:
            self.values.update(self.layout.split(x))    # what the last sweep read
        for name in self.order:
            accepted = {d: self.mapped(d, name) for d in self._reads[name]}
            accepted.update({d: self.values[d].copy() for d in self._writes[name]})
            self.participants[name].end_window(accepted)

    def finalize(self) -> None:
        """Call every participant's ``finalize()`` (:meth:`solve` and :meth:`run` do it when they return).

        Call it after the last :meth:`advance_window`.  A later window calls
        ``initialize()`` again.
        """
        if self._initialized:
            for name in self.order:
                self.participants[name].finalize()
            self._initialized = False

    def _save_window_states(self, transient: bool) -> dict[str, Any]:
        """Every participant's state at the window start, if it is restored or recorded."""
        states: dict[str, Any] = {}
        if transient and self.implicit and (self.config.state_reload == "iteration" or self.recording is not None):
            for name in self.order:
                states[name] = self._call(name, "save_state")
                if self.recording is not None:
                    self.recording.checkpoints[(self.window, name)] = states[name]
        return states

    def _participant_failed(self, rec: WindowRecord, k: int, failure: _ParticipantFailure) -> None:
        """End the window as diverged because a participant's solve raised in iteration ``k``."""
        rec.reason = (f"diverged: participant {failure.participant!r} failed in iteration "
                      f"{failure.iteration} ({type(failure.error).__name__}: {failure.error})")
        rec.participant_error = failure.error     # the cause of the CouplingDivergedError
        self._print(f"it {k:3d}  participant {failure.participant!r} FAILED: {failure.error}")

    def _end_window(self, rec: WindowRecord, itrec: IterationRecord, status: str, x: np.ndarray,
                    transient: bool) -> None:
        """Close the window on its last iteration: converged, explicit, diverged or out of iterations."""
        if status.startswith("diverged"):
            rec.reason = status
            self._print(format_progress(itrec, transient) + "  DIVERGED")
        elif status == "continue":
            rec.reason = "max_iterations"
            self._print(format_progress(itrec, transient) + "  max iterations reached")
            if self.config.on_max_iterations == "continue":
                self._close_acceleration_window(rec, x)
                self._accept_window(x)
        else:
            itrec.converged = True
            rec.converged, rec.reason = True, status
            if status == "converged":
                self._close_acceleration_window(rec, x)
            self._print(format_progress(itrec, transient))
            self._accept_window(x)

    def _close_acceleration_window(self, rec: WindowRecord, x: np.ndarray) -> None:
        """Give the acceleration the window's last iterate; record the columns it keeps and drops."""
        self.acceleration.window_converged(x, self.layout.concat(self.values))
        rec.columns_dropped_at_end = self.acceleration.window_info.columns_dropped
        rec.columns_kept = self.acceleration.columns[0].shape[1]

    def _accelerate(self, x: np.ndarray, itrec: IterationRecord, transient: bool) -> np.ndarray:
        """The next iterate (rank 0's on every rank), which becomes the current values."""
        x_tilde = self.layout.concat(self.values)
        x_next = self.acceleration.compute(x, x_tilde)
        if self.comm.Get_size() > 1:
            x_next = np.ascontiguousarray(x_next, dtype=float)
            self.comm.Bcast(x_next, root=0)
        info = self.acceleration.info
        itrec.relaxation = info.relaxation
        itrec.columns_used = info.columns_used
        itrec.columns_filtered = info.columns_filtered
        itrec.columns_dropped = info.columns_dropped
        self._print(format_progress(itrec, transient))
        self.values.update(self.layout.split(x_next))
        return x_next

    def _status(self, k: int, evals: list[MeasureValue], rnorm: dict[str, float],
                vnorm: dict[str, float], first_r: dict[str, float],
                first_v: dict[str, float]) -> str:
        diverged = self._divergence(k, rnorm, vnorm, first_r, first_v)
        if diverged is not None:
            return "diverged: " + diverged
        if not self.implicit:
            return "explicit"
        if k < self.config.min_iterations:
            return "continue"
        if self.layout.size == 0:
            return "converged"  # no backward data: one sweep is exact
        if all(m.met for m in evals) or any(m.met and m.suffices for m in evals):
            return "converged"
        return "continue"

    def _finish_window(self, rec: WindowRecord, windows: list[WindowRecord]) -> bool:
        """Book-keep a finished window; raise on failure; return False to stop the run."""
        self.history.append(rec)
        windows.append(rec)
        if rec.reason.startswith("diverged"):
            self.result = CouplingResult.from_windows(windows, list(self.data), reason=rec.reason)
            raise CouplingDivergedError(self._diverged_message(rec, rec.reason[len("diverged: "):]),
                                        self.result) from getattr(rec, "participant_error", None)
        if not rec.converged:
            policy = self.config.on_max_iterations
            if policy == "raise":
                self.result = CouplingResult.from_windows(windows, list(self.data))
                raise CouplingNotConvergedError(self._not_converged_message(rec), self.result)
            if policy == "return":
                return False
        return True

    # ------------------------------------------------------------------ public drivers
    def solve(self) -> CouplingResult:
        """Iterate a steady problem to convergence (one window, no time level).

        Returns:
            The :class:`CouplingResult`.

        Raises:
            CouplingDivergedError: On NaN/Inf or residual growth.
            CouplingNotConvergedError: If ``max_iterations`` are reached and
                ``on_max_iterations = "raise"``.
        """
        windows: list[WindowRecord] = []
        rec = self._run_window(None, None)
        self.window += 1
        self._finish_window(rec, windows)
        self.result = CouplingResult.from_windows(windows, list(self.data))
        self.finalize()
        return self.result

    def run(self, t_end: float, dt: float) -> CouplingResult:
        """Advance from :attr:`time` to ``t_end`` in windows of length ``dt``.

        ``t_end - time`` must be a whole multiple of ``dt`` (relative
        tolerance 1e-9).  Implicit schemes iterate every window to convergence
        with checkpoint/restore of the participants' states.

        Returns:
            The :class:`CouplingResult` of the windows run in this call.

        Raises:
            ValueError: If ``dt`` or ``t_end`` are invalid.
            CouplingDivergedError: On NaN/Inf or residual growth.
            CouplingNotConvergedError: If a window reaches ``max_iterations`` and
                ``on_max_iterations = "raise"``.
        """
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"run: dt = {dt!r} must be a positive number")
        span = float(t_end) - self.time
        n = int(round(span / dt))
        if n < 1 or abs(n * dt - span) > 1e-9 * max(abs(span), dt):
            raise ValueError(f"run: t_end - time = {t_end} - {self.time} = {span} must be a positive "
                             f"whole multiple of dt = {dt}")
        windows: list[WindowRecord] = []
        for _ in range(n):
            if not self._advance(dt, windows):
                break
        self.result = CouplingResult.from_windows(windows, list(self.data))
        self.finalize()
        return self.result

    def advance_window(self, dt: float) -> WindowRecord:
        """Run the one time window ``[time, time + dt]`` (any ``dt > 0``: variable steps).

        Returns:
            The :class:`WindowRecord`; :attr:`time` and :attr:`window` move on
            unless the window ended without convergence under
            ``on_max_iterations = "return"`` (then ``record.converged`` is False).

        Raises:
            ValueError: If ``dt`` is not a positive finite number.
            CouplingDivergedError, CouplingNotConvergedError: as :meth:`run`.
        """
        if isinstance(dt, bool) or not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"advance_window: dt = {dt!r} must be a positive number")
        windows: list[WindowRecord] = []
        self._advance(float(dt), windows)
        self.result = CouplingResult.from_windows(windows, list(self.data))
        return windows[-1]

    def _advance(self, dt: float, windows: list[WindowRecord]) -> bool:
        t = self.time
        rec = self._run_window(t, dt)
        if not self._finish_window(rec, windows):
            return False
        self.time = t + dt
        self.window += 1
        self._window_end(self.time)
        return True

    # ------------------------------------------------------------------ in-memory state
    def snapshot(self) -> dict[str, Any]:
        """A copy of everything a window changes: data values, acceleration, time, participants.

        :meth:`restore` returns the scheme (and every participant, through its
        ``save_state``/``load_state``) to this point, e.g. to repeat a time
        window with a smaller ``dt`` after an error estimate rejected it.
        """
        return {"values": {n: v.copy() for n, v in self.values.items()},
                "acceleration": copy.deepcopy(self.acceleration.state_dict()),
                "window_ends": copy.deepcopy(self.window_ends),
                "time": self.time, "window": self.window, "history": len(self.history),
                "participants": {name: self._call(name, "save_state") for name in self.order}}

    def restore(self, snapshot: Mapping[str, Any]) -> None:
        """Return to a :meth:`snapshot` (the window records after it are dropped)."""
        self.values = {n: v.copy() for n, v in snapshot["values"].items()}
        self.acceleration.load_state_dict(copy.deepcopy(snapshot["acceleration"]))
        self.window_ends = copy.deepcopy(snapshot["window_ends"])
        self.time, self.window = snapshot["time"], snapshot["window"]
        del self.history[snapshot["history"]:]
        for name, state in snapshot["participants"].items():
            self._call(name, "load_state", state)

    # ------------------------------------------------------------------ reuse across solves
    def set_values(self, values: Mapping[str, Any]) -> None:
        """Set the current value of some data (the initial guess of the next window or solve).

        Raises:
            KeyError: For an unknown data name.
            ValueError: For a wrong shape.
        """
        for name, value in values.items():
            if name not in self.data:
                raise KeyError(f"set_values: unknown data {name!r}; data: {list(self.data)}")
            self.values[name] = self._as_data_array(name, value, "set_values")

    @property
    def linearized_prior(self) -> LinearizedPrior | None:
        """The acceleration's prior if it is a :class:`LinearizedPrior` (``jacobian_prior = "linearized"``)."""
        prior = getattr(self.acceleration, "surrogate", None)
        return prior if isinstance(prior, LinearizedPrior) else None

    def reuse_state(self, participants: bool = False) -> dict[str, Any]:
        """What a later solve with the same interface operator can reuse (a copy).

        The converged value of every data (the next initial guess) and the
        acceleration's complete state: the kept secant columns (IQN-ILS keeps
        those of the last ``time_windows_reused`` solves or windows), the
        preconditioner weights, the IMVJ Jacobian.  With ``participants``,
        also every participant's ``save_state()`` (``None`` for one that does
        not implement it): a participant that continues from its previous
        state (e.g. a Newton solver's initial guess) starts from the old
        solution.  Load it into another scheme of the same data with
        :meth:`load_reuse_state`.
        """
        states: dict[str, Any] = {}
        if participants:
            for name in self.order:
                try:
                    states[name] = self.participants[name].save_state()
                except NotImplementedError:
                    states[name] = None
        prior = self.linearized_prior
        return {"data": list(self.data), "accelerated": list(self.accelerated),
                "shapes": {n: list(v.shape) for n, v in self.values.items()},
                "values": {n: v.copy() for n, v in self.values.items()},
                "acceleration": copy.deepcopy(self.acceleration.state_dict()),
                "participants": states,
                # the linearized prior's factorisation: the same interface operator, so the same prior
                "prior": prior.state() if prior is not None else None}

    def load_reuse_state(self, state: Mapping[str, Any], *, values: bool = True,
                         acceleration: bool = True, prior: bool = True, participants: bool = True,
                         scale: Mapping[str, float] | None = None) -> None:
        """Start from a :meth:`reuse_state` of a related problem (same data, same interface operator).

        Args:
            state: The exported state.
            values: Take its data values as the initial guess.
            acceleration: Take its quasi-Newton information (columns, weights).
            prior: Take its linearized prior's factorisation, if both schemes have
                one (not with ``scale``: the prior is in the old units).
            participants: Load the participant states it holds (``load_state``),
                if any; they must fit this scheme's participants (same
                discretisation).  Not rescaled.
            scale: ``{data: factor}``: the data are ``factor`` times the old
                ones in this problem's units (e.g. after a change of the unit
                of stress); values, secant columns and weights are rescaled
                accordingly.  Data not named keep factor 1.

        Raises:
            ValueError: If the data (names, shapes, accelerated set) differ.
        """
        self._check_reuse_state(state)
        factors = self._scale_factors(scale)
        if values:
            self.values = {n: factors[n] * np.asarray(state["values"][n], dtype=float).copy()
                           for n in self.data}
        if acceleration:
            acc = copy.deepcopy(state["acceleration"])
            _scale_acceleration_state(acc, self.layout, factors)
            self.acceleration.load_state_dict(acc)
        linearized = self.linearized_prior
        if prior and linearized is not None and state.get("prior") is not None \
                and all(f == 1.0 for f in factors.values()):
            linearized.load_state(state["prior"])
        if participants:
            for name, pstate in (state.get("participants") or {}).items():
                if name not in self.participants:
                    raise ValueError(f"load_reuse_state: state of unknown participant {name!r}")
                if pstate is not None:
                    self._call(name, "load_state", pstate)

    def _check_reuse_state(self, state: Mapping[str, Any]) -> None:
        """Refuse a :meth:`reuse_state` of other data (names, accelerated set or shapes)."""
        shapes = {n: list(v.shape) for n, v in self.values.items()}
        if list(state["data"]) != list(self.data) or list(state["accelerated"]) != list(self.accelerated) \
                or {n: list(s) for n, s in state["shapes"].items()} != shapes:
            raise ValueError(f"load_reuse_state: the state belongs to other data ({state['data']}, "
                             f"shapes {state['shapes']}); this scheme has {list(self.data)}, shapes {shapes}")

    def _scale_factors(self, scale: Mapping[str, float] | None) -> dict[str, float]:
        """Data name -> factor of :meth:`load_reuse_state`'s ``scale`` (1 for data not named)."""
        factors = {n: 1.0 for n in self.data}
        for name, f in (scale or {}).items():
            if name not in self.data:
                raise KeyError(f"load_reuse_state: scale names unknown data {name!r}")
            if not (math.isfinite(float(f)) and float(f) != 0.0):
                raise ValueError(f"load_reuse_state: scale[{name!r}] = {f!r} must be finite and nonzero")
            factors[name] = float(f)
        return factors

    # ------------------------------------------------------------------ records
    def write_records(self, directory: str | os.PathLike) -> dict[str, str]:
        """Write the iterations and convergence logs (CSV and JSON) of :attr:`history`.

        Only rank 0 writes; all ranks wait for it.  Returns the written paths.
        """
        paths: dict[str, str] = {}
        if self._is_root():
            paths = write_records(directory, self.history, list(self.data), list(self.order))
        self.comm.Barrier()
        return paths

    # ------------------------------------------------------------------ restart
    def save_checkpoint(self, path: str | os.PathLike, include_participants: bool = True,
                        extra: Any = None) -> None:
        """Save the coupling state so that a restarted run reproduces an uninterrupted one.

        Saved: time and window index, the current value of every data, the
        acceleration's complete state (columns, past windows, relaxation,
        preconditioner weights, inverse Jacobian), the window records (:attr:`history`) and, if
        ``include_participants``, each participant's ``checkpoint_state()`` on every
        rank (states must consist of numpy arrays, numbers, strings, lists,
        tuples and dicts; participants raising ``NotImplementedError`` are skipped),
        and ``extra``, the application's own state (same types; each rank's
        own value), which :meth:`load_checkpoint` returns on that rank.  Only rank 0 writes the ``.npz``
        file, under a temporary name first: an interrupted write never replaces
        a complete checkpoint.
        """
        state = self._checkpoint_state(include_participants, extra)
        error, failed = self._write_checkpoint(path, state) if self._is_root() else (None, None)
        if self.comm.Get_size() > 1:
            error, failed = self.comm.bcast((error, failed), root=0)
        self.comm.Barrier()
        if error is not None:
            raise TypeError(error)
        if failed is not None:
            raise OSError(*failed)

    def _checkpoint_state(self, include_participants: bool, extra: Any) -> dict:
        """What :meth:`save_checkpoint` writes; participant states and ``extra`` gathered to rank 0 (collective)."""
        participant_states: dict[str, Any] = {}
        if include_participants:
            for name in self.order:
                try:
                    state = self.participants[name].checkpoint_state()
                except NotImplementedError:
                    state = None
                participant_states[name] = self.comm.gather(state, root=0)
        return {"format": _CHECKPOINT_FORMAT, "version": _CHECKPOINT_VERSION,
                "scheme": self.scheme_name, "time": self.time, "window": self.window,
                "ranks": self.comm.Get_size(), "data": list(self.data),
                "accelerated": list(self.accelerated),
                "values": {n: v.copy() for n, v in self.values.items()},
                "window_ends": [[t, ends] for t, ends in self.window_ends],
                "acceleration": self.acceleration.state_dict(),
                # the records too: the resumed run's iteration logs cover the whole run
                "history": self._records_text(),
                "participants": participant_states, "extra": self.comm.gather(extra, root=0)}

    def _records_text(self) -> str:
        """:attr:`history` as one JSON text (:func:`~coupling.serialization.encode_text`), each record
        encoded once: a checkpoint every window re-encoding every past record costs the square of the
        windows (a 129-window run: most of its checkpoints' time)."""
        cache, n = self._encoded_history, 0
        while n < min(len(cache), len(self.history)) and cache[n][0] is self.history[n]:
            n += 1                          # the records still in the history (a restore drops the last)
        cache[n:] = [(rec, encode_text(dataclasses.asdict(rec))) for rec in self.history[n:]]
        return "[" + ",".join(text for _, text in cache) + "]"

    @staticmethod
    def _write_checkpoint(path: str | os.PathLike, state: dict) -> tuple[str | None, tuple | None]:
        """Write ``state`` to ``path`` through a temporary file (rank 0); returns (a TypeError's message, an
        OSError's arguments), None each when it was written; the temporary file never stays."""
        tmp = f"{os.fspath(path)}.tmp"
        try:
            save_npz(tmp, state)
            os.replace(tmp, path)
            return None, None
        except TypeError as exc:
            result = (f"save_checkpoint: a participant state cannot be saved ({exc}); pass "
                      f"include_participants=False and save participant states yourself"), None
        except OSError as exc:           # e.g. a full disk: raised on every rank
            result = None, (exc.errno, exc.strerror or str(exc), exc.filename or tmp)
        try:
            os.remove(tmp)
        except OSError:
            pass
        return result

    def load_checkpoint(self, path: str | os.PathLike, include_participants: bool = True) -> Any:
        """Restore a state written by :meth:`save_checkpoint` (all ranks read the file).

        Returns this rank's ``extra`` application state saved with it (``None`` if none).

        Raises:
            ValueError: If the checkpoint belongs to another scheme, other data
                (names or shapes), another acceleration or another rank count.
        """
        state = load_npz(path)
        if not isinstance(state, dict) or "format" not in state or state["format"] != _CHECKPOINT_FORMAT:
            raise ValueError(f"{path}: not a coupling checkpoint")
        if state["scheme"] != self.scheme_name:
            raise ValueError(f"{path}: checkpoint of a {state['scheme']!r} scheme cannot be loaded "
                             f"into a {self.scheme_name!r} scheme")
        if list(state["data"]) != list(self.data) or list(state["accelerated"]) != list(self.accelerated):
            raise ValueError(f"{path}: checkpoint data {state['data']} (accelerated "
                             f"{state['accelerated']}) differ from this scheme's {list(self.data)} "
                             f"(accelerated {list(self.accelerated)})")
        values = {}
        for name in self.data:
            values[name] = self._as_data_array(name, state["values"][name], f"{path}")
        self.acceleration.load_state_dict(state["acceleration"])
        self.values = values
        self.window_ends = [(float(t), {n: np.array(v[n], dtype=float) for n in self.data})
                            for t, v in state.get("window_ends", [])]
        self.time = float(state["time"])
        self.window = int(state["window"])
        history = state.get("history", [])
        if isinstance(history, str):         # version 2: one text (version 1: a list)
            history = decode_text(history)
        self.history = [WindowRecord.from_dict(rec) for rec in history]
        if include_participants and state["participants"]:
            if int(state["ranks"]) != self.comm.Get_size():
                raise ValueError(f"{path}: participant states were saved on {state['ranks']} ranks, "
                                 f"now running on {self.comm.Get_size()}")
            rank = self.comm.Get_rank()
            for name, per_rank in state["participants"].items():
                if name not in self.participants:
                    raise ValueError(f"{path}: checkpoint has a state of unknown participant {name!r}")
                if per_rank is not None and per_rank[rank] is not None:
                    self.participants[name].load_checkpoint_state(per_rank[rank])
        extra = state.get("extra")
        if extra is None:
            return None
        if len(extra) != self.comm.Get_size():
            raise ValueError(f"{path}: the application state was saved on {len(extra)} ranks, "
                             f"now running on {self.comm.Get_size()}")
        return extra[self.comm.Get_rank()]


class SerialImplicitScheme(CouplingScheme):
    """Gauss–Seidel implicit coupling; the backward data are accelerated."""

    scheme_name = "serial-implicit"
    serial = True
    implicit = True


class ParallelImplicitScheme(CouplingScheme):
    """Jacobi implicit coupling; all exchanged data are accelerated."""

    scheme_name = "parallel-implicit"
    serial = False
    implicit = True


class SerialExplicitScheme(CouplingScheme):
    """Gauss–Seidel explicit coupling: one sweep per window, newest data."""

    scheme_name = "serial-explicit"
    serial = True
    implicit = False


class ParallelExplicitScheme(CouplingScheme):
    """Jacobi explicit coupling: one sweep per window from the previous window's data."""

    scheme_name = "parallel-explicit"
    serial = False
    implicit = False


_SCHEMES: dict[str, type[CouplingScheme]] = {
    cls.scheme_name: cls for cls in (SerialImplicitScheme, ParallelImplicitScheme,
                                     SerialExplicitScheme, ParallelExplicitScheme)
}


class _ParticipantFailure(Exception):
    """A participant's solve raised; carries who, when and the original error."""

    def __init__(self, participant: str, iteration: int, error: BaseException):
        super().__init__(f"{participant}: {error}")
        self.participant, self.iteration, self.error = participant, iteration, error


def _scale_acceleration_state(state: dict[str, Any], layout: VectorLayout,
                              factors: Mapping[str, float]) -> None:
    """Rescale an acceleration state in place: data ``d`` is multiplied by ``factors[d]``."""
    if all(factors.get(n, 1.0) == 1.0 for n in layout.names):
        return
    s = np.repeat(np.array([factors.get(n, 1.0) for n in layout.names]), np.diff(layout.offsets))
    for key in ("V", "W"):
        if key in state and state[key] is not None:
            state[key] = np.asarray(state[key], dtype=float) * s[:, None]
    for key in ("previous_residual", "previous_output"):
        if state.get(key) is not None:
            state[key] = np.asarray(state[key], dtype=float) * s
    if state.get("jacobian") is not None:
        state["jacobian"] = np.asarray(state["jacobian"], dtype=float) * s[:, None] / s[None, :]
    pre = state.get("preconditioner")
    if pre is not None and pre.get("kind") in ("value", "residual", "constant"):
        data_factors = np.array([abs(factors.get(n, 1.0)) for n in layout.names])
        pre["data_weights"] = np.asarray(pre["data_weights"], dtype=float) / data_factors


def build_scheme(config: CouplingConfig | Mapping[str, Any],
                 participants: Sequence[Participant] | Mapping[str, Participant],
                 data: Sequence[Data], comm: Any = None,
                 stream: TextIO | None = None, surrogate: Any = None,
                 distribution: Distribution | None = None) -> CouplingScheme:
    """Create the scheme named by ``config.scheme``.

    Args:
        config: A :class:`CouplingConfig` or a ``[coupling]`` table (dict).
        participants: The participants.
        data: The coupling data.
        comm: MPI communicator (default: :func:`coupling.parallel.default_comm`).
        stream: Destination of the progress lines (default ``sys.stdout``).
        surrogate: Optional surrogate model for the quasi-Newton prior
            (see :class:`CouplingScheme`).
        distribution: Participants in separate process groups
            (:class:`coupling.distributed.Distribution`); ``participants``
            are then this rank's group's (see :class:`CouplingScheme`).

    Returns:
        A :class:`CouplingScheme` subclass instance.

    Example::

        scheme = build_scheme({"scheme": "serial-implicit",
                               "convergence": [{"type": "relative", "limit": 1e-8}],
                               "acceleration": {"type": "iqn-ils"}},
                              [fluid, gel], data)
        result = scheme.solve()
    """
    cfg = load_config(config)
    return _SCHEMES[cfg.scheme](cfg, participants, data, comm=comm, stream=stream, surrogate=surrogate,
                                distribution=distribution)
