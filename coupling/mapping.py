"""Mappings of interface data from a writer's points to a reader's points.

Every mapping is a sparse matrix ``M`` of shape ``(N_reader, N_writer)``
applied to each component: ``values_reader = M @ values_writer``.

* ``"matching"``: conforming interfaces.  Each reader point must coincide with
  a writer point (KD-tree lookup, tolerance ``1e-12`` times the size of the
  writer's bounding box); ``M`` is a 0/1 selection matrix.  A reader point
  without an exact partner raises a :class:`ValueError` naming the data.
* ``"nearest"``: the value of the nearest writer point (first order, O(h)).
* ``"linear"``: the writer's points are ordered along the interface curve
  (see :func:`order_along_curve`) to form a polyline; each reader point is
  projected onto the nearest segment ``[p_i, p_{i+1}]`` at parameter
  ``t ∈ [0, 1]`` and receives ``(1 - t) v_i + t v_{i+1}`` (second order,
  O(h²), for points on a smooth curve).  Rows of ``M`` sum to one.
* ``"conservative"``: ``M = Lᵀ`` with ``L`` the linear map from the
  *reader's* polyline to the writer's points.  Since the rows of ``L`` sum to
  one, ``Σ_reader M f = Σ_writer f``: the total (e.g. of nodal forces) is
  preserved exactly.
* ``"surface"``, ``"surface-conservative"``: their analogues between
  triangulated surfaces in 3-D, see :mod:`coupling.surface_mapping`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from coupling.surface_mapping import SURFACE_MAPPINGS, surface_mapping_matrix

__all__ = ["Mapping", "build_mapping", "order_along_curve", "polyline_interpolation_matrix"]

_MATCH_RTOL = 1e-12
_JUMP_FACTOR = 4.0


@dataclass(frozen=True)
class Mapping:
    """A linear map ``values_reader = matrix @ values_writer``.

    Attributes:
        kind: The mapping kind (``"matching"``, ``"nearest"``, ``"linear"``,
            ``"conservative"``, ``"surface"``, ``"surface-conservative"``).
        matrix: Sparse CSR matrix of shape ``(N_reader, N_writer)``.
        data_name: Name of the mapped data (for messages).
        reader: Name of the reading participant (for messages).
    """

    kind: str
    matrix: sp.csr_matrix
    data_name: str = ""
    reader: str = ""

    @property
    def shape(self) -> tuple[int, int]:
        """``(N_reader, N_writer)``."""
        return self.matrix.shape

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """Map ``values`` of shape ``(N_writer, dim)`` to ``(N_reader, dim)``."""
        values = np.asarray(values, dtype=float)
        if values.shape[0] != self.matrix.shape[1]:
            raise ValueError(f"mapping of {self.data_name!r} to {self.reader!r}: expected "
                             f"{self.matrix.shape[1]} writer rows, got {values.shape[0]}")
        return np.asarray(self.matrix @ values)


def as_points(points: np.ndarray, what: str) -> np.ndarray:
    """Validated ``(N, space_dim)`` float points: non-empty and finite; ``what`` names them in errors."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim == 1:
        pts = pts[:, None]
    if pts.ndim != 2 or pts.shape[0] == 0:
        raise ValueError(f"{what}: points must be a non-empty (N, space_dim) array, got shape "
                         f"{np.shape(points)}")
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"{what}: points contain NaN or Inf")
    return pts


def _greedy_chain(points: np.ndarray, start: int) -> np.ndarray:
    """Order points by repeatedly stepping to the nearest unvisited point."""
    n = points.shape[0]
    tree = cKDTree(points)
    visited = np.zeros(n, dtype=bool)
    order = np.empty(n, dtype=np.int64)
    order[0] = start
    visited[start] = True
    k = min(n, 8)
    current = start
    for i in range(1, n):
        _, candidates = tree.query(points[current], k=k)
        nxt = -1
        for j in np.atleast_1d(candidates):
            if not visited[j]:
                nxt = int(j)
                break
        if nxt < 0:
            unvisited = np.flatnonzero(~visited)
            dist = np.linalg.norm(points[unvisited] - points[current], axis=1)
            nxt = int(unvisited[np.argmin(dist)])
        order[i] = nxt
        visited[nxt] = True
        current = nxt
    return order


