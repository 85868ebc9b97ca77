"""The gmsh models of the built-in devices (shear, normal): OCC geometry, tags, size fields.

:func:`build_model` builds and meshes the model of a case in the current
gmsh session (rank 0); :func:`gelcell.geometry.meshes.build_meshes` turns it
into dolfinx meshes.  A module of its own so that gmsh is imported only when
a device is meshed, not on a mesh-cache hit.  What it produces is keyed in
the mesh cache by :data:`gelcell.geometry.meshcache.MESH_FORMAT`: a change
here that changes the mesh bumps it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from femtools.gmshimport import import_gmsh
from gelcell.case import CaseParameters
from gelcell.geometry.tags import FACET_TAGS, Tag, cell_region_tag, gamma2_tag, tag_name

gmsh = import_gmsh()

__all__ = ["build_model"]


def _bbox(dim: int, tag: int) -> np.ndarray:
    return np.array(gmsh.model.getBoundingBox(dim, tag))   # xmin, ymin, zmin, xmax, ymax, zmax


def _build_shear(params: CaseParameters):
    """OCC entities of the shear device; returns the fragment groups (fluid, gel, [cells])."""
    occ, g = gmsh.model.occ, params.geometry
    L, W = g.channel_length, g.channel_height
    xm, yb = g.bowl_centre
    R = g.radius
    chan = occ.addRectangle(0, 0, 0, L, W)
    disk = occ.addDisk(xm, yb, 0, R, R)
    box = occ.addRectangle(xm - 2 * R, -2 * R, 0, 4 * R, 2 * R)
    seg, _ = occ.intersect([(2, disk)], [(2, box)])
    tools = list(seg)
    cells = g.cell_list() if params.with_cell else []
    for xc, yc, d in cells:
        tools.append((2, occ.addDisk(xc, yc, 0, 0.5 * d, 0.5 * d)))
    _, out_map = occ.fragment([(2, chan)], tools)
    occ.synchronize()
    fluid = [t for _, t in out_map[0]]
    cell = [[t for _, t in out_map[2 + k]] for k in range(len(cells))]
    inside = {t for c in cell for t in c}
    gel = [t for _, t in out_map[1] if t not in inside]
    return fluid, gel, cell


def _build_normal(params: CaseParameters):
    occ, g = gmsh.model.occ, params.geometry
    H, Lg = g.height, g.gel_length
    up = occ.addRectangle(-g.upstream_length, 0, 0, g.upstream_length, H)
    down = occ.addRectangle(Lg, 0, 0, g.downstream_length, H)
    gel_rect = occ.addRectangle(0, 0, 0, Lg, H)
    rp = 0.5 * g.post_diameter
    posts = [(2, occ.addDisk(xp, 0, 0, rp, rp)) for xp in g.post_centres]
    gel, _ = occ.cut([(2, gel_rect)], posts)
    tools = []
    cells = g.cell_list() if params.with_cell else []
    for xc, yc, d in cells:
        r = 0.5 * d
        disk = occ.addDisk(xc, yc, 0, r, r)
        if g.on_symmetry_line(yc):          # cut by the symmetry line: its lower half
            clip = occ.addRectangle(xc - 2 * r, yc - 2 * r, 0, 4 * r, 2 * r)
            half, _ = occ.intersect([(2, disk)], [(2, clip)])
            tools += list(half)
        else:
            tools.append((2, disk))
    objects = [(2, up)] + list(gel) + [(2, down)]
    _, out_map = occ.fragment(objects, tools)
    occ.synchronize()
    n_obj = len(objects)
    cell = [[t for _, t in out_map[n_obj + k]] for k in range(len(cells))]
    inside = {t for c in cell for t in c}
    fluid = [t for _, t in out_map[0]] + [t for _, t in out_map[n_obj - 1]]
    gel = [t for m in out_map[1:n_obj - 1] for _, t in m if t not in inside]
    return fluid, gel, cell


def _classify_curves(params: CaseParameters, fluid, gel, cell) -> dict[int, list[int]]:
    """Tag every curve by the surfaces it bounds and, for outer boundaries, its position."""
    cell_of = {t: k + 1 for k, c in enumerate(cell) for t in c}
    regions = (set(fluid), set(gel), cell_of)
    scale = max(abs(v) for v in gmsh.model.getBoundingBox(-1, -1)) or 1.0
    tol = 1e-7 * scale
    groups: dict[int, list[int]] = {t: [] for t in FACET_TAGS}
    for _, c in gmsh.model.getEntities(1):
        up = set(gmsh.model.getAdjacencies(1, c)[0])
        x0, y0, _, x1, y1, _ = _bbox(1, c)
        box = _Box(x0, y0, x1, y1, tol)
        tag = _curve_tag(params, up, regions, box)
        if tag is None:
            raise RuntimeError(f"{params.case} geometry: cannot classify curve {c} "
                               f"(bbox {[x0, y0, x1, y1]}, surfaces {sorted(up)})")
        groups.setdefault(tag, []).append(c)
    return {t: v for t, v in groups.items() if v}


@dataclasses.dataclass(frozen=True)
class _Box:
    """A curve's bounding box, compared with positions to a tolerance."""

    x0: float
    y0: float
    x1: float
    y1: float
    tol: float

    def close(self, a: float, b: float) -> bool:
        return abs(a - b) <= self.tol

    @property
    def vertical(self) -> bool:
        return self.close(self.x0, self.x1)

    @property
    def horizontal(self) -> bool:
        return self.close(self.y0, self.y1)


