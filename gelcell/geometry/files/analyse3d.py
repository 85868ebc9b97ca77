"""A geometry file with volumes (a 3D device) checked against the naming convention, one dimension up.

The regions are volumes (``fluid``, ``gel``, ``cell``/``cell_K``) and the
conditions are on surfaces (``inlet``, ``outlet``, ``wall``, ``held``,
``symmetry``, ``interface``): the checks of
:mod:`~gelcell.geometry.files.steps` that carry over (every name known and
present, every boundary surface in a group, interfaces shared by the fluid
and the gel, the pressure fixed, the network anchored) run on the file's
surfaces and volumes as they do on curves and surfaces.  What differs:

* a symmetry surface must be planar and axis-aligned; the component fixed on
  it is the one along its normal;
* an inlet is one planar surface; its profile (:class:`FaceInflow`) is
  ``uniform`` on any planar inlet, ``parabolic`` on a rectangular inlet whose
  normal is a coordinate axis: fully developed flow between the inlet's
  edges, no slip on edges where it meets walls, symmetric about edges on a
  symmetry plane;
* cells are volumes inside the gel: checked by the surfaces they share and by
  sampled gaps to the named boundaries and the other cells
  (:func:`cell_specs_3d`).
"""

from __future__ import annotations

import numpy as np

from gelcell.geometry.files.steps import Analysis, FileLayout, boundary_tags
from gelcell.geometry.files.names import ParsedGroups
from gelcell.geometry.files.read import GeometryInfo
from gelcell.geometry.files.shapes import TOUCH, where
from gelcell.geometry.layout import CellSpec, DeviceBoundaries, DeviceLayout, duct_poiseuille
from gelcell.geometry.tags import Tag, cell_region_tag, gamma2_name, gamma2_tag, inlet_tag

__all__ = ["FaceInflow", "SYMMETRY_TAGS", "analyse_volumes", "cell_specs_3d"]

#: (region, the axis normal to a symmetry plane) -> its facet tag
SYMMETRY_TAGS = {("fluid", 0): Tag.FLUID_SYMMETRY_X, ("fluid", 1): Tag.SYMMETRY_BOTTOM,
                 ("fluid", 2): Tag.FLUID_SYMMETRY_Z, ("gel", 0): Tag.GEL_SYMMETRY_X,
                 ("gel", 1): Tag.GEL_SYMMETRY_Y, ("gel", 2): Tag.GEL_SYMMETRY_Z,
                 ("cell", 0): Tag.CELL_SYMMETRY_X, ("cell", 1): Tag.SYMMETRY_TOP, ("cell", 2): Tag.CELL_SYMMETRY_Z}
#: a planar surface's points lie within this fraction of the file's size of its plane
PLANAR = 1e-7


class FaceInflow:
    """Inflow through a planar inlet: ``speed`` times the inward unit ``normal`` times a profile s(x).

    ``uniform``: s = 1.  ``parabolic`` (a rectangle with edges along the axes ``sides``, each
    ``(axis, lo, hi, wall_lo, wall_hi)``): fully developed flow in the duct the inlet's edges
    bound, maximum ``speed``: no slip on a wall edge, an edge on a symmetry plane mirrored (the
    duct is twice as wide, the profile symmetric about that edge).  With two walled directions
    s is the rectangular-duct series (:func:`~gelcell.geometry.layout.duct_poiseuille`), with
    one 4 a (A - a) / A^2 across it, with none 1.
    """

    def __init__(self, normal, speed: float, profile: str, sides: tuple = ()):
        self.normal, self.speed, self.profile = np.asarray(normal, float), float(speed), profile
        self.sides = tuple(sides)

    def ducts(self) -> list[tuple[int, float, float]]:
        """``(axis, origin, width)`` of each walled direction of the duct (mirrored where symmetric)."""
        out = []
        for axis, lo, hi, wall_lo, wall_hi in self.sides:
            if wall_lo and wall_hi:
                out.append((axis, lo, hi - lo))
            elif wall_lo:
                out.append((axis, lo, 2 * (hi - lo)))
            elif wall_hi:
                out.append((axis, 2 * lo - hi, 2 * (hi - lo)))
        return out

    def shape(self, x: np.ndarray) -> np.ndarray:
        if self.profile == "uniform":
            return np.ones_like(x[0])
        ducts = self.ducts()
        a = [np.clip(x[axis] - origin, 0.0, width) for axis, origin, width in ducts]
        if len(ducts) == 2:
            return duct_poiseuille(a[0], a[1], ducts[0][2], ducts[1][2], 1.0)
        if len(ducts) == 1:
            return 4.0 * a[0] * (ducts[0][2] - a[0]) / ducts[0][2] ** 2
        return np.ones_like(x[0])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        s = self.speed * self.shape(x)
        return np.vstack([n * s for n in self.normal])


