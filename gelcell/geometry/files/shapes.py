"""Plane geometry on the sampled curves of a geometry file: straightness, inside, areas, distances.

A curve is sampled as a polyline (:mod:`gelcell.geometry.files.read`); these
helpers answer the analysis's questions on those polylines.
"""

from __future__ import annotations

import math

import numpy as np

from gelcell.geometry.files.read import GeometryInfo

__all__ = ["TOUCH", "symmetry_axis", "is_straight", "is_inside", "area_and_centroid", "connected_surfaces",
           "distance_to_polyline", "where"]


def symmetry_axis(c: int, p: np.ndarray, scale: float, name: str | None = None):
    """``(horizontal, None)`` for a straight axis-aligned symmetry curve, else ``(None, problem)``."""
    label = f"symmetry curve {c} {where(p)}" + (f" ('{name}')" if name else "")
    if not is_straight(p, scale):
        return None, f"{label} is not straight"
    horizontal = abs(p[0, 1] - p[-1, 1]) <= 1e-9 * scale
    vertical = abs(p[0, 0] - p[-1, 0]) <= 1e-9 * scale
    if not (horizontal or vertical):
        return None, f"{label} is neither horizontal nor vertical: gelcell supports axis-aligned symmetry lines only"
    return horizontal, None


def is_straight(points: np.ndarray, scale: float) -> bool:
    a, b = points[0], points[-1]
    t = b - a
    L = np.linalg.norm(t)
    if L == 0:
        return False
    n = np.array([-t[1], t[0]]) / L
    return float(np.abs((points - a) @ n).max()) <= 1e-8 * max(scale, L)


def is_inside(point, loops) -> bool:
    """Even-odd rule over all loops of a surface (holes included)."""
    from matplotlib.path import Path
    count = 0
    for loop in loops:
        if len(loop) > 2 and Path(loop).contains_point(point):
            count += 1
    return count % 2 == 1


def area_and_centroid(loops) -> tuple[float, np.ndarray]:
    area, cx, cy = 0.0, 0.0, 0.0
    for loop in loops:
        x, y = loop[:, 0], loop[:, 1]
        x1, y1 = np.roll(x, -1), np.roll(y, -1)
        cr = x * y1 - x1 * y
        a = 0.5 * cr.sum()
        # orient every loop as a boundary of the surface: the outer loop counts positive, holes negative
        sign = 1.0 if a >= 0 else -1.0
        area += sign * a
        cx += sign * ((x + x1) * cr).sum() / 6.0
        cy += sign * ((y + y1) * cr).sum() / 6.0
    return abs(area), np.array([cx, cy]) / area if area else np.zeros(2)


def connected_surfaces(surfaces: list, info: GeometryInfo) -> list[set]:
    """Connected groups of ``surfaces`` (sharing a curve)."""
    parent = {s: s for s in surfaces}

    def find(s):
        while parent[s] != s:
            parent[s] = parent[parent[s]]
            s = parent[s]
        return s
    for up in info.adjacent.values():
        mine = [s for s in up if s in parent]
        for s in mine[1:]:
            parent[find(s)] = find(mine[0])
    comps: dict = {}
    for s in surfaces:
        comps.setdefault(find(s), set()).add(s)
    return list(comps.values())


#: a gap between a cell and another cell or a gel boundary below this fraction of the cell's size is
#: taken as touching
TOUCH = 1e-3


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> float:
    """Smallest distance from ``points`` to the segments of ``polyline``."""
    if len(polyline) == 0 or len(points) == 0:
        return math.inf
    if len(polyline) == 1:
        return float(np.linalg.norm(points - polyline[0], axis=1).min())
    a, b = polyline[:-1], polyline[1:]
    t = b - a
    ll = np.maximum((t * t).sum(axis=1), 1e-300)
    rel = points[:, None, :] - a[None, :, :]
    s = np.clip((rel * t[None]).sum(axis=2) / ll[None], 0.0, 1.0)
    proj = a[None] + s[..., None] * t[None]
    return float(np.linalg.norm(points[:, None, :] - proj, axis=2).min())


def where(points: np.ndarray) -> str:
    m = points[len(points) // 2] if points.shape[1] == 2 else points.mean(axis=0)
    return "near (" + ", ".join(f"{v:.4g}" for v in m) + ")"