def _check_chain(ordered: np.ndarray, steps: np.ndarray, closing: float, closed: bool,
                 what: str) -> None:
    """Raise if a greedy chain is not a plausible ordering of one curve.

    Two symptoms are detected: a point whose nearest neighbour is not next to
    it in the chain (the chain skipped a point and came back for it), and a
    step longer than ``_JUMP_FACTOR`` times both neighbouring steps *and*
    20 times the median step (the points lie on several disjoint curves).
    """
    n = ordered.shape[0]
    _, nearest = cKDTree(ordered).query(ordered, k=2)
    gap = np.abs(nearest[:, 1] - np.arange(n))
    if closed:
        gap = np.minimum(gap, n - gap)
    problem = ""
    if np.any(gap > 1):
        i = int(np.flatnonzero(gap > 1)[0])
        problem = (f"point {ordered[i].tolist()} is not next to its nearest neighbour "
                   f"{ordered[nearest[i, 1]].tolist()} in the chain")
    all_steps = np.concatenate([steps, [closing]]) if closed else steps
    m = all_steps.size
    median = float(np.median(all_steps))
    for i in range(m):
        if problem:
            break
        if closed:
            neighbours = (all_steps[(i - 1) % m], all_steps[(i + 1) % m])
        else:
            neighbours = tuple(all_steps[j] for j in (i - 1, i + 1) if 0 <= j < m)
        if all_steps[i] > _JUMP_FACTOR * max(neighbours) and all_steps[i] > 20.0 * median:
            problem = (f"a step of {all_steps[i]:.3g} between steps of {max(neighbours):.3g} "
                       f"(median {median:.3g})")
    if problem:
        raise ValueError(
            f"{what}: ordering the points along the curve failed: {problem}; the points may "
            f"not lie on a single curve, or the curve may be sampled too coarsely where it "
            f"nearly touches itself.  Return the points in curve order and use "
            f"curve_order='given', or use curve_order='angle' for a closed star-shaped curve.")


def order_along_curve(points: np.ndarray, curve: str = "auto", order: str = "chain",
                      what: str = "curve") -> tuple[np.ndarray, bool]:
    """Order points along the interface curve they sample.

    Args:
        points: ``(N, space_dim)`` points on one connected curve.
        curve: ``"open"``, ``"closed"`` or ``"auto"``.  With ``"auto"`` the
            curve is closed if the gap from the last to the first ordered
            point is at most twice the longer of the two end segments
            (``"angle"`` ordering: always closed).
        order: ``"chain"``: greedy nearest-neighbour chain started from point 0;
            its last point is an end point of an open curve, and a second chain
            started there gives the order.  A chain that skipped a point, or
            jumps between disjoint pieces, is reported as an error.
            ``"angle"``: sort by polar angle about the centroid (2-D closed,
            star-shaped curves; for ``curve="open"`` the curve is cut at the
            largest angular gap).  ``"given"``: keep the input order.
        what: Description used in error messages.

    Returns:
        ``(permutation, closed)``: ``points[permutation]`` are in curve order.

    Raises:
        ValueError: If the chain ordering finds a jump or the options are invalid.
    """
    pts = as_points(points, what)
    n = pts.shape[0]
    if curve not in ("auto", "open", "closed"):
        raise ValueError(f"{what}: curve = {curve!r} is not allowed; allowed: 'auto', 'open', 'closed'")
    if n == 1:
        return np.zeros(1, dtype=np.int64), False
    if order == "angle":
        return _angle_order(pts, curve, what)
    if order == "given":
        perm = np.arange(n)
    elif order == "chain":
        end = _greedy_chain(pts, 0)[-1]
        perm = _greedy_chain(pts, int(end))
    else:
        raise ValueError(f"{what}: curve_order = {order!r} is not allowed; allowed: 'chain', "
                         f"'angle', 'given'")
    ordered = pts[perm]
    steps = np.linalg.norm(np.diff(ordered, axis=0), axis=1)
    closing = float(np.linalg.norm(ordered[-1] - ordered[0]))
    if curve == "closed":
        closed = n >= 3
    elif curve == "open":
        closed = False
    else:
        closed = n >= 3 and closing <= 2.0 * max(steps[0], steps[-1])
    if order == "chain" and n >= 3:
        _check_chain(ordered, steps, closing, closed, what)
    return perm, closed


