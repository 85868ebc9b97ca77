"""The participant lifecycle: the exact sequence of calls a scheme makes (docs/coupling.md).

Reference: the protocol written in ``coupling.participant.Participant``'s
docstring, rebuilt here call by call for a steady solve, implicit serial
and parallel runs (both state reloads), an explicit run and a participant
of the earlier ``advance`` protocol.  Every window is cut at a fixed number
of iterations (``on_max_iterations = "continue"``), so the sequence does
not depend on a convergence test.
"""

from __future__ import annotations

import numpy as np
import pytest

import coupling as cp
from coupling.toys import LinearOdeParticipant

ITERATIONS = 3


class Recorder(cp.Participant):
    """Writes ``out = gain * in + offset`` and records every call the scheme makes."""

    def __init__(self, name, read, write, gain, offset, calls):
        self.name, self.read, self.write = name, read, write
        self.gain, self.offset, self.calls = gain, offset, calls
        self.accepted = []

    def _log(self, *call):
        self.calls.append((self.name,) + call)

    def interface_points(self, mesh_name):
        return np.array([[0.0, 0.0]])

    def initialize(self):
        self._log("initialize")

    def begin_window(self, t, dt):
        self._log("begin_window", t, dt)

    def save_state(self):
        self._log("save_state")
        return {}

    def load_state(self, state):
        self._log("load_state")

    def solve(self, inputs):
        self._log("solve")
        return {self.write: self.gain * inputs[self.read] + self.offset}

    def end_window(self, accepted):
        self._log("end_window", tuple(sorted(accepted)))
        self.accepted.append({k: v.copy() for k, v in accepted.items()})

    def finalize(self):
        self._log("finalize")


class Legacy(Recorder):
    """The earlier protocol: ``advance`` (idempotent) instead of ``begin_window``."""

    begin_window = cp.Participant.begin_window

    def advance(self, t, dt):
        self._log("advance", t, dt)


def build(scheme="serial-implicit", participant=Recorder, **options):
    calls = []
    a = participant("A", "b", "a", 0.5, 1.0, calls)
    b = participant("B", "a", "b", 0.5, 0.0, calls)
    data = [cp.Data("a", "G", 1, "A", ("B",)), cp.Data("b", "G", 1, "B", ("A",))]
    config = {"scheme": scheme, "order": ["A", "B"], "verbose": False, **options}
    if scheme.endswith("implicit"):
        config.update(max_iterations=ITERATIONS, on_max_iterations="continue",
                      convergence=[{"type": "relative", "limit": 1e-14}])
    return cp.build_scheme(config, [a, b], data), calls, (a, b)


def window_calls(t, dt, iterations, reload, implicit=True, names=("A", "B")):
    """The protocol of one window (``t is None``: steady, no begin_window and no states)."""
    out = [] if t is None else [(n, "begin_window", t, dt) for n in names]
    saved = t is not None and implicit and reload == "iteration"
    out += [(n, "save_state") for n in names] if saved else []
    for k in range(1, iterations + 1):
        for n in names:
            out += [(n, "load_state")] if saved and k > 1 else []
            out.append((n, "solve"))
    return out + [(n, "end_window", ("a", "b")) for n in names]


def run_calls(windows, iterations, reload="iteration", dt=0.5, implicit=True):
    out = [("A", "initialize"), ("B", "initialize")]
    for w in range(windows):
        out += window_calls(None if dt is None else w * dt, dt, iterations, reload, implicit)
    return out + [("A", "finalize"), ("B", "finalize")]


def test_steady_solve_calls_initialize_solves_end_window_finalize():
    scheme, calls, _ = build()
    scheme.solve()
    assert calls == run_calls(1, ITERATIONS, dt=None)


@pytest.mark.parametrize("scheme_name", ["serial-implicit", "parallel-implicit"])
@pytest.mark.parametrize("reload", ["iteration", "window"])
def test_implicit_run_calls_begin_and_end_window_once_per_window(scheme_name, reload):
    """With state_reload = "window", save_state and load_state are never called in a window."""
    scheme, calls, _ = build(scheme_name, state_reload=reload)
    scheme.run(t_end=1.5, dt=0.5)
    assert calls == run_calls(3, ITERATIONS, reload)
    assert (("A", "save_state") in calls) == (reload == "iteration")


@pytest.mark.parametrize("scheme_name", ["serial-explicit", "parallel-explicit"])
def test_explicit_run_solves_once_per_window_without_states(scheme_name):
    scheme, calls, _ = build(scheme_name)
    scheme.run(t_end=1.0, dt=0.5)
    assert calls == run_calls(2, 1, implicit=False)


def test_advance_window_finalizes_only_when_told():
    scheme, calls, _ = build()
    scheme.advance_window(0.5)
    scheme.advance_window(0.5)
    assert ("A", "finalize") not in calls
    scheme.finalize()
    assert calls == run_calls(2, ITERATIONS)


