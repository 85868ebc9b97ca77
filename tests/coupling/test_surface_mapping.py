"""Surface mappings between non-matching triangulated surfaces: observed orders, conservation, errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

import coupling as cp

# the project's tolerance on an observed rate (as in test_coupling_mapping.py)
RATE_TOL = 0.15
# a tilted plane through the origin: orthonormal in-plane axes
AXES = np.linalg.qr(np.array([[1.0, 0.3, 0.4], [-0.2, 1.0, 0.5], [0.1, -0.3, 1.0]]))[0][:, :2].T


def field(x: np.ndarray) -> np.ndarray:
    """A smooth field in space, two components (data are mapped per component)."""
    return np.column_stack([np.sin(2.0 * x[:, 0]) + np.cos(3.0 * x[:, 1]) * x[:, 2] + np.exp(0.5 * x[:, 2]),
                            x[:, 0] * x[:, 1] - np.sin(x[:, 2])])


def linear(x: np.ndarray) -> np.ndarray:
    """A linear field in space: every linear interpolant reproduces it."""
    return (1.0 + x @ np.array([2.0, -3.0, 0.5]))[:, None]


def plane(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The unit square on the tilted plane, n x n squares cut by alternating diagonals: points, triangles."""
    s = np.linspace(0.0, 1.0, n + 1)
    uv = np.array(np.meshgrid(s, s, indexing="ij")).reshape(2, -1).T
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    v00, v10, v01, v11 = (i * (n + 1) + j, (i + 1) * (n + 1) + j, i * (n + 1) + j + 1, (i + 1) * (n + 1) + j + 1)
    flip = (i + j) % 2 == 1
    first = np.where(flip[:, None], np.column_stack([v00, v10, v01]), np.column_stack([v00, v10, v11]))
    second = np.where(flip[:, None], np.column_stack([v10, v11, v01]), np.column_stack([v00, v11, v01]))
    return uv @ AXES, np.vstack([first, second])


def icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """The unit sphere: an icosahedron whose faces are split in four ``level`` times, nodes on the sphere."""
    g = (1.0 + 5.0 ** 0.5) / 2.0
    points = np.array([[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0], [0, -1, g], [0, 1, g], [0, -1, -g],
                       [0, 1, -g], [g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]], dtype=float)
    points /= np.linalg.norm(points, axis=1)[:, None]
    triangles = ConvexHull(points).simplices
    for _ in range(level):
        points, mid = edge_nodes(points, triangles, on_sphere=True)
        a, b, c = triangles.T
        bc, ac, ab = mid.T
        triangles = np.vstack([np.column_stack(t) for t in ([a, ab, ac], [ab, b, bc], [ac, bc, c], [ab, bc, ac])])
    return points, triangles


def edge_nodes(points, triangles, on_sphere=False):
    """Points with one node per edge appended (the midpoint, pushed onto the sphere if ``on_sphere``).

    Returns the points and, per triangle, the new nodes of its edges (v1, v2), (v0, v2), (v0, v1).
    """
    edges = np.sort(triangles[:, [[1, 2], [0, 2], [0, 1]]], axis=2).reshape(-1, 2)
    unique, index = np.unique(edges, axis=0, return_inverse=True)
    mid = 0.5 * (points[unique[:, 0]] + points[unique[:, 1]])
    if on_sphere:
        mid /= np.linalg.norm(mid, axis=1)[:, None]
    return np.vstack([points, mid]), points.shape[0] + index.reshape(-1, 3)


def quadratic(points, triangles, on_sphere=False):
    """The (M, 6) P2 triangles of a linear triangulation, edge nodes on the surface."""
    points, mid = edge_nodes(points, triangles, on_sphere)
    return points, np.hstack([triangles, mid])


def random_on_sphere(n: int, seed: int = 0) -> np.ndarray:
    x = np.random.default_rng(seed).normal(size=(n, 3))
    return x / np.linalg.norm(x, axis=1)[:, None]


def random_on_plane(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.0, 1.0, size=(n, 2)) @ AXES


def observed_rate(resolutions, errors) -> float:
    """The slope p of error ~ resolution^-p (resolution: elements per unit length)."""
    return -np.polyfit(np.log(resolutions), np.log(errors), 1)[0]


def rms_error(writer, triangles, reader) -> float:
    m = cp.build_mapping("surface", writer, reader, data_name="test", triangles=triangles)
    return float(np.sqrt(np.mean((m(field(writer)) - field(reader)) ** 2)))


@pytest.mark.parametrize("degree, order", [(1, 2.0), (2, 3.0)])
def test_the_consistent_mapping_on_a_plane_has_the_claimed_order(degree, order):
    reader = random_on_plane(2000)
    sizes, errors = [8, 16, 32], []
    for n in sizes:
        writer, triangles = plane(n)
        if degree == 2:
            writer, triangles = quadratic(writer, triangles)
        errors.append(rms_error(writer, triangles, reader))
    rate = observed_rate(sizes, errors)
    assert abs(rate - order) < RATE_TOL, f"observed rate {rate:.3f} (errors {errors}), claimed {order}"


