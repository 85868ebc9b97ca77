"""Time-dependent coupling: checkpoint/restore, reuse of past windows, restart."""

from __future__ import annotations

import numpy as np
import pytest

import coupling as cp
from coupling.toys import transient_problem


def build(problem, acceleration, scheme="serial-implicit", **options):
    participants, data = problem.build()
    config = {"scheme": scheme, "order": list(problem.order), "verbose": False,
              "max_iterations": 100, "convergence": [{"type": "relative", "limit": 1e-12}],
              "acceleration": acceleration, **options}
    return cp.build_scheme(config, participants, data), participants


ACCELERATIONS = [
    {"type": "iqn-ils", "initial_relaxation": 0.1, "time_windows_reused": 4},
    {"type": "iqn-imvj", "initial_relaxation": 0.1},
    {"type": "aitken", "initial_relaxation": 0.1},
]


@pytest.mark.parametrize("scheme_name", ["serial-implicit", "parallel-implicit"])
@pytest.mark.parametrize("acceleration", ACCELERATIONS, ids=lambda a: a["type"])
def test_windows_match_the_monolithic_solution(scheme_name, acceleration):
    if scheme_name == "parallel-implicit" and acceleration["type"] == "aitken":
        pytest.skip("Aitken does not converge on this Jacobi map")
    problem = transient_problem()
    scheme, _ = build(problem, acceleration, scheme_name)
    t_end, dt = problem.transient
    result = scheme.run(t_end=t_end, dt=dt)
    assert result.converged and len(result.windows) == 10
    assert scheme.time == pytest.approx(t_end)
    # converged to ‖r‖/‖x̃‖ < 1e-12 in every window; errors accumulate over 10 windows
    for name, value in problem.exact.items():
        np.testing.assert_allclose(scheme.latest(name), value, rtol=1e-9, err_msg=name)


class NoRestore(cp.toys.LinearOdeParticipant):
    """A participant of the earlier protocol (``advance`` before every solve, moving ``u_n``) whose
    load_state forgets to restore (a classic adapter bug)."""

    def load_state(self, state):
        pass

    def advance(self, t, dt):
        self.u_old, self.t_new, self.dt = self.u.copy(), t + dt, dt


class WindowAwareOde(cp.toys.LinearOdeParticipant):
    """The same backward Euler ODE with its past state kept apart from the iterate: ``advance`` only
    moves the past state when a new window starts, as ``state_reload = "window"`` requires."""

    loads = 0

    def save_state(self):
        return {"u": self.u.copy(), "u_old": self.u_old.copy(), "t_new": self.t_new}

    def load_state(self, state):
        type(self).loads += 1
        self.u, self.u_old, self.t_new = state["u"].copy(), state["u_old"].copy(), state["t_new"]

    def advance(self, t, dt):
        if t + dt != self.t_new:
            self.u_old = self.u.copy()
        self.t_new, self.dt = t + dt, dt


@pytest.mark.parametrize("acceleration", ACCELERATIONS, ids=lambda a: a["type"])
def test_state_reload_per_window_continues_from_the_last_iterate(acceleration):
    """state_reload = "window": no state is restored within a window, the windows reach the exact
    solution, and (the solves not depending on their initial state) with the same iterations as the
    default reload before every iteration."""
    runs = {}
    for reload in ("iteration", "window"):
        problem = transient_problem()
        participants, data = problem.build()
        aware = [WindowAwareOde(p.name, p.mesh, p.read, p.write, p.stiffness, p.coupling, p.source, p.u0)
                 for p in participants]
        WindowAwareOde.loads = 0
        scheme = cp.build_scheme({"order": list(problem.order), "verbose": False, "max_iterations": 100,
                                  "convergence": [{"type": "relative", "limit": 1e-12}],
                                  "acceleration": acceleration, "state_reload": reload}, aware, data)
        result = scheme.run(*problem.transient)
        runs[reload] = (result.iterations_per_window, WindowAwareOde.loads, scheme)
        for name, value in problem.exact.items():
            np.testing.assert_allclose(scheme.latest(name), value, rtol=1e-9, err_msg=name)
    assert runs["window"][1] == 0 < runs["iteration"][1]
    assert runs["window"][0] == runs["iteration"][0]


