"""A geometry file checked against the naming convention and turned into gelcell's tags and conditions.

:func:`analyse` reads a file (:mod:`~gelcell.geometry.files.read`), sorts
its groups by name (:mod:`~gelcell.geometry.files.names`) and checks, step
by step, that every curve carries the condition its surfaces need, that the
cells lie inside the gel (:mod:`~gelcell.geometry.files.cells`), that the
pressure is fixed and the network anchored, and that inlets are straight.
Every problem of a step is reported at once, in one
:class:`~gelcell.errors.ParameterError` naming the group or entity.  The
result, a :class:`FileLayout`, is cached per file version.  The steps
that hold in 2D and 3D are :mod:`~gelcell.geometry.files.steps`; a file
with volumes is analysed by :mod:`~gelcell.geometry.files.analyse3d`.
"""

from __future__ import annotations

import numpy as np

from gelcell.geometry.files.analyse3d import analyse_volumes
from gelcell.geometry.files.cells import CellGeometry, cell_specs
from gelcell.geometry.files.names import parse_groups
from gelcell.geometry.files.read import GeometryInfo, file_version, read_geometry
from gelcell.geometry.files.shapes import area_and_centroid
from gelcell.geometry.files.steps import Analysis, FileLayout, check_mesh_kind, boundary_tags
from gelcell.geometry.layout import DeviceBoundaries, DeviceLayout
from gelcell.geometry.tags import Tag, cell_region_tag

__all__ = ["FileLayout", "analyse"]


def _boundaries(inflow: list, present: set, cell_fixed: dict, fluid_interfaces: dict, cells: list) -> DeviceBoundaries:
    """The device's conditions by tag (only those of tags the file has)."""
    wall = [([int(Tag.WALL)], (0.0, 0.0))] if int(Tag.WALL) in present else []
    return DeviceBoundaries(
        fluid_velocity=[([tag], g) for tag, g, _, _ in inflow] + wall,
        fluid_component=[([t], c, 0.0) for t, c in ((int(Tag.SYMMETRY_BOTTOM), 1), (int(Tag.FLUID_SYMMETRY_X), 0))
                         if t in present],
        gel_no_slip=[int(Tag.BOWL)],
        gel_symmetry=[([t], c) for t, c in ((int(Tag.GEL_SYMMETRY_Y), 1), (int(Tag.GEL_SYMMETRY_X), 0))
                      if t in present],
        cell_symmetry=[([t], c) for t, c in sorted(cell_fixed.items())],
        fluid_interfaces=fluid_interfaces,
        cell_interfaces={c.interface: c.facet_tag for c in cells})


def _gel_depth(a: Analysis) -> float:
    """The gel's area over the fluid-gel interfaces' length."""
    area = sum(area_and_centroid(a.info.surface_polygons[s])[0] for s in a.gel)
    length = sum(float(np.linalg.norm(np.diff(a.info.curve_points[c], axis=0), axis=1).sum())
                 for c in a.curves_of("interface"))
    return area / length


def _analyse(info: GeometryInfo) -> FileLayout:
    source = f"geometry file {info.path!r}"
    check_mesh_kind(info, source)
    problems: list[str] = []
    parsed = parse_groups(info, problems)
    if info.dimension == 3:
        return analyse_volumes(info, parsed, source, problems)
    a = Analysis(info, parsed, source)
    a.problems += problems
    a.stop_if_wrong()
    a.unnamed_surfaces()
    a.classify_curves()
    a.stop_if_wrong()
    cells = cell_specs(CellGeometry(info, parsed.cells, a.gamma2, a.cut, a.gel), a.kind_of, a.problems)
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
    layout = DeviceLayout(boundaries=_boundaries(inflow, set(curve_tags), cell_fixed, fluid_interfaces, cells),
                          cells=cells, fluid_interfaces=fluid_interfaces,
                          wide=np.ptp(xs[:, 0]) > 2.5 * np.ptp(xs[:, 1]),
                          tag_names={tag: ("inlet " + name) for tag, _, name, _ in inflow})
    return FileLayout(curve_tags=curve_tags, surface_tags=surface_tags, layout=layout,
                      gel_depth=_gel_depth(a), enclosed_fluid=enclosed)


_ANALYSED: dict = {}


def analyse(path: str) -> FileLayout:
    """The checked layout of a geometry file (cached per file version); raises ParameterError."""
    info = read_geometry(path)
    key = file_version(path)
    if key not in _ANALYSED:
        _ANALYSED[key] = _analyse(info)
    return _ANALYSED[key]
