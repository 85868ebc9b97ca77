"""Accelerations on fixed-point problems x = G(x) with known fixed points.

Tolerances come from theory: "machine precision" means a small multiple of
eps times the condition number of I - A; rates are the spectral radii of
the iteration matrices.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import coupling as cp
from coupling.serialization import load_npz, save_npz
from coupling.toys import AffineParticipant, affine_pair_problem

EPS = np.finfo(float).eps


def make(kind: str, n: int, **options) -> cp.Acceleration:
    cfg = cp.AccelerationConfig(type=kind, **options)
    return cp.build_acceleration(cfg, cp.VectorLayout.single(n))


def iterate(acc: cp.Acceleration, g, x0: np.ndarray, steps: int) -> list[np.ndarray]:
    """Iterates x_0 .. x_steps of the accelerated fixed-point iteration."""
    xs = [x0.copy()]
    x = x0.copy()
    for _ in range(steps):
        x = acc.compute(x, g(x))
        xs.append(x.copy())
    return xs


def random_affine(n: int, radius: float, seed: int):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, n))
    a *= radius / np.max(np.abs(np.linalg.eigvals(a)))
    b = rng.standard_normal(n)
    return a, b, np.linalg.solve(np.eye(n) - a, b)


@pytest.mark.parametrize("kind", ["iqn-ils", "iqn-imvj"])
@pytest.mark.parametrize("filter_type, limit", [("none", 1e-2), ("qr1", 1e-12), ("qr2", 1e-12)])
@pytest.mark.parametrize("radius", [0.9, 1.5, 4.0])
def test_quasi_newton_terminates_in_n_plus_one_iterations(kind, filter_type, limit, radius):
    n = 8
    a, b, x_star = random_affine(n, radius, seed=int(10 * radius))
    acc = make(kind, n, initial_relaxation=0.5, filter=cp.FilterConfig(type=filter_type, limit=limit))
    xs = iterate(acc, lambda x: a @ x + b, np.zeros(n), n + 1)
    errors = [np.linalg.norm(x - x_star) / np.linalg.norm(x_star) for x in xs]
    tolerance = 1e3 * EPS * np.linalg.cond(np.eye(n) - a)
    assert errors[n + 1] < tolerance, f"error history {errors}"
    assert errors[n - 1] > 1e3 * tolerance  # not already converged: the bound is sharp here


def test_constant_relaxation_converges_at_the_spectral_radius():
    problem = affine_pair_problem()
    t = problem.extra["T"]
    lam = problem.extra["eigenvalues"]
    c = np.random.default_rng(5).standard_normal(t.shape[0])
    x_star = np.linalg.solve(np.eye(t.shape[0]) - t, c)
    omega = 0.3
    rho = np.max(np.abs(1.0 - omega * (1.0 - lam)))  # spectral radius of (1-ω)I + ωT
    acc = make("constant", t.shape[0], relaxation=omega)
    xs = iterate(acc, lambda x: t @ x + c, np.zeros_like(c), 40)
    errors = np.array([np.linalg.norm(x - x_star) for x in xs])
    observed = (errors[40] / errors[30]) ** 0.1
    assert observed == pytest.approx(rho, rel=0.02)
    # plain iteration diverges at rate ρ(T) = 3
    plain = iterate(make("none", t.shape[0]), lambda x: t @ x + c, np.zeros_like(c), 60)
    growth = (np.linalg.norm(plain[60] - x_star) / np.linalg.norm(plain[50] - x_star)) ** 0.1
    assert growth == pytest.approx(np.max(np.abs(lam)), rel=0.02)


@pytest.mark.parametrize("lam", [-100.0, -10.0, -0.5, 0.5, 0.9, 3.0])
@pytest.mark.parametrize("n", [1, 5])
def test_aitken_is_exact_after_two_steps_for_a_multiple_of_the_identity(lam, n):
    c = np.linspace(1.0, 2.0, n)
    x_star = c / (1.0 - lam)
    acc = make("aitken", n, initial_relaxation=0.3)
    xs = iterate(acc, lambda x: lam * x + c, np.zeros(n), 2)
    # secant step on an affine residual: exact up to rounding ~ eps * |1 - λ ω0| / |1 - λ|
    scale = 1.0 + abs(lam)
    assert np.linalg.norm(xs[2] - x_star) <= 50 * EPS * scale * np.linalg.norm(x_star)
    assert acc.omega == pytest.approx(1.0 / (1.0 - lam), rel=1e-12)


def test_aitken_is_superlinear_on_a_nonlinear_scalar_problem():
    def g(x):
        return -2.0 * x - 0.5 * np.sin(x) + 1.0  # G'(x*) ≈ -2.4: plain iteration diverges

    x_star = 0.3
    for _ in range(100):  # Newton for the reference fixed point
        x_star -= (g(x_star) - x_star) / (-2.0 - 0.5 * math.cos(x_star) - 1.0)
    acc = make("aitken", 1, initial_relaxation=0.2)
    xs = iterate(acc, lambda x: g(x), np.array([0.0]), 12)
    errors = [abs(float(x[0]) - x_star) for x in xs]
    useful = [e for e in errors if e > 1e-13]
    assert len(useful) < 10
    orders = [math.log(useful[k + 1] / useful[k]) / math.log(useful[k] / useful[k - 1])
              for k in range(2, len(useful) - 1)]
    assert max(orders[-2:]) > 1.4, f"orders {orders}, errors {errors}"  # secant: (1 + √5) / 2


def test_quasi_newton_filter_removes_a_planted_dependent_column():
    rng = np.random.default_rng(6)
    v1, v2 = rng.standard_normal(10), rng.standard_normal(10)
    v3 = v1 + v2 + 1e-13 * rng.standard_normal(10)  # newest, nearly dependent
    matrix = np.column_stack([v3, v2, v1])  # newest first
    for kind, limit in (("qr1", 1e-8), ("qr2", 1e-8)):
        assert cp.qr_filter(matrix, kind, limit) == [2], kind  # the oldest goes
    assert cp.qr_filter(np.column_stack([v2, v1]), "qr2", 1e-8) == []
    assert cp.qr_filter(np.column_stack([v2, np.zeros(10), v1]), "none", 1e-8) == [1]


def gram_schmidt_qr2(matrix: np.ndarray, limit: float) -> list[int]:
    """QR2 by its definition (preCICE): column by column, newest first, Gram–Schmidt with one
    re-orthogonalisation against the kept newer columns; a column whose orthogonal part is at most
    ``limit`` times its norm, or that comes after n kept ones, is deleted."""
    n = matrix.shape[0]
    basis, deleted = [], []
    for j in range(matrix.shape[1]):
        v = matrix[:, j].copy()
        rho0 = np.linalg.norm(v)
        if not np.isfinite(rho0) or rho0 == 0:
            deleted.append(j)
            continue
        for _ in range(2 if basis else 0):
            q = np.column_stack(basis)
            v -= q @ (q.T @ v)
        rho = np.linalg.norm(v)
        if len(basis) >= n or rho <= limit * rho0:
            deleted.append(j)
        else:
            basis.append(v / rho)
    return deleted


@pytest.mark.parametrize("n,m", [(40, 12), (40, 40), (30, 55)])
def test_qr2_deletes_what_gram_schmidt_deletes(n, m):
    """The blocked (LAPACK) QR2 against its column-by-column definition, with planted dependent
    columns (exact and to 1e-6 of their norm), a zero column and more columns than rows."""
    rng = np.random.default_rng(n + m)
    matrix = rng.standard_normal((n, m)) * rng.uniform(1e-3, 1e3, m)
    for j, (a, b) in {3: (1, 2), 7: (0, 5), 9: (4, 8)}.items():
        noise = 1e-6 * np.linalg.norm(matrix[:, a]) * rng.standard_normal(n) / n
        matrix[:, j] = matrix[:, a] - 2 * matrix[:, b] + noise
    matrix[:, 10] = matrix[:, 6]
    matrix[:, 11] = 0.0
    for limit in (1e-3, 1e-8):
        expected = gram_schmidt_qr2(matrix, limit)
        assert cp.qr_filter(matrix, "qr2", limit) == expected, limit
        assert {10, 11} <= set(expected) and (limit < 1e-5 or {3, 7, 9} <= set(expected))


@pytest.mark.parametrize("filter_type", ["qr1", "qr2"])
def test_iqn_filter_deletes_a_planted_column_inside_the_method(filter_type):
    rng = np.random.default_rng(7)
    n = 10
    acc = make("iqn-ils", n, filter=cp.FilterConfig(type=filter_type, limit=1e-6))
    residuals = [rng.standard_normal(n), rng.standard_normal(n), rng.standard_normal(n)]
    residuals.append(residuals[2] + (residuals[2] - residuals[0]))  # Δr_3 = Δr_1 + Δr_2
    x = np.zeros(n)
    for k, r in enumerate(residuals):
        acc.compute(x, x + r)
        if k < 3:
            assert acc.info.columns_filtered == 0
    assert acc.info.columns_filtered == 1
    v, w = acc.columns
    assert v.shape == (n, 2) == w.shape
    np.testing.assert_allclose(v[:, 0], residuals[3] - residuals[2])  # newest kept
    np.testing.assert_allclose(v[:, 1], residuals[2] - residuals[1])


@pytest.mark.parametrize("kind", ["iqn-ils", "iqn-imvj", "aitken"])
def test_zero_and_repeated_residuals_never_crash(kind):
    n = 4
    acc = make(kind, n)
    x = np.ones(n)
    r = np.full(n, 0.5)
    for _ in range(3):  # identical residuals: zero difference columns
        x_next = acc.compute(x, x + r)
        assert np.all(np.isfinite(x_next))
    if kind != "aitken":
        assert acc.columns[0].shape[1] == 0
        assert acc.info.columns_filtered == 1
    x_next = acc.compute(x, x.copy())  # zero residual
    assert np.all(np.isfinite(x_next))


def test_preconditioner_weights():
    layout = cp.VectorLayout(["a", "b"], [(2, 1), (3, 1)])
    x = np.array([3.0, 4.0, 0.0, 0.0, 2.0])
    r = np.array([1.0, 0.0, 0.0, 3.0, 4.0])  # ‖r_a‖ = 1, ‖r_b‖ = 5, ‖r‖ = √26
    value = cp.Preconditioner(cp.PreconditionerConfig(type="value"), layout)
    value.update(False, x, r)
    np.testing.assert_allclose(value.data_weights, [1 / 5, 1 / 2])
    value.update(False, 2 * x, r)  # in every iteration of the first window (as preCICE)
    np.testing.assert_allclose(value.data_weights, [1 / 10, 1 / 4])
    value.update(True, 4 * x, r)   # the first window completes
    np.testing.assert_allclose(value.data_weights, [1 / 20, 1 / 8])
    value.update(False, x, r)      # later windows: only at their completion
    np.testing.assert_allclose(value.data_weights, [1 / 20, 1 / 8])
    rsum = cp.Preconditioner(cp.PreconditionerConfig(type="residual-sum", freeze_after=1), layout)
    rsum.update(False, x, r)
    rsum.update(False, x, r)
    np.testing.assert_allclose(rsum.data_weights, [math.sqrt(26) / 2, math.sqrt(26) / 10])
    np.testing.assert_allclose(rsum.weights, np.repeat(rsum.data_weights, [2, 3]))
    rsum.update(True, x, r)  # first window complete: frozen from now on
    rsum.update(False, x, 10 * r[::-1])
    np.testing.assert_allclose(rsum.data_weights, [math.sqrt(26) / 2, math.sqrt(26) / 10])
    const = cp.Preconditioner(cp.PreconditionerConfig(type="constant", factors={"a": 2.0, "b": 1e-6}),
                              layout)
    np.testing.assert_allclose(const.data_weights, [0.5, 1e6])


def scaled_affine_pair(scale: float):
    """The affine pair with z expressed in units 1/scale (z' = scale z)."""
    base = affine_pair_problem()
    participants, data = base.build()
    pa, pb = participants
    s_mat = pa.matrices[("Gamma/z", "Gamma/y")]
    m_b = pb.matrices[("Gamma/y", "Gamma/z")]
    pa = AffineParticipant("A", "Gamma", pa.n, {("Gamma/z", "Gamma/y"): scale * s_mat},
                           {"Gamma/z": scale * pa.offsets["Gamma/z"]})
    pb = AffineParticipant("B", "Gamma", pb.n, {("Gamma/y", "Gamma/z"): m_b / scale},
                           {"Gamma/y": pb.offsets["Gamma/y"]})
    return base, [pa, pb], data


@pytest.mark.parametrize("preconditioner", ["residual-sum", "value", "residual"])
def test_preconditioned_parallel_iqn_is_unit_independent(preconditioner):
    iterations = []
    for scale in (1.0, 1e-7, 1e6):
        base, participants, data = scaled_affine_pair(scale)
        scheme = cp.build_scheme(
            {"scheme": "parallel-implicit", "verbose": False, "max_iterations": 100,
             "convergence": [{"type": "relative", "limit": 1e-10}],
             "acceleration": {"type": "iqn-ils", "initial_relaxation": 0.1,
                              "max_used_iterations": 5,  # an inexact model: weighting matters
                              "filter": {"type": "qr2", "limit": 1e-2},
                              "preconditioner": {"type": preconditioner}}},
            participants, data)
        result = scheme.solve()
        np.testing.assert_allclose(scheme.latest("Gamma/y"), base.exact["Gamma/y"], rtol=1e-8)
        np.testing.assert_allclose(scheme.latest("Gamma/z"), scale * base.exact["Gamma/z"], rtol=1e-8)
        iterations.append(result.iterations)
    if preconditioner in ("value", "residual"):
        # w_d ∝ 1/‖data_d‖: the scaled iteration is identical whatever the units
        assert max(iterations) - min(iterations) <= 1, iterations
    # residual-sum weights 1/Σ(‖r_d‖/‖r‖) mix the data in ‖r‖: only nearly unit-independent


@pytest.mark.parametrize("kind", ["none", "constant", "aitken", "iqn-ils", "iqn-imvj"])
def test_state_dict_round_trip_reproduces_the_iteration(kind, tmp_path):
    """Save after two windows (through an npz file), continue both: identical iterates."""
    n = 6
    a, b, _ = random_affine(n, 1.8, seed=3)
    options = {"type": kind}
    if kind in ("aitken", "iqn-ils", "iqn-imvj"):
        options["preconditioner"] = cp.PreconditionerConfig(type="residual-sum")
    if kind == "iqn-ils":
        options["time_windows_reused"] = 2
    cfg = cp.AccelerationConfig(**options)
    layout = cp.VectorLayout(["u", "v"], [(3, 1), (3, 1)])
    first = cp.build_acceleration(cfg, layout)

    def window(acc, shift, x, steps=4):
        for _ in range(steps):
            x = acc.compute(x, a @ x + b + shift)
        acc.window_converged(x, a @ x + b + shift)
        return x

    x = np.zeros(n)
    for w in range(2):
        x = window(first, 0.1 * w, x)
    x = first.compute(x, a @ x + b + 0.2)  # mid-window
    path = tmp_path / "acc.npz"
    save_npz(path, first.state_dict())
    second = cp.build_acceleration(cfg, layout)
    second.load_state_dict(load_npz(path))
    xa, xb = x.copy(), x.copy()
    for _ in range(3):
        xa = first.compute(xa, a @ xa + b + 0.2)
        xb = second.compute(xb, a @ xb + b + 0.2)
    np.testing.assert_array_equal(xa, xb)
    with pytest.raises(ValueError, match="cannot be loaded"):
        other = "aitken" if kind != "aitken" else "iqn-ils"
        cp.build_acceleration(cp.AccelerationConfig(type=other), layout).load_state_dict(first.state_dict())


@pytest.mark.parametrize("scheme_name", ["serial-implicit", "parallel-implicit"])
def test_accelerations_converge_where_plain_iteration_diverges(scheme_name):
    """Affine pair with serial eigenvalues in [-3, -0.5]: ρ = 3 (serial), √3 (parallel)."""
    problem = affine_pair_problem()
    outcomes = {}
    for kind in ("none", "constant", "aitken", "iqn-ils", "iqn-imvj"):
        participants, data = problem.build()
        acceleration = {"type": kind}
        if kind == "constant":
            acceleration["relaxation"] = 0.25  # ρ < 1 for both schemes (0.5 serial, 0.87 parallel)
        scheme = cp.build_scheme({"scheme": scheme_name, "verbose": False, "max_iterations": 400,
                                  "convergence": [{"type": "relative", "limit": 1e-11}],
                                  "acceleration": acceleration}, participants, data)
        try:
            outcomes[kind] = scheme.solve().iterations
        except cp.CouplingDivergedError:
            outcomes[kind] = "diverged"
            continue
        for name, value in problem.exact.items():
            np.testing.assert_allclose(scheme.latest(name), value, rtol=1e-9)
    assert outcomes["none"] == "diverged"
    assert all(isinstance(outcomes[k], int) for k in ("constant", "aitken", "iqn-ils", "iqn-imvj")), outcomes
    assert outcomes["iqn-ils"] <= 2 * 8 + 3  # parallel: x has 2n = 16 entries


def test_positive_aitken_on_a_non_normal_map_with_negative_eigenvalues():
    """Real eigenvalues in [-12, -0.05] (a Dirichlet-Neumann-type overshoot) of a non-normal map.

    Every constant 0 < ω < 2/13 contracts, but the secant estimate of ω,
    a Rayleigh quotient of the non-normal map, turns negative and Aitken
    never converges; with ``positive_relaxation`` (|ω|) it converges to
    rounding.  This is the coupling map of a short time window of the device
    (docs/transient.md).
    """
    rng = np.random.default_rng(0)
    n = 12
    s = np.eye(n) + np.triu(3.0 * rng.standard_normal((n, n)), 1)
    a = s @ np.diag(-np.geomspace(0.05, 12.0, n)) @ np.linalg.inv(s)
    b = rng.standard_normal(n)
    x_star = np.linalg.solve(np.eye(n) - a, b)
    outcome = {}
    for positive in (False, True):
        acc = make("aitken", n, initial_relaxation=0.1, positive_relaxation=positive)
        x, omegas = np.zeros(n), []
        for _ in range(400):
            x = acc.compute(x, a @ x + b)
            omegas.append(acc.info.relaxation)
        outcome[positive] = (np.linalg.norm(x - x_star) / np.linalg.norm(x_star), min(omegas))
    assert outcome[False][1] < 0 and outcome[False][0] > 1e-3, outcome
    assert outcome[True][1] > 0 and outcome[True][0] < 1e3 * EPS * np.linalg.cond(np.eye(n) - a), outcome