def test_without_restore_the_coupling_fails():
    problem = transient_problem()
    participants, data = problem.build()
    a = participants[0]
    broken = NoRestore(a.name, a.mesh, a.read, a.write, a.stiffness, a.coupling, a.source, a.u0)
    scheme = cp.build_scheme({"order": ["A", "B"], "verbose": False, "max_iterations": 100,
                              "convergence": [{"type": "relative", "limit": 1e-12}],
                              "acceleration": {"type": "iqn-ils", "initial_relaxation": 0.1}},
                             [broken, participants[1]], data)
    try:
        scheme.run(*problem.transient)
    except (cp.CouplingNotConvergedError, cp.CouplingDivergedError):
        return  # the iteration chases a moving target: no convergence
    error = np.linalg.norm(scheme.latest("Gamma/a") - problem.exact["Gamma/a"])
    assert error > 1e-3 * np.linalg.norm(problem.exact["Gamma/a"])


def test_reuse_of_past_windows_lowers_the_iteration_count():
    problem = transient_problem(windows=20, variation=0.1)
    counts = {}
    for label, acceleration in {
        "no reuse": {"type": "iqn-ils", "initial_relaxation": 0.1, "time_windows_reused": 0},
        "reuse 8": {"type": "iqn-ils", "initial_relaxation": 0.1, "time_windows_reused": 8},
        "imvj": {"type": "iqn-imvj", "initial_relaxation": 0.1},
    }.items():
        scheme, _ = build(problem, acceleration, convergence=[{"type": "relative", "limit": 1e-10,
                                                               "data": "Gamma/b"}])
        result = scheme.run(*problem.transient)
        counts[label] = np.mean(result.iterations_per_window[1:])
    assert counts["reuse 8"] < 0.8 * counts["no reuse"], counts
    assert counts["imvj"] < 0.8 * counts["no reuse"], counts


@pytest.mark.parametrize("scheme_name", ["serial-implicit", "parallel-implicit"])
@pytest.mark.parametrize("acceleration", [
    {"type": "iqn-ils", "initial_relaxation": 0.1, "time_windows_reused": 3,
     "preconditioner": {"type": "residual-sum"}},
    {"type": "iqn-imvj", "initial_relaxation": 0.1, "preconditioner": {"type": "value", "freeze_after": 4}},
    {"type": "aitken", "initial_relaxation": 0.1},
], ids=lambda a: a["type"])
@pytest.mark.parametrize("extrapolation", [0, 1, 2])
def test_restart_reproduces_the_uninterrupted_run(scheme_name, acceleration, extrapolation, shared_tmp_path):
    """Bit for bit (1e-12) and with the same iterations: the columns, weights and extrapolation history."""
    if scheme_name == "parallel-implicit" and acceleration["type"] == "aitken":
        pytest.skip("Aitken does not converge on this Jacobi map")
    problem = transient_problem(windows=8)
    dt = problem.transient[1]
    n_total, n_first = 8, 3
    full, _ = build(problem, acceleration, scheme_name, extrapolation_order=extrapolation)
    full_result = full.run(t_end=n_total * dt, dt=dt)

    first, _ = build(problem, acceleration, scheme_name, extrapolation_order=extrapolation)
    first_result = first.run(t_end=n_first * dt, dt=dt)
    path = shared_tmp_path / "restart.npz"
    first.save_checkpoint(path)

    # fresh participants at t = 0
    second, _ = build(problem, acceleration, scheme_name, extrapolation_order=extrapolation)
    second.load_checkpoint(path)
    assert second.time == first.time and second.window == n_first
    second_result = second.run(t_end=n_total * dt, dt=dt)

    assert first_result.iterations_per_window + second_result.iterations_per_window == \
        full_result.iterations_per_window
    for name in full.data:
        np.testing.assert_allclose(second.latest(name), full.latest(name), rtol=1e-12, atol=0.0)
    assert [w.time for w in second_result.windows] == [w.time for w in full_result.windows[n_first:]]