def _curve_tag(params: CaseParameters, up: set, regions, box: _Box) -> int | None:
    """The facet tag of a curve bounding the surfaces ``up``; None if it fits none."""
    fl, ge, cell_of = regions
    ce = set(cell_of)
    if up & ce and up & ge:
        return gamma2_tag(cell_of[min(up & ce)])
    if up & fl and up & ge:
        return _interface_tag(params, box)
    if up & ce:
        top = params.case == "normal" and box.horizontal and box.close(box.y0, params.geometry.height)
        return Tag.SYMMETRY_TOP if top else None
    if up & ge:
        return _gel_boundary_tag(params, box)
    if up & fl:
        return _fluid_boundary_tag(params, box)
    return None


def _interface_tag(params: CaseParameters, box: _Box) -> int | None:
    """Gamma1 (the shear device's one interface, the normal device's upstream face) or Gamma3."""
    if params.case == "shear" or (box.vertical and box.close(box.x0, 0.0)):
        return Tag.GAMMA1
    if box.vertical and box.close(box.x0, params.geometry.gel_length):
        return Tag.GAMMA3
    return None


def _gel_boundary_tag(params: CaseParameters, box: _Box) -> int | None:
    """The gel's outer boundary: the shear device's bowl; the normal device's symmetry lines and post."""
    if params.case == "shear":
        return Tag.BOWL if not box.horizontal else None
    if box.horizontal and box.close(box.y0, 0.0):
        return Tag.SYMMETRY_BOTTOM
    if box.horizontal and box.close(box.y0, params.geometry.height):
        return Tag.SYMMETRY_TOP
    if box.close(box.y0, 0.0) and not box.horizontal:
        return Tag.POST
    return None


def _fluid_boundary_tag(params: CaseParameters, box: _Box) -> int | None:
    """The fluid's outer boundary: inlet, outlet, and the walls or symmetry lines."""
    g = params.geometry
    if params.case == "shear":
        x_in, x_out = 0.0, g.channel_length
    else:
        x_in, x_out = -g.upstream_length, g.gel_length + g.downstream_length
    if box.vertical and box.close(box.x0, x_in):
        return Tag.INLET
    if box.vertical and box.close(box.x0, x_out):
        return Tag.OUTLET
    if not box.horizontal:
        return None
    if params.case == "shear":
        return Tag.WALL if box.close(box.y0, 0.0) or box.close(box.y0, g.channel_height) else None
    if box.close(box.y0, 0.0):
        return Tag.SYMMETRY_BOTTOM
    if box.close(box.y0, g.height):
        return Tag.SYMMETRY_TOP
    return None


def _threshold(curves: list[int], size: float, band: float, far: float, growth: float,
               length: float) -> int:
    """Distance+Threshold field: ``size`` within ``band`` of ``curves``, growing to ``far``."""
    field = gmsh.model.mesh.field
    fd = field.add("Distance")
    field.setNumbers(fd, "CurvesList", curves)
    field.setNumber(fd, "NumPointsPerCurve", max(100, int(math.ceil(4 * length / size))))
    ft = field.add("Threshold")
    field.setNumber(ft, "InField", fd)
    field.setNumber(ft, "SizeMin", size)
    field.setNumber(ft, "SizeMax", max(far, size))
    field.setNumber(ft, "DistMin", band)
    field.setNumber(ft, "DistMax", band + max(far - size, 0.0) / growth + 1e-12)
    return ft