def test_a_participant_of_the_advance_protocol_keeps_its_calls():
    """save_state before the window's first solve, advance before every solve (after each load_state)."""
    scheme, calls, _ = build(participant=Legacy)
    scheme.run(t_end=0.5, dt=0.5)
    expected = [("A", "initialize"), ("B", "initialize"), ("A", "save_state"), ("B", "save_state")]
    for k in range(1, ITERATIONS + 1):
        for n in ("A", "B"):
            expected += ([(n, "load_state")] if k > 1 else []) + [(n, "advance", 0.0, 0.5), (n, "solve")]
    expected += [(n, "end_window", ("a", "b")) for n in "AB"] + [("A", "finalize"), ("B", "finalize")]
    assert calls == expected
    assert cp.uses_advance(scheme.participants["A"])
    toy = LinearOdeParticipant("x", "G", "i", "o", lambda t: np.eye(1), np.eye(1), lambda t: np.zeros(1),
                               np.zeros(1))
    assert not cp.uses_advance(toy)


def test_end_window_receives_the_values_the_window_keeps():
    """Each participant is told the kept value of what it reads (on its points) and writes."""
    scheme, _, (a, b) = build()
    scheme.run(t_end=1.0, dt=0.5)
    for p in (a, b):
        assert len(p.accepted) == 2
        for name in ("a", "b"):
            np.testing.assert_array_equal(p.accepted[-1][name], scheme.latest(name))


def test_a_failed_window_is_not_ended():
    """A window that raises (max_iterations, on_max_iterations = "raise") gets no end_window."""
    calls = []
    a = Recorder("A", "b", "a", 0.5, 1.0, calls)
    b = Recorder("B", "a", "b", 0.5, 0.0, calls)
    data = [cp.Data("a", "G", 1, "A", ("B",)), cp.Data("b", "G", 1, "B", ("A",))]
    scheme = cp.build_scheme({"order": ["A", "B"], "verbose": False, "max_iterations": 2,
                              "convergence": [{"type": "relative", "limit": 1e-14}]}, [a, b], data)
    with pytest.raises(cp.CouplingNotConvergedError):
        scheme.run(t_end=0.5, dt=0.5)
    assert not [c for c in calls if c[1] in ("end_window", "finalize")]


@pytest.mark.parametrize("scheme_name, kept", [
    # serial, no acceleration: b reads x = 0, 0.5 and writes x̃ = 0.5, 0.625; a = x/2 + 1 = 1.25
    ("serial-implicit", {"output": {"a": 1.25, "b": 0.625}, "input": {"a": 1.25, "b": 0.5}}),
    # parallel: (a, b) reads x = (0, 0), (1, 0) and writes x̃ = (1, 0), (1, 0.5)
    ("parallel-implicit", {"output": {"a": 1.0, "b": 0.5}, "input": {"a": 1.0, "b": 0.0}}),
])
@pytest.mark.parametrize("accepted_value", ["output", "input"])
def test_a_window_accepted_unconverged_keeps_the_chosen_value(scheme_name, kept, accepted_value):
    """accepted_value = "output" keeps x̃ (the default), "input" keeps x; the next window starts from it.

    Two iterations per window (max_iterations = 2, on_max_iterations = "continue"), values by hand.
    """
    calls = []
    a = Recorder("A", "b", "a", 0.5, 1.0, calls)
    b = Recorder("B", "a", "b", 0.5, 0.0, calls)
    data = [cp.Data("a", "G", 1, "A", ("B",)), cp.Data("b", "G", 1, "B", ("A",))]
    options = {} if accepted_value == "output" else {"accepted_value": accepted_value}
    scheme = cp.build_scheme({"scheme": scheme_name, "order": ["A", "B"], "verbose": False, "max_iterations": 2,
                              "on_max_iterations": "continue", "acceleration": {"type": "none"},
                              "convergence": [{"type": "relative", "limit": 1e-14}], **options}, [a, b], data)
    scheme.advance_window(1.0)
    for name, value in kept[accepted_value].items():
        assert scheme.latest(name)[0, 0] == pytest.approx(value, rel=1e-15)
        assert a.accepted[0][name][0, 0] == pytest.approx(value, rel=1e-15)
    seen = []
    a.solve = lambda inputs: seen.append(inputs["b"].copy()) or {"a": 0.5 * inputs["b"] + 1.0}
    scheme.advance_window(1.0)
    assert seen[0][0, 0] == pytest.approx(kept[accepted_value]["b"], rel=1e-15)


def test_accepted_value_names_its_choices():
    with pytest.raises(ValueError, match=r"coupling\.accepted_value = 'last'.*'output', 'input'"):
        cp.load_config({"accepted_value": "last"})


def test_a_window_not_accepted_is_not_ended_but_the_run_finalizes():
    """on_max_iterations = "return": the window is not accepted (no end_window), run() returns and finalizes."""
    calls = []
    a = Recorder("A", "b", "a", 0.5, 1.0, calls)
    b = Recorder("B", "a", "b", 0.5, 0.0, calls)
    data = [cp.Data("a", "G", 1, "A", ("B",)), cp.Data("b", "G", 1, "B", ("A",))]
    scheme = cp.build_scheme({"order": ["A", "B"], "verbose": False, "max_iterations": 2,
                              "on_max_iterations": "return",
                              "convergence": [{"type": "relative", "limit": 1e-14}]}, [a, b], data)
    result = scheme.run(t_end=1.0, dt=0.5)
    assert not result.converged and scheme.time == 0.0
    assert not [c for c in calls if c[1] == "end_window"]
    assert calls[-2:] == [("A", "finalize"), ("B", "finalize")]