def test_checkpoint_of_another_scheme_is_rejected(shared_tmp_path):
    problem = transient_problem(windows=2)
    scheme, _ = build(problem, {"type": "iqn-ils"})
    scheme.run(*problem.transient)
    path = shared_tmp_path / "serial.npz"
    scheme.save_checkpoint(path)
    other, _ = build(problem, {"type": "iqn-ils"}, "parallel-implicit")
    with pytest.raises(ValueError, match="checkpoint of a 'serial-implicit' scheme cannot be loaded"):
        other.load_checkpoint(path)
    aitken, _ = build(problem, {"type": "aitken"})
    with pytest.raises(ValueError, match="acceleration state of type 'iqn-ils' cannot be loaded"):
        aitken.load_checkpoint(path)


class Stateless(cp.toys.LinearOdeParticipant):
    def save_state(self):
        raise NotImplementedError("no state")


def test_explicit_runs_need_no_checkpoint_and_implicit_ones_say_so():
    problem = transient_problem(windows=3, coupling=2.0)
    participants, data = problem.build()
    a = participants[0]
    stateless = Stateless(a.name, a.mesh, a.read, a.write, a.stiffness, a.coupling, a.source, a.u0)
    explicit = cp.build_scheme({"scheme": "serial-explicit", "verbose": False},
                               [stateless, participants[1]], data)
    result = explicit.run(*problem.transient)
    assert result.iterations_per_window == [1, 1, 1] and result.converged
    implicit = cp.build_scheme({"verbose": False, "convergence": [{"type": "relative", "limit": 1e-8}]},
                               [stateless, participants[1]], data)
    with pytest.raises(TypeError, match=r"participant 'A' must implement save_state\(\)"):
        implicit.run(*problem.transient)


def test_on_max_iterations_continue_runs_every_window():
    problem = transient_problem(windows=4)
    scheme, _ = build(problem, {"type": "iqn-ils"}, max_iterations=3, on_max_iterations="continue")
    result = scheme.run(*problem.transient)
    assert len(result.windows) == 4 and not result.converged
    assert result.iterations_per_window == [3, 3, 3, 3] and result.reason == "max_iterations"
    assert scheme.time == pytest.approx(problem.transient[0])


def test_run_rejects_a_window_that_does_not_divide_the_interval():
    problem = transient_problem(windows=2)
    scheme, _ = build(problem, {"type": "iqn-ils"})
    with pytest.raises(ValueError, match="must be a positive whole multiple of dt"):
        scheme.run(t_end=0.25, dt=0.1)


def test_replay_restores_the_window_checkpoint():
    problem = transient_problem(windows=3)
    scheme, participants = build(problem, {"type": "iqn-ils", "initial_relaxation": 0.1},
                                 record_data=True)
    scheme.run(*problem.transient)
    fresh, _ = problem.build()
    out = cp.replay(fresh[0], scheme.recording, iteration=3, window=1)
    assert max(out.max_abs_difference.values()) <= 1e-12 * np.abs(out.recorded_outputs["Gamma/a"]).max()


# --------------------------------------------------------------------------- variable windows
def _monolithic_backward_euler(problem, times):
    """The toy's exact answer on an arbitrary time grid (backward Euler, both systems at once)."""
    participants, _ = problem.build()
    a, b = participants
    u, v = a.u0.copy(), b.u0.copy()
    m = u.size
    eye = np.eye(m)
    for t0, t1 in zip(times[:-1], times[1:]):
        dt = t1 - t0
        lhs = np.block([[eye / dt + a.stiffness(t1), -a.coupling], [-b.coupling, eye / dt + b.stiffness(t1)]])
        rhs = np.concatenate([u / dt + a.source(t1), v / dt + b.source(t1)])
        sol = np.linalg.solve(lhs, rhs)
        u, v = sol[:m], sol[m:]
    return {"Gamma/a": u[:, None], "Gamma/b": v[:, None]}