@pytest.mark.parametrize("degree, order", [(1, 2.0), (2, 3.0)])
def test_the_consistent_mapping_on_a_sphere_has_the_claimed_order(degree, order):
    # the reader's points lie on the exact sphere: the error includes the writer's geometric error
    reader = random_on_sphere(2000)
    levels, errors = [2, 3, 4], []
    for level in levels:
        writer, triangles = icosphere(level)
        if degree == 2:
            writer, triangles = quadratic(writer, triangles, on_sphere=True)
        errors.append(rms_error(writer, triangles, reader))
    rate = observed_rate(2.0 ** np.array(levels), errors)
    assert abs(rate - order) < RATE_TOL, f"observed rate {rate:.3f} (errors {errors}), claimed {order}"


def sphere_hull(n: int, seed: int):
    """A reader's own triangulation of the sphere: the convex hull of random points on it."""
    points = random_on_sphere(n, seed)
    return points, ConvexHull(points).simplices


@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("surface", ["plane", "sphere"])
def test_the_conservative_mapping_preserves_the_sum_of_nodal_forces(surface, degree):
    if surface == "plane":
        writer, _ = plane(12)
        reader, reader_triangles = plane(7)
    else:
        writer, _ = icosphere(3)
        reader, reader_triangles = sphere_hull(300, seed=3)
    if degree == 2:
        reader, reader_triangles = quadratic(reader, reader_triangles, on_sphere=surface == "sphere")
    forces = np.random.default_rng(5).normal(size=(writer.shape[0], 3))
    m = cp.build_mapping("surface-conservative", writer, reader, data_name="Gamma3/force",
                         triangles=reader_triangles)
    mapped = m(forces)
    assert mapped.shape == (reader.shape[0], 3)
    # round-off of the sums: a few ulps of the sum of magnitudes
    tolerance = 16.0 * np.finfo(float).eps * np.abs(forces).sum(axis=0)
    assert np.all(np.abs(mapped.sum(axis=0) - forces.sum(axis=0)) <= tolerance)


