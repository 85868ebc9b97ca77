"""Mappings of interface data between non-matching triangulated surfaces in 3-D.

Both mappings are sparse matrices ``M`` of shape ``(N_reader, N_writer)``,
like those of :mod:`coupling.mapping`, built from the triangles of one
participant's surface (:meth:`coupling.Participant.interface_triangles`):

* ``"surface"`` (consistent): each reader point ``q`` is projected onto the
  writer's triangulated surface, at the closest point ``x(ξ*)`` of the
  nearest triangle, and receives the writer's nodal values interpolated there,
  ``Σ_a N_a(ξ*) v_a``.  The rows of ``M`` sum to one.
* ``"surface-conservative"``: ``M = Lᵀ`` with ``L`` the ``"surface"`` map from
  the *reader's* triangles to the writer's points.  Since the rows of ``L``
  sum to one, ``Σ_reader M f = Σ_writer f`` exactly: use it for nodal forces.

Triangles are ``(M, 3)`` (linear, nodes ``v0, v1, v2``) or ``(M, 6)``
(quadratic, isoparametric: ``v0, v1, v2`` then the nodes on the edges
``(v1, v2)``, ``(v0, v2)``, ``(v0, v1)``, the order of dolfinx/basix; a gmsh
6-node triangle ``t`` is ``t[:, [0, 1, 2, 4, 5, 3]]``), indices into the
participant's interface points.  Every point must be a node of a triangle.

Order of accuracy (``h`` the writer's triangle size; the data, the surface
and the writer's nodes on it smooth).  Linear triangles give second order with
no correction: a reader point ``q`` on the surface is O(h²) from the flat
triangles (their chord error), and its foot ``p`` on them lies O(h³) along the
surface from ``q``, since the triangles' normals are within O(h) of the
surface's; the linear interpolant at ``p`` is within O(h²) of ``v(p)``, and
``v(p)`` within O(h²) of ``v(q)``: **O(h²), curvature included**.  (A quadratic
correction built from linear data alone would need normals or a recovered
Hessian that participants do not provide.)  Quadratic triangles: ``q`` is
projected onto the curved triangle by Gauss–Newton steps started from the flat
triangle's closest point; the curved surface departs from the true one by
O(h³) and the P2 interpolant's error is O(h³): **O(h³)**.  The transpose of a
P2 map gives vertex nodes negative shares near edge midpoints (the P2 vertex
functions ``λ(2λ - 1)`` are negative there); the sum is still preserved.

Points off the surface are projected onto it if their distance is at most
``0.5 ×`` the local mesh size (the larger of the nearest triangle's longest
edge and the distance from the point to its nearest neighbour among the
points mapped): two discretisations of one smooth surface are apart by their
chord errors, at most 0.195 of an edge even for an icosahedron in its
sphere.  A point farther off raises a :class:`ValueError` naming the data and
the distance.  A point a distance δ off a curved surface gets the value at its
foot on the triangles, which on linear triangles lies O(δ h) along the surface
from the exact foot (their normals tilt by O(h)): O(h³) for the gap δ = O(h²)
between two discretisations.

Candidate triangles come from KD-trees of the triangle centroids, one per
band of triangle sizes; a query keeps asking a band for more candidates until
the farthest returned centroid is farther than the nearest triangle found plus
the band's largest triangle radius, so the nearest triangle is never missed,
on graded meshes too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

__all__ = ["SURFACE_MAPPINGS", "surface_interpolation_matrix", "surface_mapping_matrix", "surface_mass_matrix"]

SURFACE_MAPPINGS = ("surface", "surface-conservative")

_GAP_FACTOR = 0.5
_P2_ORDER_FACTOR = 0.25
_CANDIDATES = 8
_NEWTON_ITERATIONS = 20
_NEWTON_TOL = 1e-13
# (v1, v2), (v0, v2), (v0, v1): the edge of the P2 node 3, 4, 5
_P2_EDGES = np.array([[1, 2], [0, 2], [0, 1]])


@dataclass(frozen=True)
class _Surface:
    """Triangle geometry for the closest-point search (arrays per triangle)."""

    nodes: np.ndarray      # (n, 3) node coordinates
    triangles: np.ndarray  # (M, 3|6) node indices
    centroids: np.ndarray  # (M, 3)
    radius: np.ndarray     # (M,) bound on |x - centroid| over the (curved) triangle
    bulge: np.ndarray      # (M,) bound on |curved - flat| at equal ξ (0 for linear triangles)
    size: np.ndarray       # (M,) longest edge
    origin: tuple          # vertex a, per coordinate: three (M,) arrays
    e0: tuple              # b - a, per coordinate
    e1: tuple              # c - a, per coordinate

    @property
    def quadratic(self) -> bool:
        return self.triangles.shape[1] == 6


def triangle_owner(kind: str, writer: str, reader: str) -> str | None:
    """The participant whose triangles mapping ``kind`` projects onto, or ``None`` for a curve mapping."""
    if kind == "surface":
        return writer
    if kind == "surface-conservative":
        return reader
    return None


def participant_triangles(participant: Any, mesh_name: str, what: str) -> np.ndarray:
    """``participant.interface_triangles(mesh_name)`` as an integer array; a clear error if it is missing."""
    try:
        raw = participant.interface_triangles(mesh_name)
    except NotImplementedError:
        raw = None
    if raw is None:
        raise ValueError(
            f"{what}: a surface mapping projects onto the triangles of participant "
            f"{participant.name!r} on mesh {mesh_name!r}, which gives none: implement its "
            f"interface_triangles(mesh_name), returning an (M, 3) or (M, 6) array of indices into "
            f"its interface points, replicated on every rank")
    return np.asarray(raw)


def check_triangles(triangles: np.ndarray, n_points: int, what: str) -> np.ndarray:
    """Validated ``(M, 3|6)`` int64 triangles: indices in range, every point a node of one."""
    tri = np.asarray(triangles)
    if tri.ndim != 2 or tri.shape[0] == 0 or tri.shape[1] not in (3, 6):
        raise ValueError(f"{what}: triangles must be a non-empty (M, 3) or (M, 6) array, got shape "
                         f"{tri.shape}")
    if tri.dtype.kind not in "iu" and not np.array_equal(tri, np.round(tri)):
        raise ValueError(f"{what}: triangles must hold integer point indices")
    tri = tri.astype(np.int64)
    if tri.min() < 0 or tri.max() >= n_points:
        raise ValueError(f"{what}: triangle node indices must be in [0, {n_points - 1}], got "
                         f"[{tri.min()}, {tri.max()}]")
    unused = np.setdiff1d(np.arange(n_points), tri)
    if unused.size:
        raise ValueError(f"{what}: {unused.size} of {n_points} points are nodes of no triangle "
                         f"(e.g. point {int(unused[0])}); every interface point must be a node "
                         f"(give (M, 6) triangles for points at P2 nodes)")
    return tri


def _surface(nodes: np.ndarray, triangles: np.ndarray, what: str) -> _Surface:
    """The search geometry of a triangulated surface; degenerate triangles and misordered P2 nodes raise."""
    corners = nodes[triangles[:, :3]]
    edges = corners[:, [1, 2, 0]] - corners[:, [2, 0, 1]]  # edge i is opposite vertex i
    lengths = np.linalg.norm(edges, axis=2)
    size = lengths.max(axis=1)
    area2 = np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1)
    flat = np.flatnonzero(area2 <= 1e-12 * size ** 2)
    if flat.size:
        j = int(flat[0])
        raise ValueError(f"{what}: {flat.size} triangles are degenerate (zero area), e.g. triangle {j} "
                         f"with nodes {triangles[j].tolist()}")
    centroids = corners.mean(axis=1)
    bulge = np.zeros(len(triangles))
    if triangles.shape[1] == 6:
        mid = 0.5 * (corners[:, _P2_EDGES[:, 0]] + corners[:, _P2_EDGES[:, 1]])
        dev = np.linalg.norm(nodes[triangles[:, 3:]] - mid, axis=2)
        _check_p2_order(dev, lengths, triangles, what)
        bulge = 4.0 / 3.0 * dev.max(axis=1)  # |Σ 4 λi λj dev_ij| ≤ max|dev| · 4 max Σ λi λj
    radius = np.linalg.norm(corners - centroids[:, None], axis=2).max(axis=1) + bulge
    e0, e1 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    return _Surface(nodes, triangles, centroids, radius, bulge, size, tuple(corners[:, 0].T.copy()),
                    tuple(e0.T.copy()), tuple(e1.T.copy()))


def _check_p2_order(dev: np.ndarray, lengths: np.ndarray, triangles: np.ndarray, what: str) -> None:
    """Raise if a P2 edge node is far from the midpoint of the edge the node order assigns it to."""
    bad = np.argwhere(dev > _P2_ORDER_FACTOR * lengths)
    if bad.size:
        j, e = (int(v) for v in bad[0])
        a, b = _P2_EDGES[e]
        raise ValueError(
            f"{what}: node {3 + e} of triangle {j} ({triangles[j].tolist()}) is {dev[j, e]:.3g} from the "
            f"midpoint of its edge (v{a}, v{b}) of length {lengths[j, e]:.3g}; (M, 6) triangles list "
            f"v0, v1, v2, then the nodes on the edges (v1, v2), (v0, v2), (v0, v1)")


def _flat_closest(surface: _Surface, q: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of the flat triangles ``tri`` ``(p,)`` to the points ``q`` ``(p, 3)``, pair by pair.

    Returns their reference coordinates ``(p, 2)`` and distances ``(p,)``.
    """
    v = [q[:, i] - surface.origin[i][tri] for i in range(3)]
    return _affine_closest(v, [x[tri] for x in surface.e0], [x[tri] for x in surface.e1])


