"""The coarse-model surrogate prior: surface mass matrices, its transfers between two spheres, its prior.

References: the sphere's area and second moment (closed forms), smooth fields and their
consistent nodal integrals evaluated exactly on each surface, and the identity of the
transfers between two equal surfaces.
"""

from __future__ import annotations

import numpy as np
import pytest

import coupling as cp
from test_surface_mapping import RATE_TOL, Surface, field, icosphere, observed_rate, quadratic


def p2_sphere(level: int):
    """The unit sphere as P2 triangles, every node on the sphere."""
    return quadratic(*icosphere(level), on_sphere=True)


def density(x: np.ndarray) -> np.ndarray:
    """A smooth 3-component density on the sphere (a traction, say)."""
    return np.column_stack([field(x), 1.0 + x[:, 0] * x[:, 2]])


@pytest.mark.parametrize("degree", [1, 2])
def test_the_mass_matrix_integrates_the_sphere(degree):
    errors, sizes = [], []
    for level in (2, 3, 4):
        points, triangles = p2_sphere(level) if degree == 2 else icosphere(level)
        M = cp.surface_mass_matrix(points, triangles)
        ones, z2 = np.ones(len(points)), points[:, 2] ** 2
        errors.append(max(abs(ones @ M @ ones - 4 * np.pi), abs(ones @ M @ z2 - 4 * np.pi / 3)))
        sizes.append(2 ** level)
    # the surface's geometric error: chords O(h^2) for flat triangles, O(h^4) (even) for curved P2
    order = 2.0 if degree == 1 else 4.0
    rate = observed_rate(sizes, errors)
    assert rate > order - RATE_TOL, f"observed rate {rate:.3f} (errors {errors}), expected {order}"


def test_the_mass_matrix_is_exact_on_a_flat_square():
    points = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0.0]])
    M = cp.surface_mass_matrix(points, np.array([[0, 1, 2], [0, 2, 3]]))
    x = points[:, 0]
    assert np.ones(4) @ M @ np.ones(4) == pytest.approx(2.0, rel=1e-14)
    assert x @ M @ x == pytest.approx(8.0 / 3.0, rel=1e-14)       # int x^2 over [0,2]x[0,1], x linear


class FixedPrior:
    """A stand-in coarse prior: J0 r = B r for a fixed matrix B (its columns in one call)."""

    accepts_matrices = True

    def __init__(self, B):
        self.B = B

    def inverse_jacobian(self, r):
        return self.B @ r


def sphere_scheme(level: int):
    """Two participants on one P2 sphere: a gel writing a displacement, a cell writing nodal forces."""
    mesh = p2_sphere(level)
    gel = Surface("gel", mesh, "Gamma2/displacement", density)
    cell = Surface("cell", mesh, "Gamma2/force", density)
    data = [cp.Data("Gamma2/displacement", "Gamma2", 3, "gel", ("cell",)),
            cp.Data("Gamma2/force", "Gamma2", 3, "cell", ("gel",))]
    config = {"scheme": "serial-implicit", "order": ["gel", "cell"], "verbose": False,
              "convergence": [{"type": "relative", "limit": 1e-10}], "acceleration": {"type": "iqn-ils"}}
    return cp.build_scheme(config, [gel, cell], data), mesh


def state(scheme, mesh, values):
    """The accelerated vector of ``values(points)`` (intensive) and their nodal integrals (force)."""
    points, triangles = mesh
    M = cp.surface_mass_matrix(points, triangles)
    parts = {"Gamma2/displacement": values(points), "Gamma2/force": M @ values(points)}
    return scheme.layout.concat({n: parts[n] for n in scheme.layout.names})


def surrogate(fine_level: int, coarse_level: int, B=None):
    fine, fine_mesh = sphere_scheme(fine_level)
    coarse, coarse_mesh = sphere_scheme(coarse_level)
    B = np.eye(coarse.layout.size) if B is None else B(coarse.layout.size)
    s = cp.CoarseSurrogate.on_surfaces(fine, coarse, prior=FixedPrior(B), extensive=["Gamma2/force"])
    return s, (fine, fine_mesh), (coarse, coarse_mesh)


def test_transfers_carry_a_smooth_field_and_its_nodal_integrals_with_the_interpolations_order():
    errors, sizes = [], []
    for level in (2, 3, 4):
        s, (fine, fine_mesh), (coarse, coarse_mesh) = surrogate(level + 1, level)
        exact_coarse, exact_fine = state(coarse, coarse_mesh, density), state(fine, fine_mesh, density)
        err = [np.linalg.norm(s.restrict(exact_fine)[sl] - exact_coarse[sl]) / np.linalg.norm(exact_coarse[sl])
               for sl in coarse.layout.slices()]
        err += [np.linalg.norm(s.prolong(exact_coarse)[sl] - exact_fine[sl]) / np.linalg.norm(exact_fine[sl])
                for sl in fine.layout.slices()]
        errors.append(max(err))
        sizes.append(2 ** level)
    # P2 interpolation at the other surface's nodes: O(h^3) (coupling.surface_mapping)
    rate = observed_rate(sizes, errors)
    assert rate > 3.0 - RATE_TOL, f"observed rate {rate:.3f} (errors {errors})"


def test_the_transferred_forces_keep_their_total():
    s, (fine, fine_mesh), (coarse, coarse_mesh) = surrogate(4, 2)
    forces = fine.layout.slice("Gamma2/force")
    x = state(fine, fine_mesh, density)
    total = x[forces].reshape(-1, 3).sum(axis=0)
    moved = s.restrict(x)[coarse.layout.slice("Gamma2/force")].reshape(-1, 3).sum(axis=0)
    # the total of the density's integrals, carried through the coarse interpolant: O(h_c^3)
    np.testing.assert_allclose(moved, total, rtol=0, atol=2e-3 * np.abs(total).max())


def test_on_equal_surfaces_the_surrogate_is_the_coarse_prior():
    rng = np.random.default_rng(1)
    s, (fine, _), _ = surrogate(2, 2, B=lambda n: rng.normal(size=(n, n)))
    r = rng.normal(size=(fine.layout.size, 3))
    np.testing.assert_allclose(s.restrict(r), r, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.inverse_jacobian(r), s.prior.B @ r, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(s.inverse_jacobian(r[:, 0]), s.prior.B @ r[:, 0], rtol=1e-12, atol=1e-12)


def test_the_surrogate_needs_a_coarse_prior_and_the_same_accelerated_data():
    fine, _ = sphere_scheme(3)
    coarse, _ = sphere_scheme(2)
    with pytest.raises(ValueError, match="the coarse scheme has no prior"):
        cp.CoarseSurrogate.on_surfaces(fine, coarse)
    with pytest.raises(ValueError, match=r"extensive data \['Gamma2/forces'\] are not data"):
        cp.CoarseSurrogate.on_surfaces(fine, coarse, prior=FixedPrior(None), extensive=["Gamma2/forces"])
