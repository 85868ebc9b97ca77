"""The gmsh models of the built-in 3D devices (model.md section 10): OCC solids, tags, size fields.

The planar device of section 4 extruded in z over the half height
[0, H/2] (H = ``chip_height``): the floor z = 0 (:data:`Tag.FLOOR`) and the
mid-height symmetry plane z = H/2 (:data:`Tag.SYMMETRY_MID`); the shear
device's bowl is the arc extruded, the normal device's posts are cylinders,
the cells are spheres centred at mid-height (half spheres, quarter spheres
on the normal device's symmetry plane y = height).  Every other surface takes
the tag of the planar curve it is the extrusion of
(:func:`gelcell.geometry.builtin_model._curve_tag`).  Sizes: the planar ones,
``h_layer`` within the Brinkman length of the gel's bonded floor (no-slip
walls), ``h_cell`` on and around the cells.  Called by
:mod:`gelcell.geometry.meshes` for a geometry with a ``chip_height``.
"""

from __future__ import annotations

import math

import numpy as np

from femtools.gmshimport import import_gmsh
from gelcell.case import CaseParameters
from gelcell.geometry.builtin_model import _Box, _curve_tag, add_physical_groups, background_size
from gelcell.geometry.tags import FACET_TAGS, Tag, gamma2_tag, tag_name

gmsh = import_gmsh()

__all__ = ["build_model_3d"]


def _cell_solid(x: float, y: float, z: float, d: float, y_cut: float | None) -> list:
    """The part of the sphere (centre (x, y, z), diameter d) below z (and below ``y_cut`` if given)."""
    occ, r = gmsh.model.occ, 0.5 * d
    ball = occ.addSphere(x, y, z, r)
    dy = 2 * r if y_cut is not None else 4 * r
    clip = occ.addBox(x - 2 * r, y - 2 * r, z - 2 * r, 4 * r, dy, 2 * r)
    part, _ = occ.intersect([(3, ball)], [(3, clip)])
    return list(part)


def _cells(params: CaseParameters) -> list:
    return params.geometry.cell_list_3d() if params.with_cell else []


def _build_shear(params: CaseParameters):
    """OCC solids of the 3D shear device; returns the fragment groups (fluid, gel, [cells])."""
    occ, g = gmsh.model.occ, params.geometry
    L, W, top = g.channel_length, g.channel_height, 0.5 * g.chip_height
    xm, yb = g.bowl_centre
    R = g.radius
    chan = occ.addBox(0, 0, 0, L, W, top)
    drum = occ.addCylinder(xm, yb, 0, 0, 0, top, R)
    box = occ.addBox(xm - 2 * R, -2 * R, 0, 4 * R, 2 * R, top)
    seg, _ = occ.intersect([(3, drum)], [(3, box)])
    tools = list(seg)
    cells = _cells(params)
    for x, y, z, d in cells:
        tools += _cell_solid(x, y, z, d, None)
    _, out_map = occ.fragment([(3, chan)], tools)
    occ.synchronize()
    fluid = [t for _, t in out_map[0]]
    cell = [[t for _, t in out_map[2 + k]] for k in range(len(cells))]
    inside = {t for c in cell for t in c}
    gel = [t for _, t in out_map[1] if t not in inside]
    return fluid, gel, cell


def _build_normal(params: CaseParameters):
    """OCC solids of the 3D normal device (lower half of one unit, half height)."""
    occ, g = gmsh.model.occ, params.geometry
    Hy, Lg, top = g.height, g.gel_length, 0.5 * g.chip_height
    up = occ.addBox(-g.upstream_length, 0, 0, g.upstream_length, Hy, top)
    down = occ.addBox(Lg, 0, 0, g.downstream_length, Hy, top)
    gel_box = occ.addBox(0, 0, 0, Lg, Hy, top)
    rp = 0.5 * g.post_diameter
    posts = [(3, occ.addCylinder(xp, 0, 0, 0, 0, top, rp)) for xp in g.post_centres]
    gel, _ = occ.cut([(3, gel_box)], posts)
    cells = _cells(params)
    tools, n_parts = [], []
    for x, y, z, d in cells:
        part = _cell_solid(x, y, z, d, Hy if g.on_symmetry_line(y) else None)
        tools += part
        n_parts.append(len(part))
    objects = [(3, up)] + list(gel) + [(3, down)]
    _, out_map = occ.fragment(objects, tools)
    occ.synchronize()
    n_obj = len(objects)
    starts = np.cumsum([0] + n_parts)
    cell = [[t for m in out_map[n_obj + starts[k]:n_obj + starts[k + 1]] for _, t in m] for k in range(len(cells))]
    inside = {t for c in cell for t in c}
    fluid = [t for _, t in out_map[0]] + [t for _, t in out_map[n_obj - 1]]
    gel = [t for m in out_map[1:n_obj - 1] for _, t in m if t not in inside]
    return fluid, gel, cell


def _surface_tag(params: CaseParameters, up: set, regions, bbox, tol: float) -> int | None:
    """Floor, mid-height plane, else the tag of the planar curve the surface is the extrusion of."""
    x0, y0, z0, x1, y1, z1 = bbox
    top = 0.5 * params.geometry.chip_height
    flat = abs(z1 - z0) <= tol
    if flat and abs(z0) <= tol:
        return Tag.FLOOR
    if flat and abs(z0 - top) <= tol:
        return Tag.SYMMETRY_MID
    return _curve_tag(params, up, regions, _Box(x0, y0, x1, y1, tol))


