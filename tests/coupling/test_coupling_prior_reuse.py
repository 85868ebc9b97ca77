"""Quasi-Newton priors (relaxation prior, surrogate) and reuse across related solves.

Every path must reach the known answer of its toy problem; iteration counts
are asserted only where the method guarantees them (an exact prior is one
Newton step; a kept secant model of an affine map spans it), never timings.
"""

from __future__ import annotations

import numpy as np
import pytest

import coupling as cp
from coupling.toys import affine_pair_problem, chain_problem, two_bar_problem

LIMIT = 1e-10


def _config(acceleration: dict, **extra) -> dict:
    return {"scheme": "serial-implicit", "max_iterations": 200, "verbose": False,
            "convergence": [{"data": "*", "type": "relative", "limit": LIMIT}],
            "acceleration": acceleration, **extra}


IQN = {"type": "iqn-ils", "initial_relaxation": 0.5, "max_used_iterations": 100,
       "filter": {"type": "qr2", "limit": 1e-8}, "preconditioner": {"type": "value"}}


def _error(scheme: cp.CouplingScheme, problem) -> float:
    return max(float(np.linalg.norm(scheme.latest(n) - v) / np.linalg.norm(v)) for n, v in problem.exact.items())


def _solve(problem, acceleration: dict, surrogate=None, **extra):
    participants, data = problem.build()
    scheme = cp.build_scheme(_config(acceleration, order=list(problem.order), **extra), participants, data,
                             surrogate=surrogate)
    return scheme, scheme.solve()


def _dn_affine(rho: float, n: int = 12):
    """A Dirichlet–Neumann-like affine map: eigenvalues in [-2 rho, -rho/2] (model of Gamma2)."""
    return affine_pair_problem(n, eigenvalues=np.linspace(-2.0 * rho, -0.5 * rho, n), seed=4)


@pytest.mark.parametrize("kind", ["iqn-ils", "iqn-imvj"])
@pytest.mark.parametrize("problem", [_dn_affine(1.0), _dn_affine(10.0), two_bar_problem(100.0), chain_problem()],
                         ids=lambda p: p.name)
def test_relaxation_prior_reaches_the_known_answer(kind, problem):
    scheme, result = _solve(problem, {**IQN, "type": kind, "relaxation_prior": {"*": 0.3}})
    assert result.converged
    assert _error(scheme, problem) < 1e-8


@pytest.mark.parametrize("rho", [1.0, 10.0])
def test_relaxation_prior_of_the_stiffness_ratio_saves_iterations(rho):
    """On eigenvalues in [-2 rho, -rho/2] the prior omega = 1/(1 + rho) contracts every direction the
    secant columns miss (1 - omega (1 - lambda) in [-0.5, 0.25] rho/(1+rho)), plain IQN-ILS does not."""
    problem = _dn_affine(rho, n=40)
    plain_scheme, plain = _solve(problem, IQN)
    prior_scheme, prior = _solve(problem, {**IQN, "relaxation_prior": {"Gamma/y": 1.0 / (1.0 + rho)}})
    assert plain.converged and prior.converged
    assert _error(prior_scheme, problem) < 1e-8 and _error(plain_scheme, problem) < 1e-8
    assert prior.iterations < plain.iterations


class ExactSurrogate:
    """The exact inverse Jacobian dx~/dr = T (T - I)^-1 of the serial affine map on y."""

    def __init__(self, t: np.ndarray):
        n = t.shape[0]
        self.matrix = t @ np.linalg.inv(t - np.eye(n))
        self.calls = 0

    def inverse_jacobian(self, r: np.ndarray) -> np.ndarray:
        self.calls += 1
        return self.matrix @ r


def test_exact_surrogate_is_one_newton_step():
    problem = affine_pair_problem(8)
    surrogate = ExactSurrogate(problem.extra["T"])
    scheme, result = _solve(problem, IQN, surrogate=surrogate)
    assert result.converged and surrogate.calls > 0
    assert _error(scheme, problem) < 1e-10
    # iteration 1 evaluates the initial guess, its Newton step is exact, iteration 2 confirms it
    # (the forward data's change lags by one more iteration)
    assert result.iterations <= 3


def test_inexact_surrogate_still_reaches_the_answer():
    problem = _dn_affine(10.0)
    rng = np.random.default_rng(0)
    t = problem.extra["T"]
    wrong = ExactSurrogate(t + 0.3 * np.abs(t).max() * rng.standard_normal(t.shape) / np.sqrt(t.shape[0]))
    scheme, result = _solve(problem, IQN, surrogate=wrong)
    assert result.converged
    assert _error(scheme, problem) < 1e-8


