"""The cells of a geometry file: each inside the gel with a gap to its boundaries and to the other cells.

A gap below :data:`~gelcell.geometry.files.shapes.TOUCH` x the cell's size
counts as touching (it could not be meshed); the samples of a curve are
joined by straight segments.  A cell's nominal circle is centred on its
centroid (on the symmetry line of a cut cell) through the boundary point
farthest from it: exact for a circular cell.
"""

from __future__ import annotations

import numpy as np

from gelcell.geometry.files.read import GeometryInfo
from gelcell.geometry.files.shapes import (TOUCH, area_and_centroid, distance_to_polyline, is_inside, symmetry_axis,
                                           where)
from gelcell.geometry.layout import CellSpec
from gelcell.geometry.tags import cell_region_tag, gamma2_name, gamma2_tag

__all__ = ["CellGeometry", "cell_specs"]


class CellGeometry:
    """The curves and points of every cell of a file, for the checks below.

    Args:
        info: the file's content.
        cells: ``(name, K, [surfaces])`` of every cell, in order.
        gamma2: cell index (1-based) -> its curves in the gel.
        cut: cell index -> its curves on symmetry lines (a half cell).
        gel: the gel's surfaces.
    """

    def __init__(self, info: GeometryInfo, cells: list, gamma2: dict, cut: dict, gel: set):
        self.info, self.cells, self.gamma2, self.cut = info, cells, gamma2, cut
        self.gel_loops = [lp for s in gel for lp in info.surface_polygons[s]]
        self.loops = {k: [lp for s in ents for lp in info.surface_polygons[s]]
                      for k, (_, _, ents) in enumerate(cells, start=1)}
        self.points = {}
        for k in range(1, len(cells) + 1):
            curves = self.curves(k)
            self.points[k] = np.vstack([info.curve_points[c] for c in curves]) if curves else np.zeros((0, 2))

    def curves(self, k: int) -> list[int]:
        return self.gamma2.get(k, []) + self.cut.get(k, [])

    def tolerance(self, k: int) -> float:
        """The gap below which cell ``k`` touches: TOUCH x its size."""
        pts = self.points[k]
        return TOUCH * (float(np.ptp(pts, axis=0).max()) if len(pts) else self.info.scale)


def _touching_boundaries(cg: CellGeometry, k: int, name: str, kind_of: dict, problems: list) -> None:
    """Cell ``k`` shares a corner with, or comes within the tolerance of, a named boundary curve."""
    info, tol, cut = cg.info, cg.tolerance(k), bool(cg.cut.get(k))
    corners = {p for c in cg.curves(k) for p in info.curve_ends[c]}
    for c, (kind, gname) in kind_of.items():
        if c in cg.cut.get(k, []) or (cut and kind == "symmetry"):
            continue
        shared = corners & set(info.curve_ends[c])
        gap = distance_to_polyline(cg.points[k], info.curve_points[c])
        if shared or gap <= tol:
            problems.append(f"cell '{name}' touches the boundary '{gname}' {where(info.curve_points[c])} "
                            f"(gap {gap:.3g}): a cell must lie inside the gel with a gap to its boundaries")


def _crossing_the_gel(cg: CellGeometry, k: int, name: str, problems: list) -> None:
    """Points just outside cell ``k``'s surface must lie in the gel (or next to another cell or a symmetry line)."""
    info, tol = cg.info, cg.tolerance(k)
    if not cg.gamma2.get(k):
        return
    ring = np.vstack([info.curve_points[c] for c in cg.gamma2[k]])
    out = ring - ring.mean(axis=0)
    out /= np.maximum(np.linalg.norm(out, axis=1), 1e-300)[:, None]
    probes = ring + 2 * tol * out
    sym_lines = [info.curve_points[c] for c in cg.cut.get(k, [])]

    def explained(q) -> bool:
        # probes in or next to another cell belong to the cell-cell checks
        near_other = any(is_inside(q, cg.loops[j]) or distance_to_polyline(q[None, :], cg.points[j]) <= 4 * tol
                         for j in cg.loops if j != k)
        near_line = any(distance_to_polyline(q[None, :], ln) <= 4 * tol for ln in sym_lines)
        return is_inside(q, cg.gel_loops) or near_other or near_line

    if not all(explained(q) for q in probes[::2]):
        problems.append(f"cell '{name}' overlaps a boundary of the gel (part of it lies outside the gel)")


def _nominal_circle(cg: CellGeometry, k: int, ents: list, problems: list) -> tuple[np.ndarray, float, tuple]:
    """Centre, diameter and the components fixed on the flat edges of cell ``k``."""
    info = cg.info
    area, centre = 0.0, np.zeros(2)
    for s in ents:
        a, cen = area_and_centroid(info.surface_polygons[s])
        centre = (centre * area + cen * a) / (area + a) if area + a else centre
        area += a
    sym = []
    for c in cg.cut.get(k, []):
        p = info.curve_points[c]
        horizontal, problem = symmetry_axis(c, p, info.scale)
        if problem:
            problems.append(problem)
            continue
        comp = 1 if horizontal else 0
        sym.append(comp)
        centre[comp] = p[0, comp]          # the whole (mirrored) cell is centred on the line
    pts = cg.points[k]
    radius = float(np.linalg.norm(pts - centre, axis=1).max()) if len(pts) else 0.0
    return centre, 2.0 * radius, tuple(sorted(set(sym)))


def _cell_overlaps(cg: CellGeometry, k: int, name: str, problems: list) -> None:
    """Cell ``k`` against every earlier cell: overlapping, or touching within the tolerance."""
    tol = cg.tolerance(k)
    for j in range(1, k):
        other = cg.cells[j - 1][0]
        deep = [p for p in cg.points[k][::2] if is_inside(p, cg.loops[j])
                and distance_to_polyline(p[None, :], cg.points[j]) > tol]
        deep += [p for p in cg.points[j][::2] if is_inside(p, cg.loops[k])
                 and distance_to_polyline(p[None, :], cg.points[k]) > tol]
        if deep:
            problems.append(f"cell '{name}' overlaps cell '{other}'")
        elif distance_to_polyline(cg.points[k], cg.points[j]) <= tol:
            problems.append(f"cell '{name}' touches cell '{other}'")


def cell_specs(cg: CellGeometry, kind_of: dict, problems: list) -> list[CellSpec]:
    """Check every cell of ``cg`` (problems appended) and return its :class:`CellSpec`."""
    specs = []
    n_cells = len(cg.cells)
    for k, (name, _, ents) in enumerate(cg.cells, start=1):
        _touching_boundaries(cg, k, name, kind_of, problems)
        _crossing_the_gel(cg, k, name, problems)
        centre, diameter, symmetry = _nominal_circle(cg, k, ents, problems)
        specs.append(CellSpec(index=k, name=name, region_tag=cell_region_tag(k), facet_tag=gamma2_tag(k),
                              interface=gamma2_name(k, n_cells), centre=(float(centre[0]), float(centre[1])),
                              diameter=diameter, symmetry=symmetry))
        _cell_overlaps(cg, k, name, problems)
    return specs