@pytest.mark.parametrize("extrapolation", [0, 1, 2])
def test_advance_window_with_variable_steps(extrapolation):
    """advance_window takes any dt; the result is the backward-Euler answer on that grid."""
    problem = transient_problem()
    scheme, _ = build(problem, ACCELERATIONS[0], extrapolation_order=extrapolation)
    times = np.cumsum([0.0, 0.05, 0.1, 0.2, 0.15, 0.3, 0.2])
    for t0, t1 in zip(times[:-1], times[1:]):
        rec = scheme.advance_window(t1 - t0)
        assert rec.converged and rec.time == pytest.approx(t0)
    assert scheme.time == pytest.approx(times[-1])
    for name, value in _monolithic_backward_euler(problem, times).items():
        np.testing.assert_allclose(scheme.latest(name), value, rtol=1e-9, err_msg=name)
    with pytest.raises(ValueError, match="dt"):
        scheme.advance_window(0.0)


class _Signal(cp.Participant):
    """Writes ``a = q(t + dt)``, a prescribed polynomial in time, whatever it reads (``b``)."""

    name = "signal"

    def __init__(self, coefficients):
        self.coefficients, self.t_end = np.asarray(coefficients, dtype=float), 0.0

    def interface_points(self, mesh_name):
        return np.array([[0.0, 0.0], [1.0, 0.0]])

    def save_state(self):
        return None

    def load_state(self, state):
        pass

    def advance(self, t, dt):
        self.t_end = t + dt

    def solve(self, inputs):
        q = np.polyval(self.coefficients[::-1], self.t_end)
        return {"a": np.array([[q, 2.0 * q], [-q, 0.5]])}


class _Echo(_Signal):
    """Writes ``b = a``."""

    name = "echo"

    def solve(self, inputs):
        return {"b": inputs["a"].copy()}


@pytest.mark.parametrize("order, degree", [(1, 1), (2, 2)])
def test_extrapolation_is_exact_for_data_polynomial_in_time(order, degree):
    """Lagrange extrapolation of order k reproduces data of degree k in t on unequal windows: from
    window k + 1 on, the initial guess is the window's answer and one iteration confirms it; one
    degree more leaves a residual to iterate away (2 iterations)."""
    steps = [0.1, 0.15, 0.05, 0.2, 0.1, 0.3, 0.12]
    for q_degree, expected in ((degree, 1), (degree + 1, 2)):
        coefficients = [0.3, -1.0, 2.0, 1.5][:q_degree + 1]
        data = [cp.Data("a", "G", 2, "signal", ("echo",)), cp.Data("b", "G", 2, "echo", ("signal",))]
        config = {"scheme": "serial-implicit", "order": ["signal", "echo"], "verbose": False,
                  "max_iterations": 20, "convergence": [{"type": "relative", "limit": 1e-12}],
                  "acceleration": {"type": "constant", "relaxation": 1.0}, "extrapolation_order": order}
        scheme = cp.build_scheme(config, [_Signal(coefficients), _Echo(coefficients)], data)
        iterations = [scheme.advance_window(dt).iterations for dt in steps]
        assert iterations[order + 1:] == [expected] * (len(steps) - order - 1), (q_degree, iterations)


def test_lagrange_weights():
    """Weights of the polynomial through the nodes: they reproduce t^2 at x, sum to 1, and equal
    nodes are refused."""
    nodes, x = [0.0, 0.3, 0.4], 0.65
    w = cp.lagrange_weights(nodes, x)
    assert sum(w) == pytest.approx(1.0, abs=1e-14)
    assert np.dot(w, np.square(nodes)) == pytest.approx(x * x, abs=1e-14)
    assert cp.lagrange_weights([1.0, 2.0], 3.0) == pytest.approx([-1.0, 2.0])
    with pytest.raises(ValueError, match="distinct"):
        cp.lagrange_weights([1.0, 1.0], 2.0)