def _restrict(surfaces: list[int], size: float) -> int:
    """Constant ``size`` on ``surfaces`` and their boundary curves (huge elsewhere)."""
    field = gmsh.model.mesh.field
    fc = field.add("MathEval")
    field.setString(fc, "F", repr(float(size)))
    fr = field.add("Restrict")
    field.setNumber(fr, "InField", fc)
    field.setNumbers(fr, "SurfacesList", surfaces)
    curves = gmsh.model.getBoundary([(2, s) for s in surfaces], combined=False, oriented=False)
    field.setNumbers(fr, "CurvesList", sorted({abs(t) for _, t in curves}))
    return fr


def _curve_length(curves: list[int]) -> float:
    return sum(gmsh.model.occ.getMass(1, c) for c in curves)


def _mesh_fields(params: CaseParameters, fluid, gel, cell, groups) -> None:
    h = params.element_sizes()
    far = max(h["h_fluid"], h["h_gel"])
    fields = [_restrict(fluid, h["h_fluid"]), _restrict(gel, h["h_gel"])]
    if cell:
        fields.append(_restrict([t for c in cell for t in c], h["h_cell"]))
        c = [x for k in range(len(cell)) for x in groups[gamma2_tag(k + 1)]]
        fields.append(_threshold(c, h["h_cell"], h["cell_band"], far, h["growth"],
                                 _curve_length(c)))
    for tags in ((Tag.GAMMA1, Tag.GAMMA3), (Tag.BOWL, Tag.POST)):
        c = [x for t in tags for x in groups.get(t, [])]
        if c:
            fields.append(_threshold(c, h["h_layer"], h["layer_band"], far, h["growth"],
                                     max(gmsh.model.occ.getMass(1, x) for x in c)))
    background_size(fields, far)


def background_size(fields: list[int], far: float) -> None:
    """Mesh with the minimum of ``fields`` as the size, at most ``far``; nothing else sets sizes."""
    fmin = gmsh.model.mesh.field.add("Min")
    gmsh.model.mesh.field.setNumbers(fmin, "FieldsList", fields)
    gmsh.model.mesh.field.setAsBackgroundMesh(fmin)
    for opt in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints",
                "Mesh.MeshSizeFromCurvature"):
        gmsh.option.setNumber(opt, 0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", far)
    gmsh.option.setNumber("Mesh.Algorithm", 6)   # Frontal-Delaunay


def add_physical_groups(dim: int, fluid, gel, cell, groups: dict) -> None:
    """Name the regions (entities of ``dim``) and the boundary groups (``dim - 1``) by their tags."""
    regions = [(fluid, int(Tag.FLUID), "fluid"), (gel, int(Tag.GEL), "gel")]
    regions += [(c, cell_region_tag(k + 1), "cell" if len(cell) == 1 else f"cell_{k + 1}")
                for k, c in enumerate(cell)]
    for tags, tag, name in regions:
        if tags:
            gmsh.model.addPhysicalGroup(dim, tags, tag)
            gmsh.model.setPhysicalName(dim, tag, name)
    for tag, entities in groups.items():
        gmsh.model.addPhysicalGroup(dim - 1, entities, int(tag))
        gmsh.model.setPhysicalName(dim - 1, int(tag), tag_name(tag).lower())


def build_model(params: CaseParameters) -> dict:
    """Build and mesh the gmsh model of ``params`` (current gmsh session, rank 0)."""
    gmsh.model.add(f"gelcell_{params.case}")
    fluid, gel, cell = (_build_shear if params.case == "shear" else _build_normal)(params)
    groups = _classify_curves(params, fluid, gel, cell)
    add_physical_groups(2, fluid, gel, cell, groups)
    _mesh_fields(params, fluid, gel, cell, groups)
    gmsh.model.mesh.generate(2)
    gmsh.model.mesh.setOrder(2)
    return {"curves": {tag_name(t): c for t, c in groups.items()}}