def _angle_order(pts: np.ndarray, curve: str, what: str) -> tuple[np.ndarray, bool]:
    """:func:`order_along_curve` by polar angle about the centroid (an open curve is cut at the largest gap)."""
    if pts.shape[1] != 2:
        raise ValueError(f"{what}: curve_order = 'angle' needs 2-D points, got "
                         f"space_dim = {pts.shape[1]}")
    centre = pts.mean(axis=0)
    angle = np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0])
    perm = np.argsort(angle, kind="stable")
    if curve == "open":
        sorted_angle = angle[perm]
        gaps = np.diff(np.concatenate([sorted_angle, [sorted_angle[0] + 2.0 * np.pi]]))
        cut = int(np.argmax(gaps))
        perm = np.roll(perm, -(cut + 1))
        return perm, False
    return perm, True


def polyline_interpolation_matrix(nodes: np.ndarray, closed: bool,
                                  queries: np.ndarray) -> sp.csr_matrix:
    """Linear interpolation from polyline nodes to the projections of query points.

    Each query point ``q`` is projected onto the nearest segment
    ``[a, b] = [nodes[i], nodes[i+1]]`` (plus ``[nodes[-1], nodes[0]]`` if
    ``closed``) at ``t = clip((q - a)·(b - a) / |b - a|², 0, 1)`` and gets the
    weights ``1 - t`` on node ``i`` and ``t`` on node ``i + 1``.  Candidate
    segments are those incident to the 8 nearest nodes of ``q``.

    Args:
        nodes: ``(m, space_dim)`` polyline nodes in curve order.
        closed: Whether the polyline closes on itself.
        queries: ``(q, space_dim)`` points to interpolate to.

    Returns:
        CSR matrix ``(q, m)`` whose rows sum to one.
    """
    nodes = np.asarray(nodes, dtype=float)
    queries = np.asarray(queries, dtype=float)
    m = nodes.shape[0]
    nq = queries.shape[0]
    if m == 1:
        return sp.csr_matrix((np.ones(nq), (np.arange(nq), np.zeros(nq, dtype=np.int64))),
                             shape=(nq, 1))
    n_segments = m if (closed and m >= 3) else m - 1
    seg_start = np.arange(n_segments)
    seg_end = (seg_start + 1) % m
    left, right = _incident_segments(m, n_segments)
    k = min(m, 8)
    _, near = cKDTree(nodes).query(queries, k=k)
    near = near.reshape(nq, k)
    candidates = np.concatenate([left[near], right[near]], axis=1)  # (nq, 2k)
    best, tb = _nearest_projection(nodes[seg_start[candidates]], nodes[seg_end[candidates]], queries)
    rows = np.arange(nq)
    seg = candidates[rows, best]
    i0 = seg_start[seg]
    i1 = seg_end[seg]
    matrix = sp.coo_matrix((np.concatenate([1.0 - tb, tb]),
                            (np.concatenate([rows, rows]), np.concatenate([i0, i1]))),
                           shape=(nq, m))
    return matrix.tocsr()


def _incident_segments(m: int, n_segments: int) -> tuple[np.ndarray, np.ndarray]:
    """The two segments incident to each of ``m`` nodes: ``i - 1`` and ``i`` (wrapped if closed)."""
    left = np.arange(m) - 1
    right = np.arange(m).copy()
    if n_segments == m:
        left %= m
    else:
        left = np.where(left < 0, 0, left)
        right = np.where(right >= n_segments, n_segments - 1, right)
    return left, right