def _affine_closest(v: list, e0: list, e1: list) -> tuple[np.ndarray, np.ndarray]:
    """Closest point to ``q`` of the triangle ``a + s e0 + t e1`` (``s, t ≥ 0``, ``s + t ≤ 1``).

    ``v = q - a``, ``e0`` and ``e1`` are lists of their three coordinates
    (arrays of one shape).  Inside the triangle the closest point is the
    orthogonal projection, outside the closest point of the nearest edge.
    Returns ``(s, t)`` stacked on a last axis, and the distance.
    """
    d00, d01, d11 = (sum(x[i] * y[i] for i in range(3)) for x, y in ((e0, e0), (e0, e1), (e1, e1)))
    d0, d1 = sum(v[i] * e0[i] for i in range(3)), sum(v[i] * e1[i] for i in range(3))
    det = d00 * d11 - d01 ** 2
    s, t = (d11 * d0 - d01 * d1) / det, (d00 * d1 - d01 * d0) / det
    u2 = np.clip((d1 - d0 - d01 + d00) / (d11 - 2.0 * d01 + d00), 0.0, 1.0)  # on a + e0 + u (e1 - e0)
    zero = np.zeros_like(s)
    options = [(s, t), (np.clip(d0 / d00, 0.0, 1.0), zero), (zero, np.clip(d1 / d11, 0.0, 1.0)), (1.0 - u2, u2)]
    best_s, best_t, best = s, t, np.full(s.shape, np.inf)
    inside = (s >= 0.0) & (t >= 0.0) & (s + t <= 1.0)
    for j, (so, to) in enumerate(options):
        dist2 = sum((v[i] - so * e0[i] - to * e1[i]) ** 2 for i in range(3))
        if j == 0:
            dist2 = np.where(inside, dist2, np.inf)
        better = dist2 < best
        best = np.where(better, dist2, best)
        best_s, best_t = np.where(better, so, best_s), np.where(better, to, best_t)
    return np.stack([best_s, best_t], axis=-1), np.sqrt(best)