@pytest.mark.parametrize("degree", [1, 2])
def test_points_near_the_surface_get_the_value_at_their_foot(degree):
    # on the plane z = 0 the closest point is the orthogonal foot, clamped to the square's boundary,
    # and the writer's interpolant reproduces fields of its degree exactly
    n = 8
    uv = np.array(np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")).reshape(2, -1).T
    writer = np.column_stack([uv, np.zeros(len(uv))])
    _, triangles = plane(n)
    if degree == 2:
        writer, triangles = quadratic(writer, triangles)

    def exact(x):
        return 1 + 2 * x[:, 0] - 3 * x[:, 1] + (degree - 1) * (x[:, 0] ** 2 - x[:, 0] * x[:, 1] + 2 * x[:, 1] ** 2)

    rng = np.random.default_rng(2)
    h = 1.0 / n
    inside = np.column_stack([rng.uniform(0, 1, (50, 2)), rng.uniform(-0.4 * h, 0.4 * h, 50)])
    beyond_edge = np.column_stack([1.0 + rng.uniform(0, 0.3 * h, 20), rng.uniform(0, 1, 20),
                                   rng.uniform(-0.2 * h, 0.2 * h, 20)])
    reader = np.vstack([inside, beyond_edge])
    foot = np.column_stack([np.clip(reader[:, :2], 0.0, 1.0), np.zeros(len(reader))])
    m = cp.build_mapping("surface", writer, reader, data_name="Gamma1/velocity", triangles=triangles)
    np.testing.assert_allclose(m(exact(writer)[:, None])[:, 0], exact(foot), rtol=0, atol=1e-13)


def test_on_a_graded_mesh_the_nearest_triangle_is_found_though_its_centroid_is_far():
    # a fine patch inside large triangles: for 40 % of the points the large triangle holding them is not
    # among the 8 triangles with the nearest centroids; a linear field is exact only on the right one
    s = np.linspace(0.4, 0.6, 30)
    uv = np.vstack([np.array(np.meshgrid(s, s)).reshape(2, -1).T,
                    [[0, 0], [1, 0], [0, 1], [1, 1], [0.5, 0], [0, 0.5]]])
    writer = np.column_stack([uv, np.zeros(len(uv))])
    reader = np.column_stack([np.random.default_rng(0).uniform(0, 1, (2000, 2)), np.zeros(2000)])
    m = cp.build_mapping("surface", writer, reader, triangles=Delaunay(uv).simplices)
    np.testing.assert_allclose(m(linear(writer)), linear(reader), rtol=0, atol=1e-13)


@pytest.mark.parametrize("kind", ["surface", "surface-conservative"])
def test_a_point_far_from_the_surface_is_an_error_naming_the_data_and_the_distance(kind):
    points, triangles = plane(8)
    normal = np.cross(AXES[0], AXES[1])
    far = np.vstack([random_on_plane(5), 0.5 * (AXES[0] + AXES[1]) + 0.25 * normal])
    writer, reader = (points, far) if kind == "surface" else (far, points)
    who = "reader" if kind == "surface" else "writer"
    with pytest.raises(ValueError, match=rf"data 'Gamma2/traction' \(reader 'cell'\).*{who} point 5 .* "
                                         rf"at distance 2\.500e-01 from it"):
        cp.build_mapping(kind, writer, reader, data_name="Gamma2/traction", reader="cell", triangles=triangles)


def test_malformed_triangles_are_errors_saying_what_is_wrong():
    points, triangles = plane(4)
    with pytest.raises(ValueError, match=r"indices must be in \[0, 24\]"):
        cp.build_mapping("surface", points, points, triangles=triangles + 1)
    with pytest.raises(ValueError, match=r"1 of 25 points are nodes of no triangle"):
        cp.build_mapping("surface", points, points, triangles=triangles[triangles.max(axis=1) < 24])
    with pytest.raises(ValueError, match=r"needs its triangles"):
        cp.build_mapping("surface", points, points)
    quad_points, quad = quadratic(points, triangles)
    gmsh_order = quad[:, [0, 1, 2, 5, 3, 4]]  # gmsh: edges (v0, v1), (v1, v2), (v2, v0)
    with pytest.raises(ValueError, match=r"list v0, v1, v2, then the nodes on the edges \(v1, v2\)"):
        cp.build_mapping("surface", quad_points, quad_points, triangles=gmsh_order)
    with pytest.raises(ValueError, match=r"3-D points"):
        cp.build_mapping("surface", points[:, :2], points[:, :2], triangles=triangles)


def test_matching_surfaces_stay_exact_through_matching():
    writer, _ = icosphere(3)
    permutation = np.random.default_rng(0).permutation(len(writer))
    m = cp.build_mapping("matching", writer, writer[permutation], data_name="Gamma2/velocity")
    values = field(writer)
    np.testing.assert_array_equal(m(values), values[permutation])


class Surface(cp.Participant):
    """Writes a fixed field (or its forces) on its own triangulated surface; records what it reads."""

    def __init__(self, name, mesh, writes, value, triangles=None):
        self.name, self.points, self.triangles = name, mesh[0], (mesh[1] if triangles is None else triangles)
        self.writes, self.value, self.read = writes, value, {}

    def interface_points(self, mesh_name):
        return self.points

    def interface_triangles(self, mesh_name):
        return self.triangles

    def solve(self, inputs):
        self.read = {k: v.copy() for k, v in inputs.items()}
        return {self.writes: self.value(self.points)}


class NoTriangles(Surface):
    interface_triangles = cp.Participant.interface_triangles


def surface_scheme(gel_class=Surface, first="Gamma3/displacement"):
    """A gel writing a linear field and a cell writing forces, on non-matching tilted planes.

    Both mappings project onto the gel's triangles (the writer's for the
    consistent one, the reader's for the conservative one): the cell needs none.
    """
    gel = gel_class("gel", plane(9), "Gamma3/displacement", linear)
    cell = NoTriangles("cell", plane(5), "Gamma3/force", lambda x: np.outer(np.ones(len(x)), [1.0, 2.0, -1.0]))
    data = [cp.Data("Gamma3/displacement", "Gamma3", 1, "gel", ("cell",), mapping="surface"),
            cp.Data("Gamma3/force", "Gamma3", 3, "cell", ("gel",), mapping="surface-conservative")]
    config = {"scheme": "serial-implicit", "order": ["gel", "cell"], "verbose": False,
              "convergence": [{"type": "relative", "limit": 1e-12}], "acceleration": {"type": "none"}}
    return cp.build_scheme(config, [gel, cell], sorted(data, key=lambda d: d.name != first)), gel, cell


def test_a_scheme_maps_through_the_participants_triangles():
    scheme, gel, cell = surface_scheme()
    assert scheme.solve().converged
    # the writer's linear interpolant reproduces a linear field at every reader point
    np.testing.assert_allclose(cell.read["Gamma3/displacement"], linear(cell.points), rtol=0, atol=1e-13)
    # the cell's forces reach the gel, through the gel's triangles, with their total
    total = cell.value(cell.points).sum(axis=0)
    np.testing.assert_allclose(gel.read["Gamma3/force"].sum(axis=0), total, rtol=1e-14)  # round-off


@pytest.mark.parametrize("first, reader, kind", [("Gamma3/displacement", "cell", "surface"),
                                                 ("Gamma3/force", "gel", "surface-conservative")])
def test_a_surface_mapping_without_interface_triangles_is_an_error_naming_who_lacks_them(first, reader, kind):
    with pytest.raises(ValueError, match=rf"data '{first}' \(reader '{reader}', mapping '{kind}'\): a surface "
                                         rf"mapping projects onto the triangles of participant 'gel' on mesh "
                                         rf"'Gamma3', which gives none: implement its interface_triangles"):
        surface_scheme(gel_class=NoTriangles, first=first)