def _nearest_projection(a: np.ndarray, b: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per query, the candidate segment ``[a, b]`` nearest to it and the parameter ``t`` of its projection.

    ``a`` and ``b`` are ``(q, c, space_dim)``: the ends of each query's ``c`` candidate segments.
    Returns the index of the nearest candidate and its ``t``, both ``(q,)``.
    """
    ab = b - a
    length2 = np.einsum("qcs,qcs->qc", ab, ab)
    q = queries[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(length2 > 0.0, np.einsum("qcs,qcs->qc", q - a, ab) / length2, 0.0)
    t = np.clip(t, 0.0, 1.0)
    proj = a + t[..., None] * ab
    dist2 = np.einsum("qcs,qcs->qc", q - proj, q - proj)
    best = np.argmin(dist2, axis=1)
    return best, t[np.arange(queries.shape[0]), best]


def build_mapping(kind: str, writer_points: np.ndarray, reader_points: np.ndarray, *,
                  data_name: str = "", reader: str = "", curve: str = "auto",
                  curve_order: str = "chain", triangles: np.ndarray | None = None) -> Mapping:
    """Build the mapping of a data from its writer's points to a reader's points.

    Args:
        kind: ``"matching"``, ``"nearest"``, ``"linear"``, ``"conservative"``,
            ``"surface"`` or ``"surface-conservative"``.
        writer_points: ``(N_writer, space_dim)`` points of the writer.
        reader_points: ``(N_reader, space_dim)`` points of the reader.
        data_name: Name of the data (for messages).
        reader: Name of the reader (for messages).
        curve: Curve type for ``"linear"``/``"conservative"``, see
            :func:`order_along_curve`.
        curve_order: Ordering strategy, see :func:`order_along_curve`.
        triangles: For ``"surface"`` the writer's triangles, for
            ``"surface-conservative"`` the reader's, see
            :func:`coupling.surface_mapping.surface_mapping_matrix`.

    Returns:
        The :class:`Mapping`.

    Raises:
        ValueError: If a ``"matching"`` reader point has no exact partner, a
            surface mapping's point is far from the surface, the space
            dimensions differ, or ``kind`` is unknown.
    """
    what = f"data {data_name!r} (reader {reader!r})"
    wp = as_points(writer_points, f"{what}: writer")
    rp = as_points(reader_points, f"{what}: reader")
    if wp.shape[1] != rp.shape[1]:
        raise ValueError(f"{what}: writer points are {wp.shape[1]}-D but reader points are "
                         f"{rp.shape[1]}-D")
    nr, nw = rp.shape[0], wp.shape[0]
    rows = np.arange(nr)
    if kind in ("matching", "nearest"):
        dist, idx = cKDTree(wp).query(rp)
        if kind == "matching":
            _check_matching(wp, rp, dist, what)
        matrix = sp.csr_matrix((np.ones(nr), (rows, idx)), shape=(nr, nw))
    elif kind == "linear":
        perm, closed = order_along_curve(wp, curve, curve_order, what=f"{what}: writer curve")
        local = polyline_interpolation_matrix(wp[perm], closed, rp).tocoo()
        matrix = sp.csr_matrix((local.data, (local.row, perm[local.col])), shape=(nr, nw))
    elif kind == "conservative":
        perm, closed = order_along_curve(rp, curve, curve_order, what=f"{what}: reader curve")
        local = polyline_interpolation_matrix(rp[perm], closed, wp).tocoo()  # (nw, nr) consistent
        matrix = sp.csr_matrix((local.data, (perm[local.col], local.row)), shape=(nr, nw))
    elif kind in SURFACE_MAPPINGS:
        matrix = surface_mapping_matrix(kind, wp, rp, triangles, what)
    else:
        raise ValueError(f"{what}: mapping = {kind!r} is not allowed; allowed values: "
                         f"'matching', 'nearest', 'linear', 'conservative', 'surface', "
                         f"'surface-conservative'")
    return Mapping(kind=kind, matrix=matrix, data_name=data_name, reader=reader)


def _check_matching(wp: np.ndarray, rp: np.ndarray, dist: np.ndarray, what: str) -> None:
    """Raise unless every reader point is within ``_MATCH_RTOL`` (relative) of its nearest writer point."""
    nr, nw = rp.shape[0], wp.shape[0]
    size = float(np.max(np.ptp(wp, axis=0))) if nw > 1 else 0.0
    tol = _MATCH_RTOL * max(size, float(np.max(np.abs(wp))), 1e-300)
    bad = np.flatnonzero(dist > tol)
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"matching mapping of {what}: {bad.size} of {nr} reader points have no "
            f"writer point within {tol:.2e}; e.g. reader point {i} at {rp[i].tolist()} "
            f"is {dist[i]:.3e} from the nearest writer point.  Use mapping='nearest', "
            f"'linear' or 'conservative' for non-matching interfaces.")