def _p2_shape(st: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """P2 shape functions ``(…, 6)`` and their derivatives ``(…, 6, 2)`` in ``(s, t)`` at ``st`` ``(…, 2)``."""
    s, t = st[..., 0], st[..., 1]
    l0 = 1.0 - s - t
    n = np.stack([l0 * (2 * l0 - 1), s * (2 * s - 1), t * (2 * t - 1), 4 * s * t, 4 * l0 * t, 4 * l0 * s],
                 axis=-1)
    zero = 0.0 * s
    ds = np.stack([1 - 4 * l0, 4 * s - 1, zero, 4 * t, -4 * t, 4 * (l0 - s)], axis=-1)
    dt = np.stack([1 - 4 * l0, zero, 4 * t - 1, 4 * s, 4 * (l0 - t), -4 * s], axis=-1)
    return n, np.stack([ds, dt], axis=-1)


def _curved_closest(xnodes: np.ndarray, q: np.ndarray, st: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of P2 triangles (nodes ``(p, 6, 3)``) to ``q`` ``(p, 3)`` by Gauss–Newton from ``st``.

    Each step replaces the curved triangle by its linearization at ``st``,
    ``x(st) + J (ξ - st)`` over the reference triangle (``J = ∂x/∂(s, t)``),
    and moves to the closest point of that flat triangle; the fixed point is
    the constrained stationary point of ``|q - x(ξ)|``.
    """
    coords = [np.ascontiguousarray(xnodes[:, :, i]) for i in range(3)]  # (p, 6) per coordinate
    for _ in range(_NEWTON_ITERATIONS):
        n, dn = _p2_shape(st)
        ds, dt = dn[..., 0], dn[..., 1]
        e0 = [(ds * c).sum(axis=1) for c in coords]
        e1 = [(dt * c).sum(axis=1) for c in coords]
        v = [q[:, i] - (n * coords[i]).sum(axis=1) + e0[i] * st[:, 0] + e1[i] * st[:, 1] for i in range(3)]
        new, _ = _affine_closest(v, e0, e1)
        moved = float(np.abs(new - st).max(initial=0.0))
        st = new
        if moved < _NEWTON_TOL:  # reference coordinates: an absolute tolerance
            break
    n, _ = _p2_shape(st)
    return st, np.sqrt(sum((q[:, i] - (n * coords[i]).sum(axis=1)) ** 2 for i in range(3)))


def _nearest_among(surface: _Surface, q: np.ndarray, cand: np.ndarray, hopeful: np.ndarray,
                   known: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per query ``q`` ``(n, 3)``, the nearest of its candidate triangles ``cand`` ``(n, k)`` that are ``hopeful``.

    ``known`` ``(n,)`` is the distance of the nearest triangle found before
    (``inf`` if none): curved candidates that cannot beat it are skipped.
    Returns the triangle, the reference coordinates ``(s, t)`` of the closest
    point on it and the distance, ``(n,)``, ``(n, 2)``, ``(n,)`` (distance
    ``inf`` where no candidate is hopeful or can beat ``known``).
    """
    rows, cols = np.nonzero(hopeful)
    st, dist = np.zeros(cand.shape + (2,)), np.full(cand.shape, np.inf)
    st[rows, cols], dist[rows, cols] = _flat_closest(surface, q[rows], cand[rows, cols])
    if surface.quadratic:
        st, dist = _curved_distances(surface, q, cand, st, dist, known)
    best = np.argmin(dist, axis=1)
    everyone = np.arange(q.shape[0])
    return cand[everyone, best], st[everyone, best], dist[everyone, best]


def _curved_distances(surface: _Surface, q: np.ndarray, cand: np.ndarray, st: np.ndarray,
                      dist: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points on the curved candidates that can be the nearest (``inf`` for the others).

    A curved triangle is within its ``bulge`` of its flat one, so a candidate
    whose flat distance minus its bulge exceeds another's plus its bulge, or
    the distance ``known`` before, cannot be the nearest (an ``inf`` flat
    distance: not a candidate).
    """
    bulge = surface.bulge[cand]
    bound = np.minimum((dist + bulge).min(axis=1), known)[:, None]
    rows, cols = np.nonzero(np.isfinite(dist) & (dist - bulge <= bound))
    xnodes = surface.nodes[surface.triangles[cand[rows, cols]]]
    st_curved, dist_curved = _curved_closest(xnodes, q[rows], st[rows, cols])
    st = st.copy()
    st[rows, cols] = st_curved
    out = np.full(dist.shape, np.inf)
    out[rows, cols] = dist_curved
    return st, out


def _size_bands(surface: _Surface) -> list[np.ndarray]:
    """Triangle indices in bands of radii within a factor 2 (one band on a quasi-uniform mesh), largest first."""
    band = np.floor(np.log(surface.radius / surface.radius.min()) / np.log(2.0)).astype(np.int64)
    bands = [np.flatnonzero(band == b) for b in np.unique(band)]
    return sorted(bands, key=lambda m: -m.size)  # the largest first: the best first bound


def _search(surface: _Surface, queries: np.ndarray, rows: np.ndarray, band: tuple[np.ndarray, cKDTree, float],
            k: int, best: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Update ``best`` (triangle, ``(s, t)``, distance) of queries ``rows`` from the ``k`` triangles of a
    band (members, KD-tree of their centroids, largest radius) with the nearest centroids.

    Returns the distance of the farthest of these centroids, per query.
    """
    members, tree, largest = band
    centre_dist, local = tree.query(queries[rows], k=k)
    centre_dist, local = centre_dist.reshape(rows.size, k), local.reshape(rows.size, k)
    hopeful = centre_dist - largest < best[2][rows, None]  # the others cannot beat the best so far
    tri, st, dist = _nearest_among(surface, queries[rows], members[local], hopeful, best[2][rows])
    better = dist < best[2][rows]
    r = rows[better]
    best[0][r], best[1][r], best[2][r] = tri[better], st[better], dist[better]
    return centre_dist[:, -1]


def _closest(surface: _Surface, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest triangle, reference coordinates of the closest point on it, and distance, per query.

    Triangles are searched by bands of similar size, each with a KD-tree of
    its centroids.  In a band, a query is done when its farthest candidate
    centroid is farther than the nearest triangle found so far plus the
    band's largest radius (no other triangle of the band can be nearer); the
    others ask again for four times as many candidates.
    """
    nq = queries.shape[0]
    best = (np.full(nq, -1, dtype=np.int64), np.zeros((nq, 2)), np.full(nq, np.inf))
    bands = [(m, cKDTree(surface.centroids[m]), float(surface.radius[m].max())) for m in _size_bands(surface)]
    everyone = np.arange(nq)
    reach = [_search(surface, queries, everyone, band, min(band[0].size, _CANDIDATES), best) for band in bands]
    for band, far in zip(bands, reach):
        k = min(band[0].size, _CANDIDATES)
        todo = np.flatnonzero(far <= best[2] + band[2])
        while todo.size and k < band[0].size:
            k = min(band[0].size, 4 * k)
            far = _search(surface, queries, todo, band, k, best)
            todo = todo[far <= best[2][todo] + band[2]]
    return best


def _check_gaps(surface: _Surface, queries: np.ndarray, tri: np.ndarray, dist: np.ndarray,
                what: str, names: tuple[str, str]) -> None:
    """Raise if a query point is farther from the surface than ``_GAP_FACTOR`` × the local mesh size."""
    nq = queries.shape[0]
    allowed = _GAP_FACTOR * surface.size[tri]
    bad = np.flatnonzero(dist > allowed)
    if bad.size and nq > 1:  # the queries' own spacing may be the larger local size
        spacing = cKDTree(queries).query(queries[bad], k=2)[0][:, 1]
        allowed[bad] = np.maximum(allowed[bad], _GAP_FACTOR * spacing)
        bad = bad[dist[bad] > allowed[bad]]
    if bad.size:
        i = int(bad[np.argmax(dist[bad])])
        raise ValueError(
            f"surface mapping of {what}: {bad.size} of {nq} {names[0]} points are farther from the "
            f"{names[1]}'s surface than {_GAP_FACTOR} x the local mesh size; {names[0]} point {i} at "
            f"{queries[i].tolist()} is at distance {dist[i]:.3e} from it (allowed {allowed[i]:.3e}): "
            f"the two participants' points do not lie on the same surface")


def _as_points3(points: np.ndarray, what: str) -> np.ndarray:
    """Validated ``(N, 3)`` finite float points."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[0] == 0 or pts.shape[1] != 3:
        raise ValueError(f"{what}: a surface mapping needs a non-empty (N, 3) array of 3-D points, got "
                         f"shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"{what}: points contain NaN or Inf")
    return pts


def surface_interpolation_matrix(nodes: np.ndarray, triangles: np.ndarray, queries: np.ndarray, *,
                                 what: str = "surface", names: tuple[str, str] = ("query", "node")
                                 ) -> sp.csr_matrix:
    """Interpolation from a triangulated surface's nodes to the closest points of query points.

    Each query point ``q`` is projected onto the nearest triangle, at the
    closest point ``x(s, t)``, and gets the weights ``N_a(s, t)`` of the
    triangle's nodes: ``(1 - s - t, s, t)`` for linear triangles, the six P2
    shape functions for quadratic ones (see the module docstring).

    Args:
        nodes: ``(n, 3)`` node coordinates.
        triangles: ``(M, 3)`` or ``(M, 6)`` node indices; every node is in one.
        queries: ``(q, 3)`` points on or near the surface.
        what: Description used in error messages.
        names: What the queries and the nodes are, for messages (e.g.
            ``("reader", "writer")``).

    Returns:
        CSR matrix ``(q, n)`` whose rows sum to one.

    Raises:
        ValueError: On malformed triangles, or a query point farther from the
            surface than half the local mesh size (the message gives the distance).
    """
    xyz = _as_points3(nodes, f"{what}: {names[1]}")
    q = _as_points3(queries, f"{what}: {names[0]}")
    tri = check_triangles(triangles, xyz.shape[0], f"{what}: {names[1]} triangles")
    surface = _surface(xyz, tri, f"{what}: {names[1]} triangles")
    best, st, dist = _closest(surface, q)
    _check_gaps(surface, q, best, dist, what, names)
    if surface.quadratic:
        weights = _p2_shape(st)[0]
    else:
        weights = np.column_stack([1.0 - st[:, 0] - st[:, 1], st[:, 0], st[:, 1]])
    rows = np.repeat(np.arange(q.shape[0]), tri.shape[1])
    return sp.csr_matrix((weights.ravel(), (rows, tri[best].ravel())), shape=(q.shape[0], xyz.shape[0]))


def surface_mapping_matrix(kind: str, writer_points: np.ndarray, reader_points: np.ndarray,
                           triangles: np.ndarray | None, what: str = "surface") -> sp.csr_matrix:
    """The ``(N_reader, N_writer)`` matrix of a surface mapping.

    Args:
        kind: ``"surface"`` (consistent; ``triangles`` are the writer's) or
            ``"surface-conservative"`` (the transpose of the consistent map
            from the reader's triangles to the writer's points; ``triangles``
            are the reader's).
        writer_points: ``(N_writer, 3)`` points of the writer.
        reader_points: ``(N_reader, 3)`` points of the reader.
        triangles: The triangles of the surface projected onto.
        what: Description used in error messages (e.g. the data and the reader).
    """
    owner = triangle_owner(kind, "writer", "reader")
    if owner is None:
        raise ValueError(f"{what}: mapping = {kind!r} is not a surface mapping; allowed: "
                         f"{', '.join(repr(k) for k in SURFACE_MAPPINGS)}")
    if triangles is None:
        raise ValueError(f"{what}: mapping = {kind!r} projects onto the {owner}'s surface and needs "
                         f"its triangles (the {owner}'s interface_triangles)")
    if kind == "surface":
        return surface_interpolation_matrix(writer_points, triangles, reader_points, what=what,
                                            names=("reader", "writer"))
    transpose = surface_interpolation_matrix(reader_points, triangles, writer_points, what=what,
                                             names=("writer", "reader"))
    return transpose.T.tocsr()


# degree-4 rule on the reference triangle (Dunavant): barycentric (a, a, 1 - 2a) and its permutations
_MASS_RULE = [(0.445948490915965, 0.223381589678011), (0.091576213509771, 0.109951743655322)]


def _mass_points() -> tuple[np.ndarray, np.ndarray]:
    st, w = [], []
    for a, weight in _MASS_RULE:
        b = 1.0 - 2.0 * a
        st += [(a, a), (a, b), (b, a)]
        w += [0.5 * weight] * 3                    # the reference triangle's area is 1/2
    return np.array(st), np.array(w)


def surface_mass_matrix(nodes: np.ndarray, triangles: np.ndarray, what: str = "surface") -> sp.csr_matrix:
    """``M_ab = ∫ N_a N_b dA`` over a triangulated surface (linear or isoparametric P2 triangles).

    The matrix that turns nodal values of a density into the consistent
    nodal integrals of it (nodal forces from a traction, say); a degree-4
    rule, exact on flat triangles.
    """
    xyz = _as_points3(nodes, f"{what}: nodes")
    tri = check_triangles(triangles, xyz.shape[0], f"{what}: triangles")
    st, w = _mass_points()
    if tri.shape[1] == 6:
        n, dn = _p2_shape(st)                                       # (q, 6), (q, 6, 2)
    else:
        n = np.column_stack([1.0 - st[:, 0] - st[:, 1], st[:, 0], st[:, 1]])
        dn = np.broadcast_to(np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]]), (len(st), 3, 2))
    x = xyz[tri]                                                    # (M, k, 3)
    tangents = np.einsum("mkd,qke->mqed", x, dn)                    # (M, q, 2, 3)
    area = np.linalg.norm(np.cross(tangents[:, :, 0], tangents[:, :, 1]), axis=2)   # (M, q)
    local = np.einsum("mq,qa,qb->mab", area * w, n, n)
    k = tri.shape[1]
    rows, cols = np.repeat(tri, k, axis=1), np.tile(tri, (1, k))
    return sp.csr_matrix((local.ravel(), (rows.ravel(), cols.ravel())), shape=(len(xyz), len(xyz)))
