"""The linearized quasi-Newton prior (coupling.linearization) on the coupling toy problems.

Reference: the toys' closed-form answers.  Every toy participant is affine and
reports its exact derivatives, so the composed A is the fixed-point map's exact
Jacobian and the prior's first step is the Newton step: it lands on the fixed
point whatever the spectrum of A (plain iteration diverges on every toy here).
The convergence measures then need one more sweep (parallel: 2 iterations),
or two in a serial scheme, whose forward data are measured by their change
(the first sweep's forward data were computed from the initial guess).
"""

import numpy as np
import pytest

from coupling import Participant, build_scheme
from coupling.linearization import coupled_jacobian
from coupling.toys import LinearOdeParticipant, affine_pair_problem, chain_problem, transient_problem, two_bar_problem


def _config(scheme, problem, acceleration="iqn-ils", **extra):
    return {"scheme": f"{scheme}-implicit", "order": list(problem.order), "max_iterations": 50,
            "convergence": [{"data": "*", "type": "relative", "limit": 1e-10}],
            "acceleration": {"type": acceleration, "initial_relaxation": 0.1, "jacobian_prior": "linearized",
                             "filter": {"type": "qr2", "limit": 1e-8}, **extra}}


PROBLEMS = [affine_pair_problem(), two_bar_problem(10.0), two_bar_problem(100.0), chain_problem()]


@pytest.mark.parametrize("scheme", ["serial", "parallel"])
@pytest.mark.parametrize("acceleration", ["iqn-ils", "iqn-imvj"])
@pytest.mark.parametrize("problem", PROBLEMS, ids=lambda p: p.name)
def test_exact_linearization_converges_in_one_newton_step(problem, scheme, acceleration):
    participants, data = problem.build()
    sch = build_scheme(_config(scheme, problem, acceleration), participants, data)
    result = sch.solve()
    assert result.converged
    assert result.iterations == (3 if scheme == "serial" else 2)
    second = result.windows[0].records[1]          # the sweep after the Newton step
    for name in sch.accelerated:
        assert second.residual_norms[name] <= 1e-12 * max(second.value_norms[name], 1.0)
    for name, exact in problem.exact.items():
        assert np.allclose(sch.latest(name), exact, rtol=1e-9, atol=1e-12 * np.abs(exact).max())


def test_composed_jacobian_is_the_serial_map():
    """A from the participants equals the fixed-point operator the toy is built with (T)."""
    problem = affine_pair_problem(n=6)
    participants, data = problem.build()
    sch = build_scheme(_config("serial", problem), participants, data)
    assert sch.accelerated == ("Gamma/y",)
    assert np.allclose(coupled_jacobian(sch), problem.extra["T"], rtol=0, atol=1e-12)


def test_missing_or_wrong_jacobian_is_refused():
    problem = affine_pair_problem(n=4)
    participants, data = problem.build()
    participants[1].jacobian = lambda: {("Gamma/y", "Gamma/z"): np.zeros((3, 4))}
    sch = build_scheme(_config("serial", problem), participants, data)
    with pytest.raises(ValueError, match=r"shape \(3, 4\), expected \(4, 4\)"):
        sch.solve()
    participants, data = problem.build()
    participants[1].jacobian = lambda: {("Gamma/y", "Gamma/y"): np.zeros((4, 4))}
    with pytest.raises(ValueError, match="does not read"):
        build_scheme(_config("serial", problem), participants, data).solve()
    participants, data = problem.build()

    class Opaque(Participant):          # solves, but cannot linearise itself
        name = participants[0].name

        def interface_points(self, mesh_name):
            return participants[0].interface_points(mesh_name)

        def solve(self, inputs):
            return participants[0].solve(inputs)

    with pytest.raises(TypeError, match="has no jacobian"):
        build_scheme(_config("serial", problem), [Opaque(), participants[1]], data).solve()


