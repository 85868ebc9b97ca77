"""Mappings between non-matching interface point sets: order of accuracy and conservation."""

from __future__ import annotations

import numpy as np
import pytest

import coupling as cp


def field(points: np.ndarray) -> np.ndarray:
    """A smooth field with two components."""
    x, y = points[:, 0], points[:, 1]
    return np.column_stack([np.sin(2.0 * x) + np.cos(3.0 * y) + x * y, np.exp(0.5 * x) * y])


def circle(n: int, phase: float = 0.0, rng=None) -> np.ndarray:
    theta = 2.0 * np.pi * (np.arange(n) + phase) / n
    pts = np.column_stack([0.3 + np.cos(theta), -0.2 + np.sin(theta)])
    return pts if rng is None else pts[rng.permutation(n)]


def parabola(n: int, phase: float = 0.0, rng=None) -> np.ndarray:
    """Non-uniformly sampled open arc y = x², x in [-1, 1]."""
    s = np.linspace(-1.0, 1.0, n) if phase == 0.0 else -1.0 + 2.0 * (np.arange(n) + phase) / n
    x = np.sin(0.5 * np.pi * s)  # denser towards the ends
    pts = np.column_stack([x, x ** 2])
    return pts if rng is None else pts[rng.permutation(n)]


def observed_rate(sizes, errors) -> float:
    return -np.polyfit(np.log(sizes), np.log(errors), 1)[0]


def mapping_error(kind: str, curve_points, sizes, **kw) -> list[float]:
    rng = np.random.default_rng(0)
    errors = []
    for n in sizes:
        writer = curve_points(n, rng=rng)
        reader = curve_points(int(1.37 * n) + 1, phase=0.31)
        m = cp.build_mapping(kind, writer, reader, data_name="test", **kw)
        err = m(field(writer)) - field(reader)
        errors.append(float(np.sqrt(np.mean(err ** 2))))
    return errors


@pytest.mark.parametrize("curve_points, curve", [(circle, "auto"), (parabola, "auto"), (circle, "closed")])
def test_nearest_is_first_order(curve_points, curve):
    sizes = [40, 80, 160, 320, 640]
    rate = observed_rate(sizes, mapping_error("nearest", curve_points, sizes))
    assert abs(rate - 1.0) < 0.15, f"observed rate {rate:.3f}, expected 1"


@pytest.mark.parametrize("curve_points, order", [(circle, "chain"), (parabola, "chain"), (circle, "angle")])
def test_linear_is_second_order(curve_points, order):
    sizes = [40, 80, 160, 320, 640]
    rate = observed_rate(sizes, mapping_error("linear", curve_points, sizes, curve_order=order))
    assert abs(rate - 2.0) < 0.15, f"observed rate {rate:.3f}, expected 2"


def test_linear_reproduces_linear_fields_on_a_straight_line():
    rng = np.random.default_rng(1)
    writer = np.column_stack([np.sort(rng.uniform(0, 1, 30)), np.zeros(30)])
    writer[0, 0], writer[-1, 0] = 0.0, 1.0
    writer = writer[rng.permutation(30)]
    reader = np.column_stack([rng.uniform(0, 1, 50), np.zeros(50)])
    m = cp.build_mapping("linear", writer, reader)
    np.testing.assert_allclose(m(2.0 * writer[:, :1] - 1.0), 2.0 * reader[:, :1] - 1.0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(m.matrix.sum(axis=1)).ravel(), 1.0, rtol=1e-14)


@pytest.mark.parametrize("curve_points", [circle, parabola])
@pytest.mark.parametrize("n_writer, n_reader", [(50, 137), (137, 50)])
def test_conservative_preserves_the_total_exactly(curve_points, n_writer, n_reader):
    rng = np.random.default_rng(2)
    writer = curve_points(n_writer, rng=rng)
    reader = curve_points(n_reader, phase=0.43, rng=rng)
    forces = rng.standard_normal((n_writer, 2))
    m = cp.build_mapping("conservative", writer, reader, data_name="Gamma/force")
    mapped = m(forces)
    assert mapped.shape == (n_reader, 2)
    np.testing.assert_allclose(mapped.sum(axis=0), forces.sum(axis=0), rtol=1e-13, atol=1e-13)
    # it is the transpose of the consistent linear map from the reader's to the writer's points
    back = cp.build_mapping("linear", reader, writer)
    np.testing.assert_allclose(m.matrix.toarray(), back.matrix.toarray().T, atol=1e-15)


def test_matching_is_an_exact_lookup():
    rng = np.random.default_rng(3)
    writer = circle(40)
    perm = rng.permutation(40)
    reader = writer[perm] + 1e-15
    m = cp.build_mapping("matching", writer, reader, data_name="Gamma1/traction")
    values = rng.standard_normal((40, 2))
    np.testing.assert_array_equal(m(values), values[perm])


def test_matching_raises_naming_the_data():
    writer = circle(40)
    reader = circle(40, phase=0.5)
    with pytest.raises(ValueError, match=r"matching mapping of data 'Gamma1/traction' \(reader 'gel'\): "
                                         r"40 of 40 reader points have no writer point"):
        cp.build_mapping("matching", writer, reader, data_name="Gamma1/traction", reader="gel")


def test_order_along_curve_open_and_closed():
    rng = np.random.default_rng(4)
    theta = np.linspace(0.0, np.pi, 31)  # a half circle, as Γ2 on the symmetry line
    half = np.column_stack([np.cos(theta), np.sin(theta)])
    perm = rng.permutation(31)
    order, closed = cp.order_along_curve(half[perm])
    assert not closed
    recovered = perm[order]
    assert list(recovered) in (list(range(31)), list(range(30, -1, -1)))
    _, closed = cp.order_along_curve(circle(40, rng=rng))
    assert closed
    _, closed = cp.order_along_curve(circle(40, rng=rng), curve="open")
    assert not closed
    order, closed = cp.order_along_curve(half[perm], order="angle", curve="open")
    assert not closed


def test_order_along_curve_reports_a_failed_chain():
    line1 = np.column_stack([np.linspace(0, 1, 20), np.zeros(20)])
    line2 = np.column_stack([np.linspace(0, 1, 20), np.full(20, 5.0)])
    with pytest.raises(ValueError, match="ordering the points along the curve failed"):
        cp.order_along_curve(np.vstack([line1, line2]))


def test_mapping_of_a_scalar_on_a_3d_curve():
    t = np.linspace(0, 1, 60)
    writer = np.column_stack([np.cos(t), np.sin(t), t])
    reader = np.column_stack([np.cos(t[:-1] + 0.008), np.sin(t[:-1] + 0.008), t[:-1] + 0.008])
    m = cp.build_mapping("linear", writer, reader)
    np.testing.assert_allclose(m(writer[:, 2:]), reader[:, 2:], atol=1e-4)