def test_surrogate_needs_a_quasi_newton_acceleration():
    problem = two_bar_problem(10.0)
    participants, data = problem.build()
    with pytest.raises(ValueError, match="quasi-Newton"):
        cp.build_scheme(_config({"type": "aitken"}, order=list(problem.order)), participants, data,
                        surrogate=ExactSurrogate(np.zeros((1, 1))))


def test_relaxation_prior_is_validated():
    with pytest.raises(ValueError, match="relaxation_prior"):
        cp.load_config(_config({**IQN, "relaxation_prior": {"Gamma/y": -0.5}}))
    with pytest.raises(ValueError, match="not an option"):
        cp.load_config(_config({"type": "aitken", "relaxation_prior": {"*": 0.5}}))
    problem = two_bar_problem(10.0)
    participants, data = problem.build()
    with pytest.raises(ValueError, match="not accelerated"):
        cp.build_scheme(_config({**IQN, "relaxation_prior": {"Gamma/nothing": 0.5}}, order=list(problem.order)),
                        participants, data)


@pytest.mark.parametrize("kind", ["iqn-ils", "iqn-imvj"])
def test_reuse_of_an_unchanged_interface_operator(kind):
    """A second solve of the same affine operator with another right-hand side reuses the secant model.

    With n = 8 unknowns the first solve's columns span the operator (IQN
    terminates in n + 1 steps); the second solve then needs one quasi-Newton
    step (plus the lagging check of the forward data).
    """
    acc = {**IQN, "type": kind, **({"time_windows_reused": 2} if kind == "iqn-ils" else {})}
    first = affine_pair_problem(8, seed=1)
    scheme1, result1 = _solve(first, acc)
    assert result1.converged and result1.iterations > 5
    # same operators (S, T), other constant terms: build a problem with seed 1's matrices and new b
    second = affine_pair_problem(8, seed=1)
    participants, data = second.build()
    shift = np.linspace(0.5, 1.5, 8)
    participants[1].offsets["Gamma/y"] = participants[1].offsets["Gamma/y"] + shift
    exact_y = np.linalg.solve(np.eye(8) - second.extra["T"],
                              participants[1].matrices[("Gamma/y", "Gamma/z")] @ participants[0].offsets["Gamma/z"]
                              + participants[1].offsets["Gamma/y"])
    scheme2 = cp.build_scheme(_config(acc, order=list(second.order)), participants, data)
    scheme2.load_reuse_state(scheme1.reuse_state())
    result2 = scheme2.solve()
    assert result2.converged
    assert np.linalg.norm(scheme2.latest("Gamma/y")[:, 0] - exact_y) / np.linalg.norm(exact_y) < 1e-9
    assert result2.iterations <= 3


def test_reuse_with_values_only_and_identical_problem_converges_at_once():
    problem = two_bar_problem(10.0)
    scheme1, result1 = _solve(problem, IQN, **{})
    participants, data = problem.build()
    scheme2 = cp.build_scheme(_config(IQN, order=list(problem.order)), participants, data)
    scheme2.load_reuse_state(scheme1.reuse_state(), acceleration=False)
    result2 = scheme2.solve()
    assert result2.converged and result2.iterations == 1
    assert _error(scheme2, problem) < 1e-10


def test_reuse_rescales_values_and_columns():
    """A change of units (data x 1e-7) with ``scale`` gives the same iterations as the unscaled reuse."""
    acc = {**IQN, "time_windows_reused": 2}
    base = two_bar_problem(100.0)
    scheme1, _ = _solve(base, acc)
    counts = []
    for scale in (1.0, 1e-7):
        problem = two_bar_problem(100.0, scale=2.0 * scale)   # other loads, other units
        participants, data = problem.build()
        scheme = cp.build_scheme(_config(acc, order=list(problem.order)), participants, data)
        scheme.load_reuse_state(scheme1.reuse_state(), scale={n: scale for n in problem.exact})
        result = scheme.solve()
        assert result.converged and _error(scheme, problem) < 1e-9
        counts.append(result.iterations)
    assert counts[0] == counts[1]


def test_reuse_state_of_other_data_is_rejected():
    s1, _ = _solve(two_bar_problem(10.0), IQN)
    problem = chain_problem()
    participants, data = problem.build()
    scheme = cp.build_scheme(_config(IQN, order=list(problem.order)), participants, data)
    with pytest.raises(ValueError, match="other data"):
        scheme.load_reuse_state(s1.reuse_state())