def test_jacobian_prior_configuration_is_checked():
    problem = affine_pair_problem(n=4)
    participants, data = problem.build()
    with pytest.raises(ValueError, match="jacobian_prior"):
        build_scheme(_config("serial", problem, relaxation_prior={"*": 0.5}), participants, data)
    with pytest.raises(ValueError, match="allowed values: 'none', 'linearized'"):
        cfg = _config("serial", problem)
        cfg["acceleration"]["jacobian_prior"] = "exact"
        build_scheme(cfg, participants, data)
    with pytest.raises(ValueError, match="jacobian_prior"):
        cfg = _config("serial", problem, "aitken")
        cfg["acceleration"] = {"type": "aitken", "jacobian_prior": "linearized"}
        build_scheme(cfg, participants, data)


def test_serial_prior_through_a_shorter_inner_vector():
    """A reads x1, x2 (n each) and writes y (n); B reads y and writes x1, x2: z = y is half of x.

    The prior then factorises I - Z C (n) instead of I - A (2n); the Newton step is still exact.
    """
    from coupling import Data
    from coupling.linearization import LinearizedPrior
    from coupling.toys import AffineParticipant
    n = 5
    rng = np.random.default_rng(3)
    m1, m2, b1, b2 = (rng.standard_normal((n, n)) for _ in range(4))
    a = AffineParticipant("A", "G", n, {("G/y", "G/x1"): 2 * m1, ("G/y", "G/x2"): m2}, {"G/y": rng.standard_normal(n)})
    b = AffineParticipant("B", "G", n, {("G/x1", "G/y"): b1, ("G/x2", "G/y"): 3 * b2},
                          {"G/x1": rng.standard_normal(n), "G/x2": rng.standard_normal(n)})
    data = [Data("G/y", "G", 1, "A", ("B",)), Data("G/x1", "G", 1, "B", ("A",)), Data("G/x2", "G", 1, "B", ("A",))]
    config = {"scheme": "serial-implicit", "order": ["A", "B"], "max_iterations": 20,
              "convergence": [{"data": "*", "type": "relative", "limit": 1e-10}],
              "acceleration": {"type": "iqn-ils", "jacobian_prior": "linearized"}}
    sch = build_scheme(config, [a, b], data)
    result = sch.solve()
    prior = sch.acceleration.surrogate
    assert isinstance(prior, LinearizedPrior) and "C" in prior.state()          # the Woodbury form
    assert prior.state()["lu"][0].shape == (n, n)
    assert np.allclose(prior.jacobian, coupled_jacobian(sch), rtol=0, atol=1e-12)
    # the fixed point in closed form: x = T x + c with T = [[b1], [3 b2]] [2 m1, m2]
    T = np.vstack([b1, 3 * b2]) @ np.hstack([2 * m1, m2])
    c = np.vstack([b1, 3 * b2]) @ a.offsets["G/y"] + np.hstack([b.offsets["G/x1"], b.offsets["G/x2"]])
    x = np.linalg.solve(np.eye(2 * n) - T, c)
    assert result.converged and result.iterations == 3
    assert np.allclose(np.hstack([sch.latest("G/x1")[:, 0], sch.latest("G/x2")[:, 0]]), x, rtol=1e-9, atol=1e-12)


def test_a_map_without_a_unique_fixed_point_is_refused():
    """A Jacobian with an eigenvalue 1 (I - A singular) stops with a message, not with NaNs."""
    problem = affine_pair_problem(n=4, eigenvalues=[1.0, -0.5, -1.0, -2.0])
    participants, data = problem.build()
    with pytest.raises(ValueError, match="I - A is singular"):
        build_scheme(_config("serial", problem), participants, data).solve()


def test_a_prior_too_large_for_the_memory_is_refused(monkeypatch):
    """The dense system's size is checked against the available memory before it is allocated."""
    import builtins
    import io
    from coupling.linearization import LinearizedPrior
    real_open = builtins.open

    def tiny_meminfo(path, *args, **kwargs):
        if path == "/proc/meminfo":
            return io.StringIO("MemTotal: 1000 kB\nMemAvailable: 1 kB\n")
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", tiny_meminfo)
    with pytest.raises(MemoryError, match="jacobian_prior = 'none'"):
        LinearizedPrior.check_memory(1000, 400)
    monkeypatch.setattr(builtins, "open", real_open)
    LinearizedPrior.check_memory(10, 4)          # a small system passes on this machine