def _classify_surfaces(params: CaseParameters, fluid, gel, cell) -> dict[int, list[int]]:
    """Tag every surface by the volumes it bounds and its position."""
    cell_of = {t: k + 1 for k, c in enumerate(cell) for t in c}
    regions = (set(fluid), set(gel), cell_of)
    scale = max(abs(v) for v in gmsh.model.getBoundingBox(-1, -1)) or 1.0
    tol = 1e-6 * scale          # OCC pads bounding boxes by its tolerance
    groups: dict[int, list[int]] = {t: [] for t in FACET_TAGS}
    for _, s in gmsh.model.getEntities(2):
        up = set(gmsh.model.getAdjacencies(2, s)[0])
        bbox = gmsh.model.getBoundingBox(2, s)
        tag = _surface_tag(params, up, regions, bbox, tol)
        if tag is None:
            raise RuntimeError(f"{params.case} 3D geometry: cannot classify surface {s} "
                               f"(bbox {list(bbox)}, volumes {sorted(up)})")
        groups.setdefault(tag, []).append(s)
    return {t: v for t, v in groups.items() if v}


def _restrict(volumes: list[int], field_in: int) -> int:
    """Field ``field_in`` on ``volumes`` and their boundary (huge elsewhere)."""
    field = gmsh.model.mesh.field
    fr = field.add("Restrict")
    field.setNumber(fr, "InField", field_in)
    field.setNumbers(fr, "VolumesList", volumes)
    faces = gmsh.model.getBoundary([(3, v) for v in volumes], combined=False, oriented=False)
    field.setNumbers(fr, "SurfacesList", sorted({abs(t) for _, t in faces}))
    curves = gmsh.model.getBoundary(faces, combined=False, oriented=False)
    field.setNumbers(fr, "CurvesList", sorted({abs(t) for _, t in curves}))
    return fr


def _constant(volumes: list[int], size: float) -> int:
    fc = gmsh.model.mesh.field.add("MathEval")
    gmsh.model.mesh.field.setString(fc, "F", repr(float(size)))
    return _restrict(volumes, fc)


def _grading(field_in: int, size: float, band: float, far: float, growth: float) -> int:
    """Threshold of a distance field: ``size`` within ``band``, growing by ``growth`` up to ``far``."""
    field = gmsh.model.mesh.field
    ft = field.add("Threshold")
    field.setNumber(ft, "InField", field_in)
    field.setNumber(ft, "SizeMin", size)
    field.setNumber(ft, "SizeMax", max(far, size))
    field.setNumber(ft, "DistMin", band)
    field.setNumber(ft, "DistMax", band + max(far - size, 0.0) / growth + 1e-12)
    return ft


def _surface_threshold(surfaces: list[int], size: float, band: float, far: float, growth: float) -> int:
    """``size`` within ``band`` of ``surfaces`` (sampled about 4 points per ``size``), growing to ``far``."""
    field = gmsh.model.mesh.field
    extent = max(max(b[3] - b[0], b[4] - b[1], b[5] - b[2])
                 for b in (gmsh.model.getBoundingBox(2, s) for s in surfaces))
    fd = field.add("Distance")
    field.setNumbers(fd, "SurfacesList", surfaces)
    field.setNumber(fd, "NumPointsPerCurve", max(20, int(math.ceil(4 * extent / size))))
    return _grading(fd, size, band, far, growth)


def _floor_layer(gel: list[int], size: float, band: float, far: float, growth: float) -> int:
    """``size`` within ``band`` of the floor z = 0 in the gel (its Brinkman layer at a bonded floor)."""
    fz = gmsh.model.mesh.field.add("MathEval")
    gmsh.model.mesh.field.setString(fz, "F", "z")            # the distance to the floor
    return _restrict(gel, _grading(fz, size, band, far, growth))


def _mesh_fields(params: CaseParameters, fluid, gel, cell, groups) -> None:
    h = params.element_sizes()
    far = max(h["h_fluid"], h["h_gel"])
    fields = [_constant(fluid, h["h_fluid"]), _constant(gel, h["h_gel"])]
    if cell:
        fields.append(_constant([t for c in cell for t in c], h["h_cell"]))
        s = [x for k in range(len(cell)) for x in groups[gamma2_tag(k + 1)]]
        fields.append(_surface_threshold(s, h["h_cell"], h["cell_band"], far, h["growth"]))
    for tags in ((Tag.GAMMA1, Tag.GAMMA3), (Tag.BOWL, Tag.POST)):
        s = [x for t in tags for x in groups.get(t, [])]
        if s:
            fields.append(_surface_threshold(s, h["h_layer"], h["layer_band"], far, h["growth"]))
    if params.geometry.walls == "noslip":
        fields.append(_floor_layer(gel, h["h_layer"], h["layer_band"], far, h["growth"]))
    background_size(fields, far)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)   # Delaunay volumes (serial, reproducible)


def build_model_3d(params: CaseParameters) -> dict:
    """Build and mesh the 3D gmsh model of ``params`` (current gmsh session, rank 0)."""
    gmsh.model.add(f"gelcell_{params.case}_3d")
    fluid, gel, cell = (_build_shear if params.case == "shear" else _build_normal)(params)
    groups = _classify_surfaces(params, fluid, gel, cell)
    add_physical_groups(3, fluid, gel, cell, groups)
    _mesh_fields(params, fluid, gel, cell, groups)
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.setOrder(2)
    return {"surfaces": {tag_name(t): s for t, s in groups.items()}}