def plane_of(points: np.ndarray, scale: float):
    """``(unit normal, offset)`` of the plane through ``points`` if they lie in one, else None."""
    centre = points.mean(axis=0)
    _, sv, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[-1]
    if np.abs((points - centre) @ normal).max() > PLANAR * scale:
        return None
    return normal, float(centre @ normal)


def normal_axis(normal: np.ndarray) -> int | None:
    """The coordinate axis ``normal`` points along, or None for a plane at an angle."""
    k = int(np.argmax(np.abs(normal)))
    return k if abs(abs(normal[k]) - 1.0) <= 1e-9 else None


class _Analysis3D(Analysis):
    """The steps of :func:`analyse_volumes`: those of the planar analysis on surfaces and volumes, and
    the 3D forms of the symmetry planes, the inlets and the cells."""

    def symmetry_normal(self, c: int):
        plane = plane_of(self.info.curve_points[c], self.info.scale)
        return None if plane is None else normal_axis(plane[0])

    def symmetry_problem(self, c: int, name: str) -> str | None:
        if self.symmetry_normal(c) is not None:
            return None
        shape = "planar" if plane_of(self.info.curve_points[c], self.info.scale) is None else "axis-aligned"
        return (f"symmetry surface {c} {where(self.info.curve_points[c])} ('{name}') is not {shape}: gelcell "
                f"supports symmetry planes x, y or z = const only")

    def symmetry_tags(self) -> dict:
        """Facet tag -> surfaces of the fluid's and the gel's symmetry planes (by region and normal)."""
        tags: dict = {}
        for name, _, ents, _ in self.parsed.curves["symmetry"]:
            for c in ents:
                problem = self.symmetry_problem(c, name)
                if problem:
                    self.problems.append(problem)
                    continue
                side = [self.region[s] for s in self.info.adjacent[c] if s in self.region]
                if side:          # (a cell's flat face: cell_symmetry_tags)
                    tags.setdefault(int(SYMMETRY_TAGS[(side[0], self.symmetry_normal(c))]), []).append(c)
        return tags

    def cell_symmetry_tags(self, curve_tags: dict) -> dict:
        """The cells' flat faces into ``curve_tags``; returns facet tag -> the component fixed there."""
        fixed = {}
        for faces in self.cut.values():
            for c in faces:
                axis = self.symmetry_normal(c)
                tag = int(SYMMETRY_TAGS[("cell", axis)])
                curve_tags.setdefault(tag, []).append(c)
                fixed[tag] = axis
        return fixed

    # -- inlets --------------------------------------------------------------------------------------
    def _inward(self, s: int, normal: np.ndarray, offset: float) -> np.ndarray:
        """``normal`` or its opposite: towards the fluid, judged by the fluid's boundary samples near ``s``."""
        pts = self.info.curve_points[s]
        centre, size = pts.mean(axis=0), float(np.ptp(pts, axis=0).max())
        fluid = [f for v in self.info.adjacent[s] if v in self.fluid for f in self.info.solid["facets_of"][v]]
        near = np.vstack([self.info.curve_points[f] for f in fluid if f != s])
        near = near[np.linalg.norm(near - centre, axis=1) <= 2 * size]
        side = near @ normal - offset
        side = side[np.abs(side) > 1e-6 * size]
        return normal if side.size == 0 or np.median(side) > 0 else -normal

    def _sides(self, s: int, axis: int, name: str):
        """The rectangle ``(axis, lo, hi, wall_lo, wall_hi)`` of the two in-plane axes of a parabolic
        inlet, or a problem: its boundary must be the rectangle of its bounding box."""
        info, sides = self.info, []
        curves = info.curve_ends[s]
        pts = np.vstack([info.solid["edge_points"][c] for c in curves])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        tol = 1e-7 * max(info.scale, 1.0)
        for j in (k for k in range(3) if k != axis):
            ends = []
            for value in (lo[j], hi[j]):
                edge = [c for c in curves if np.all(np.abs(info.solid["edge_points"][c][:, j] - value) <= tol)]
                others = {f for c in edge for f in info.solid["edge_facets"][c] if f != s}
                ends.append(any(self.kind_of.get(f, ("wall",))[0] != "symmetry" for f in others))
            sides.append((j, float(lo[j]), float(hi[j]), ends[0], ends[1]))
        in_plane = [q for q in range(3) if q != axis]
        for c in curves:
            p = info.solid["edge_points"][c]
            on = np.zeros(len(p), dtype=bool)
            for q in in_plane:
                on |= (np.abs(p[:, q] - lo[q]) <= tol) | (np.abs(p[:, q] - hi[q]) <= tol)
            if not on.all():
                return None, (f"inlet '{name}': a parabolic inlet must be a rectangle with edges along the axes "
                              f"(its boundary is not that of its bounding box); use 'uniform' on other shapes")
        return tuple(sides), None

    def inlets(self) -> list:
        """``(tag, FaceInflow, group name, options)`` of every inlet: one planar surface each."""
        info, inflow = self.info, []
        for j, (name, _, ents, opts) in enumerate(self.parsed.curves["inlet"], start=1):
            plane = plane_of(info.curve_points[ents[0]], info.scale) if len(ents) == 1 else None
            if plane is None:
                self.problems.append(f"inlet '{name}': an inlet must be one planar surface (it has {len(ents)} "
                                     f"surface(s){'' if len(ents) != 1 else ', not planar'})")
                continue
            normal = self._inward(ents[0], *plane)
            sides = ()
            if opts["profile"] == "parabolic":
                axis = normal_axis(normal)
                if axis is None:
                    self.problems.append(f"inlet '{name}': a parabolic inlet must be normal to x, y or z; use "
                                         f"'uniform' on an inlet at an angle")
                    continue
                normal = np.round(normal)
                sides, problem = self._sides(ents[0], axis, name)
                if problem:
                    self.problems.append(problem)
                    continue
            inflow.append((inlet_tag(j), FaceInflow(normal, opts["speed"], opts["profile"], sides), name, opts))
        return inflow