def test_reuse_takes_the_prior_with_or_without_the_secant_columns():
    """``load_reuse_state(acceleration=False)`` still takes the prior's factorisation (a Ca sweep under
    the prior: its columns model the Ca-dependent remainder); ``prior=False`` leaves it to be computed."""
    problem = affine_pair_problem(n=6)
    participants, data = problem.build()
    first = build_scheme(_config("serial", problem, time_windows_reused=1), participants, data)
    assert first.solve().converged
    kept = first.acceleration.columns[0].shape[1]
    assert kept > 0
    state = first.reuse_state()
    for acceleration, prior in ((False, True), (True, False)):
        participants, data = problem.build()
        sch = build_scheme(_config("serial", problem, time_windows_reused=1), participants, data)
        sch.load_reuse_state(state, acceleration=acceleration, prior=prior)
        if prior:
            assert sch.linearized_prior.state()["lu"] is first.linearized_prior.state()["lu"]
        else:
            assert sch.linearized_prior.state() is None
        assert sch.acceleration.columns[0].shape[1] == (kept if acceleration else 0)
        result = sch.solve()
        # from the converged values: one sweep confirms them
        assert result.converged and result.iterations == 1
        for name, exact in problem.exact.items():
            assert np.allclose(sch.latest(name), exact, rtol=1e-9, atol=1e-12 * np.abs(exact).max())


class _LinearOde(LinearOdeParticipant):
    """The toy's backward-Euler ODE with its exact derivative, which depends on the window's dt."""

    def jacobian(self):
        lhs = np.eye(self.u.size) / self.dt + self.stiffness(self.t_new)
        return {(self.write, self.read): np.linalg.solve(lhs, self.coupling)}

    def jacobian_key(self):
        return self.dt


def _run_steps(steps, constant_key: bool = False):
    """The transient toy (constant K) over windows of ``steps``: (scheme, records, monolithic BE answer)."""
    problem = transient_problem(variation=0.0)
    participants, data = problem.build()
    for p in participants:
        p.__class__ = _LinearOde
        if constant_key:
            p.jacobian_key = lambda: None          # the prior of the first window kept (the old behaviour)
    a, b = participants
    config = {"scheme": "serial-implicit", "order": ["A", "B"], "max_iterations": 50,
              "convergence": [{"data": "*", "type": "relative", "limit": 1e-10}],
              "acceleration": {"type": "iqn-ils", "jacobian_prior": "linearized", "time_windows_reused": 0,
                               "filter": {"type": "qr2", "limit": 1e-8}}}
    sch = build_scheme(config, participants, data)
    u, v, t, m = a.u0.copy(), b.u0.copy(), 0.0, a.u0.size
    records = []
    for dt in steps:
        records.append(sch.advance_window(dt))
        lhs = np.block([[np.eye(m) / dt + a.stiffness(t + dt), -a.coupling],
                        [-b.coupling, np.eye(m) / dt + b.stiffness(t + dt)]])
        sol = np.linalg.solve(lhs, np.concatenate([u / dt + a.source(t + dt), v / dt + b.source(t + dt)]))
        u, v, t = sol[:m], sol[m:], t + dt
    return sch, records, (u, v)


STEPS = [0.1, 0.1, 0.05, 0.05, 0.1, 0.02, 0.1]


def test_prior_per_step_size_keeps_three_iterations_per_window():
    """An affine window map, its exact Jacobian per dt: 3 serial sweeps in every window (module docstring),
    one factorisation per distinct dt (0.1 taken back from the kept ones), the monolithic BE answer."""
    sch, records, (u, v) = _run_steps(STEPS)
    assert [r.iterations for r in records] == [3] * len(STEPS)
    assert sch.linearized_prior.factorizations == 3
    np.testing.assert_allclose(sch.latest("Gamma/a")[:, 0], u, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(sch.latest("Gamma/b")[:, 0], v, rtol=1e-9, atol=1e-12)


def test_prior_of_another_step_size_costs_iterations():
    """The control: the first window's prior kept for the other step sizes needs more sweeps there."""
    _, records, _ = _run_steps(STEPS, constant_key=True)
    assert all(r.iterations == 3 for r, dt in zip(records, STEPS) if dt == STEPS[0])
    assert all(r.iterations > 3 for r, dt in zip(records, STEPS) if dt != STEPS[0])