def test_linear_extrapolation_lowers_the_iteration_count():
    """The initial guess of a window from the last two windows is closer than the last value.

    With Aitken relaxation (linear convergence) fewer iterations reach the
    tolerance from a closer start; IQN-ILS on this 12-dimensional affine map
    terminates after a fixed number of iterations whatever the start.
    """
    counts = {}
    for order in (0, 1):
        problem = transient_problem(windows=20)
        scheme, _ = build(problem, {"type": "aitken", "initial_relaxation": 0.1}, extrapolation_order=order)
        counts[order] = sum(scheme.advance_window(0.1).iterations for _ in range(20))
    assert counts[1] < counts[0], counts


def test_snapshot_and_restore_repeat_a_window_exactly():
    """restore() returns data, quasi-Newton state and participants to the snapshot (a rejected step)."""
    problem = transient_problem()
    scheme, participants = build(problem, ACCELERATIONS[0], extrapolation_order=1)
    for _ in range(3):
        scheme.advance_window(0.1)
    snap = scheme.snapshot()
    first = scheme.advance_window(0.1)
    after_first = {n: scheme.latest(n) for n in scheme.data}
    scheme.advance_window(0.05)                 # a different window, then back
    scheme.restore(snap)
    assert scheme.time == pytest.approx(0.3) and len(scheme.history) == 3
    again = scheme.advance_window(0.1)
    assert again.iterations == first.iterations
    for n in scheme.data:
        np.testing.assert_array_equal(scheme.latest(n), after_first[n])


def test_checkpoint_carries_the_application_state(shared_tmp_path):
    problem = transient_problem()
    scheme, _ = build(problem, ACCELERATIONS[0], extrapolation_order=1)
    scheme.advance_window(0.1)
    path = shared_tmp_path / "extra.npz"
    scheme.save_checkpoint(path, extra={"rows": [1.0, 2.0], "past": np.arange(3.0)})
    again, _ = build(problem, ACCELERATIONS[0], extrapolation_order=1)
    extra = again.load_checkpoint(path)
    assert extra["rows"] == [1.0, 2.0]
    np.testing.assert_array_equal(extra["past"], np.arange(3.0))
    # the extrapolation history came back too: the next windows coincide
    for _ in range(2):
        a, b = scheme.advance_window(0.1), again.advance_window(0.1)
        assert a.iterations == b.iterations
    for n in scheme.data:
        np.testing.assert_allclose(again.latest(n), scheme.latest(n), rtol=1e-12)


def test_checkpoints_hold_the_whole_history_encoding_each_record_once(shared_tmp_path, monkeypatch):
    """A checkpoint after every window holds every window's record (read back equal to the records
    themselves), with each record encoded once over the run, also after a restore drops one (a
    checkpoint that re-encoded the whole history each window cost the square of the windows)."""
    import dataclasses

    from coupling import schemes
    encoded = []
    original = schemes.encode_text
    monkeypatch.setattr(schemes, "encode_text", lambda obj: encoded.append(obj["window"]) or original(obj))
    problem = transient_problem()
    scheme, _ = build(problem, ACCELERATIONS[0], extrapolation_order=1)
    path = shared_tmp_path / "every-window.npz"
    for k in range(5):
        if k == 3:
            snap = scheme.snapshot()
        scheme.advance_window(0.1)
        scheme.save_checkpoint(path)
    scheme.restore(snap)                        # window 3 rejected: its record goes, then is made again
    scheme.advance_window(0.05)
    scheme.save_checkpoint(path)
    assert encoded == [0, 1, 2, 3, 4, 3]
    again, _ = build(problem, ACCELERATIONS[0], extrapolation_order=1)
    again.load_checkpoint(path)


    def without_timing(records):                # solve times are rank 0's in the file, each rank's own here
        return [{**d, "records": [{**r, "solve_time": None} for r in d["records"]]}
                for d in map(dataclasses.asdict, records)]
    assert without_timing(again.history) == without_timing(scheme.history)
    assert [r.dt for r in again.history] == [0.1, 0.1, 0.1, 0.05]