# --------------------------------------------------------------------------- cells
def _cell_centre(a: _Analysis3D, k: int, ents: list, problems: list) -> tuple[np.ndarray, float, tuple]:
    """Centre, diameter and the components fixed on the flat faces of cell ``k``.

    The centroid of its volumes, moved onto a symmetry plane that cuts it (the mirrored cell's
    centre); a cell between two parallel symmetry planes (a cylinder through a slab) keeps its
    centroid there and its diameter is measured across that axis."""
    info = a.info
    sizes = [info.solid["sizes"][(3, v)] for v in ents]
    volume = sum(m for m, _ in sizes)
    centre = sum(m * np.asarray(c) for m, c in sizes) / volume
    planes: dict = {}
    for c in a.cut.get(k, []):
        axis = a.symmetry_normal(c)
        if axis is None:
            problems.append(a.symmetry_problem(c, "symmetry"))
            continue
        planes.setdefault(axis, set()).add(round(float(np.mean(info.curve_points[c][:, axis])), 12))
    for axis, values in planes.items():
        if len(values) == 1:
            centre[axis] = next(iter(values))
    across = [j for j in range(3) if len(planes.get(j, ())) < 2]
    pts = np.vstack([info.curve_points[c] for c in a.gamma2.get(k, []) + a.cut.get(k, [])])
    radius = float(np.linalg.norm((pts - centre)[:, across], axis=1).max())
    return centre, 2.0 * radius, tuple(sorted(planes))


def _cell_gaps(a: _Analysis3D, k: int, name: str, ents: list, problems: list) -> None:
    """Cell ``k`` shares no curve with a named boundary or another cell, and keeps a gap to them."""
    info = a.info
    own = set(a.gamma2.get(k, []) + a.cut.get(k, []))
    pts = np.vstack([info.curve_points[c] for c in own])
    tol = TOUCH * float(np.ptp(pts, axis=0).max())
    edges = {e for c in own for e in info.curve_ends[c]}
    cut = bool(a.cut.get(k))
    gaps = {}
    for v in ents:
        for s, d in info.solid["gaps"].get(v, {}).items():
            gaps[s] = min(d, gaps.get(s, np.inf))
    for s, (kind, gname) in sorted(a.kind_of.items()):
        if s in own or (cut and kind == "symmetry"):
            continue
        shared = edges & set(info.curve_ends[s])
        if shared or gaps.get(s, np.inf) <= tol:
            problems.append(f"cell '{name}' touches the boundary '{gname}' {where(info.curve_points[s])} (gap "
                            f"{0.0 if shared else gaps[s]:.3g}): a cell must lie inside the gel with a gap to its "
                            f"boundaries")
    for j, (other, _, _) in enumerate(a.parsed.cells[: k - 1], start=1):
        theirs = set(a.gamma2.get(j, []) + a.cut.get(j, []))
        if edges & {e for c in theirs for e in info.curve_ends[c]} or min(
                (gaps.get(s, np.inf) for s in theirs), default=np.inf) <= tol:
            problems.append(f"cell '{name}' touches cell '{other}'")


def cell_specs_3d(a: _Analysis3D) -> list[CellSpec]:
    """Check every cell of the file (problems into ``a.problems``) and return its :class:`CellSpec`."""
    specs, n = [], len(a.parsed.cells)
    for k, (name, _, ents) in enumerate(a.parsed.cells, start=1):
        if not a.gamma2.get(k):
            a.problems.append(f"cell '{name}' has no surface in the gel (no gel-cell interface): a cell must lie "
                              f"inside the gel, its volume sharing its surfaces with the gel's (BooleanFragments)")
            continue
        _cell_gaps(a, k, name, ents, a.problems)
        centre, diameter, symmetry = _cell_centre(a, k, ents, a.problems)
        specs.append(CellSpec(index=k, name=name, region_tag=cell_region_tag(k), facet_tag=gamma2_tag(k),
                              interface=gamma2_name(k, n), centre=tuple(float(c) for c in centre),
                              diameter=diameter, symmetry=symmetry))
    return specs


# --------------------------------------------------------------------------- the layout
def _boundaries_3d(inflow: list, present: set, cell_fixed: dict, fluid_interfaces: dict,
                   cells: list) -> DeviceBoundaries:
    """The 3D device's conditions by tag (only those of tags the file has)."""
    wall = [([int(Tag.WALL)], (0.0, 0.0, 0.0))] if int(Tag.WALL) in present else []
    symmetry = {region: [([int(t)], axis) for (r, axis), t in SYMMETRY_TAGS.items() if r == region
                         and int(t) in present] for region in ("fluid", "gel")}
    return DeviceBoundaries(
        fluid_velocity=[([tag], g) for tag, g, _, _ in inflow] + wall,
        fluid_component=[(tags, axis, 0.0) for tags, axis in symmetry["fluid"]],
        gel_no_slip=[int(Tag.BOWL)],
        gel_symmetry=symmetry["gel"],
        cell_symmetry=[([t], c) for t, c in sorted(cell_fixed.items())],
        fluid_interfaces=fluid_interfaces,
        cell_interfaces={c.interface: c.facet_tag for c in cells}, dim=3)


def _gel_depth_3d(a: _Analysis3D) -> float:
    """The gel's volume over the fluid-gel interfaces' area."""
    sizes = a.info.solid["sizes"]
    return sum(sizes[(3, v)][0] for v in a.gel) / sum(sizes[(2, s)][0] for s in a.curves_of("interface"))


def analyse_volumes(info: GeometryInfo, parsed: ParsedGroups, source: str, problems: list) -> FileLayout:
    """The checked layout of a file with volumes (the steps of the planar analysis, one dimension up)."""
    a = _Analysis3D(info, parsed, source)
    a.problems += problems
    a.stop_if_wrong()
    a.unnamed_surfaces()
    a.classify_curves()
    a.stop_if_wrong()
    cells = cell_specs_3d(a)
    enclosed = a.pressure_fixed()
    a.network_anchored()
    a.cell_boundary_groups()
    inflow = a.inlets()
    sym_tags = a.symmetry_tags()
    a.stop_if_wrong()
    curve_tags, fluid_interfaces = boundary_tags(a, inflow, sym_tags)
    cell_fixed = a.cell_symmetry_tags(curve_tags)
    surface_tags = {int(Tag.FLUID): (sorted(a.fluid), "fluid"), int(Tag.GEL): (sorted(a.gel), "gel")}
    for k, (name, _, ents) in enumerate(parsed.cells, start=1):
        surface_tags[cell_region_tag(k)] = (list(ents), name)
    xs = np.vstack([p for p in info.curve_points.values() if len(p)])
    layout = DeviceLayout(boundaries=_boundaries_3d(inflow, set(curve_tags), cell_fixed, fluid_interfaces, cells),
                          cells=cells, fluid_interfaces=fluid_interfaces,
                          wide=np.ptp(xs[:, 0]) > 2.5 * np.ptp(xs[:, 1]),
                          tag_names={tag: ("inlet " + name) for tag, _, name, _ in inflow})
    return FileLayout(curve_tags=curve_tags, surface_tags=surface_tags, layout=layout,
                      gel_depth=_gel_depth_3d(a), enclosed_fluid=enclosed, dimension=3)

