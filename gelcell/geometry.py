"""The two device geometries (gmsh OCC) and their dolfinx meshes.

:func:`build_device` builds the gmsh model of a case once (on rank 0),
meshes it with curved P2 triangles and turns it into

* one dolfinx mesh per region (fluid, gel, cell) with that region's facet
  tags: its outer boundaries and the interfaces it shares (Γ1, Γ2, Γ3);
* the whole device as one mesh with cell and facet tags (for the monolithic
  reference).

All meshes come from the same gmsh mesh, so the nodes of an interface have
bit-identical coordinates in the two region meshes that share it.  Surfaces
are classified with the ``fragment`` output map; curves by the surfaces
they bound and, for outer boundaries, by their bounding box.  Every boundary
and interface curve carries exactly one :class:`Tag`.

Geometry and refinement are described in ``docs/geometry.md``; every length
and element size is a field of :class:`gelcell.parameters.CaseParameters`.

Example::

    from gelcell.parameters import CaseParameters
    from gelcell.geometry import Tag, build_device
    dev = build_device(CaseParameters.default("normal"), comm=MPI.COMM_WORLD)
    gel_mesh, gel_facets = dev.region("gel")
    gamma1 = gel_facets.find(Tag.GAMMA1)
"""

from __future__ import annotations

import dataclasses
import enum
import math
import os
import time
import typing

import numpy as np

from mpi4py import MPI

import gmsh
from dolfinx import io as _io

from femtools.mesh import model_to_mesh, model_to_region_mesh
from gelcell.parameters import CaseParameters

__all__ = ["Tag", "REGIONS", "INTERFACES", "Device", "build_device", "closed_form_measures", "CellSpec",
           "cell_region_tag", "gamma2_tag", "gamma2_name", "fluid_interface_tag", "fluid_interface_name",
           "inlet_tag", "tag_name"]


class Tag(enum.IntEnum):
    """Cell tags (regions) and facet tags (boundaries, interfaces) used by every module."""

    FLUID = 1
    GEL = 2
    CELL = 3
    INLET = 11
    OUTLET = 12
    WALL = 13             #: channel no-slip walls (shear geometry)
    SYMMETRY_BOTTOM = 14  #: y = 0 (normal geometry)
    SYMMETRY_TOP = 15     #: y = height (normal geometry), incl. the cell's flat edge
    GAMMA1 = 21           #: fluid–gel interface (upstream one in the normal geometry)
    GAMMA2 = 22           #: gel–cell interface
    GAMMA3 = 23           #: downstream fluid–gel interface (normal geometry)
    BOWL = 31             #: wall of the shear chamber
    POST = 32             #: posts (holes in the gel, normal geometry)
    FLUID_SYMMETRY_X = 16  #: geometry files: symmetry line x = const of the fluid (V_x = 0)
    GEL_SYMMETRY_Y = 17    #: geometry files: symmetry line y = const of the gel
    GEL_SYMMETRY_X = 18    #: geometry files: symmetry line x = const of the gel
    CELL_SYMMETRY_X = 19   #: geometry files: symmetry line x = const of a cell


#: region name -> cell tag
REGIONS = {"fluid": Tag.FLUID, "gel": Tag.GEL, "cell": Tag.CELL}
#: interface name -> (facet tag, (region, region))
INTERFACES = {"Gamma1": (Tag.GAMMA1, ("fluid", "gel")),
              "Gamma2": (Tag.GAMMA2, ("gel", "cell")),
              "Gamma3": (Tag.GAMMA3, ("fluid", "gel"))}

_CELL_TAGS = (Tag.FLUID, Tag.GEL, Tag.CELL)
_FACET_TAGS = tuple(t for t in Tag if t not in _CELL_TAGS)


# --------------------------------------------------------------------------- numbering of several cells,
# interfaces and inlets: the first one keeps the tag of the single-cell devices (Tag.CELL, Tag.GAMMA2,
# Tag.GAMMA1, Tag.INLET), so a device with one of each is numbered exactly as before
def cell_region_tag(k: int) -> int:
    """Cell (surface) tag of cell ``k`` (1-based)."""
    return int(Tag.CELL) if k == 1 else 300 + k


def gamma2_tag(k: int) -> int:
    """Facet tag of the gel-cell interface of cell ``k`` (1-based)."""
    return int(Tag.GAMMA2) if k == 1 else 2200 + k


def gamma2_name(k: int, n: int) -> str:
    """Coupling name of cell ``k``'s interface among ``n`` cells: ``Gamma2`` alone, else ``Gamma2_k``."""
    return "Gamma2" if n == 1 else f"Gamma2_{k}"


def fluid_interface_name(k: int) -> str:
    """Coupling name of the ``k``-th fluid-gel interface: Gamma1, Gamma3, Gamma4, ..."""
    return "Gamma1" if k == 1 else f"Gamma{k + 1}"


def fluid_interface_tag(k: int) -> int:
    """Facet tag of the ``k``-th fluid-gel interface: 21, 23, then 2000 + k."""
    return {1: int(Tag.GAMMA1), 2: int(Tag.GAMMA3)}.get(k, 2000 + k)


def inlet_tag(k: int) -> int:
    """Facet tag of inlet ``k``: 11, then 1100 + k."""
    return int(Tag.INLET) if k == 1 else 1100 + k


def tag_name(value: int) -> str:
    """A printable name of a cell or facet tag value (the enum's, or a numbered one)."""
    value = int(value)
    try:
        return Tag(value).name
    except ValueError:
        pass
    for lo, name in ((2200, "GAMMA2_{}"), (2000, "GAMMA{}"), (1100, "INLET_{}"), (300, "CELL_{}")):
        if lo < value < lo + 100:
            k = value - lo
            return name.format(k + 1 if name == "GAMMA{}" else k)
    return str(value)


def tag_value(name: str) -> int:
    """The tag value of a :func:`tag_name` (inverse)."""
    if name in Tag.__members__:
        return int(Tag[name])
    for prefix, make in (("GAMMA2_", gamma2_tag), ("INLET_", inlet_tag), ("CELL_", cell_region_tag),
                         ("GAMMA", lambda k: fluid_interface_tag(k - 1))):
        if name.startswith(prefix) and name[len(prefix):].isdigit():
            return make(int(name[len(prefix):]))
    return int(name)


@dataclasses.dataclass(frozen=True)
class CellSpec:
    """One cell of a device: its tags, its coupling interface and its nominal shape.

    ``centre`` and ``diameter`` are those of the whole cell (a circle of the
    same area for a cell of another shape); ``symmetry`` lists the components
    fixed on its flat edges (a half cell on a symmetry line: its centroid
    moves along the line).
    """

    index: int                 #: 1-based
    name: str                  #: "cell" (single cell) or "cell_k"
    region_tag: int
    facet_tag: int             #: its Gamma2
    interface: str             #: coupling name of its Gamma2
    centre: tuple[float, float]
    diameter: float
    symmetry: tuple[int, ...] = ()


# --------------------------------------------------------------------------- closed forms
def closed_form_measures(params: CaseParameters) -> dict:
    """Exact areas and boundary lengths of the geometry of ``params``.

    Returns ``{"whole": {"area": {Tag: a}, "length": {Tag: l}}, "fluid": {"area": a,
    "length": {Tag: l}}, "gel": ..., "cell": ...}``; a region's lengths are those
    of the tagged facets of that region's own mesh.
    """
    g, cell = params.geometry, params.with_cell
    cells = g.cell_list() if cell else []
    # several cells: their areas and Gamma2 lengths are summed under Tag.CELL and Tag.GAMMA2
    if params.case == "shear":
        R, th, W, c = g.radius, g.half_angle, g.channel_height, g.chamber_width
        L = g.channel_length
        a_cell = sum(math.pi * (0.5 * d) ** 2 for _, _, d in cells)
        gamma2 = sum(math.pi * d for _, _, d in cells)
        fluid = {"area": L * W, "length": {Tag.INLET: W, Tag.OUTLET: W, Tag.WALL: 2 * L - c,
                                           Tag.GAMMA1: c}}
        gel = {"area": R * R * (th - math.sin(th) * math.cos(th)) - a_cell,
               "length": {Tag.GAMMA1: c, Tag.BOWL: 2 * R * th}}
        out = {"fluid": fluid, "gel": gel}
        if cell:
            gel["length"][Tag.GAMMA2] = gamma2
            out["cell"] = {"area": a_cell, "length": {Tag.GAMMA2: gamma2}}
    else:
        H, Lg, D = g.height, g.gel_length, g.post_diameter
        Lf = g.upstream_length + g.downstream_length
        half = [g.on_symmetry_line(y) for _, y, _ in cells]
        a_cell = sum((0.5 if h else 1.0) * math.pi * (0.5 * d) ** 2 for h, (_, _, d) in zip(half, cells))
        gamma2 = sum((0.5 if h else 1.0) * math.pi * d for h, (_, _, d) in zip(half, cells))
        cut = sum(d for h, (_, _, d) in zip(half, cells) if h)
        fluid = {"area": Lf * H, "length": {Tag.INLET: H, Tag.OUTLET: H, Tag.GAMMA1: H,
                                            Tag.GAMMA3: H, Tag.SYMMETRY_BOTTOM: Lf,
                                            Tag.SYMMETRY_TOP: Lf}}
        gel = {"area": Lg * H - math.pi * (0.5 * D) ** 2 - a_cell,
               "length": {Tag.GAMMA1: H, Tag.GAMMA3: H, Tag.POST: math.pi * D,
                          Tag.SYMMETRY_BOTTOM: Lg - 2 * D,
                          Tag.SYMMETRY_TOP: Lg - cut}}
        out = {"fluid": fluid, "gel": gel}
        if cell:
            gel["length"][Tag.GAMMA2] = gamma2
            out["cell"] = {"area": a_cell, "length": {Tag.GAMMA2: gamma2}}
            if cut:
                out["cell"]["length"][Tag.SYMMETRY_TOP] = cut
    whole_area = {REGIONS[k]: v["area"] for k, v in out.items()}
    whole_len: dict = {}
    for name, v in out.items():
        for tag, length in v["length"].items():
            shared = tag in (Tag.GAMMA1, Tag.GAMMA2, Tag.GAMMA3)
            if shared:
                whole_len[tag] = length
            else:
                whole_len[tag] = whole_len.get(tag, 0.0) + length
    out["whole"] = {"area": whole_area, "length": whole_len}
    return out


# --------------------------------------------------------------------------- gmsh model
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
    g = params.geometry
    fl, ge = set(fluid), set(gel)
    cell_of = {t: k + 1 for k, c in enumerate(cell) for t in c}
    ce = set(cell_of)
    scale = max(abs(v) for v in gmsh.model.getBoundingBox(-1, -1)) or 1.0
    tol = 1e-7 * scale
    groups: dict[int, list[int]] = {t: [] for t in _FACET_TAGS}

    def close(a, b):
        return abs(a - b) <= tol

    for _, c in gmsh.model.getEntities(1):
        up = set(gmsh.model.getAdjacencies(1, c)[0])
        x0, y0, _, x1, y1, _ = _bbox(1, c)
        vertical, horizontal = close(x0, x1), close(y0, y1)
        tag = None
        if up & ce and up & ge:
            tag = gamma2_tag(cell_of[min(up & ce)])
        elif up & fl and up & ge:
            if params.case == "shear":
                tag = Tag.GAMMA1
            elif vertical and close(x0, 0.0):
                tag = Tag.GAMMA1
            elif vertical and close(x0, g.gel_length):
                tag = Tag.GAMMA3
        elif up & ce:
            if params.case == "normal" and horizontal and close(y0, g.height):
                tag = Tag.SYMMETRY_TOP
        elif up & ge:
            if params.case == "shear":
                tag = Tag.BOWL if not horizontal else None
            elif horizontal and close(y0, 0.0):
                tag = Tag.SYMMETRY_BOTTOM
            elif horizontal and close(y0, g.height):
                tag = Tag.SYMMETRY_TOP
            elif close(y0, 0.0) and not horizontal:
                tag = Tag.POST
        elif up & fl:
            if params.case == "shear":
                x_in, x_out = 0.0, g.channel_length
            else:
                x_in, x_out = -g.upstream_length, g.gel_length + g.downstream_length
            if vertical and close(x0, x_in):
                tag = Tag.INLET
            elif vertical and close(x0, x_out):
                tag = Tag.OUTLET
            elif horizontal and params.case == "shear" and (
                    close(y0, 0.0) or close(y0, g.channel_height)):
                tag = Tag.WALL
            elif horizontal and params.case == "normal":
                if close(y0, 0.0):
                    tag = Tag.SYMMETRY_BOTTOM
                elif close(y0, g.height):
                    tag = Tag.SYMMETRY_TOP
        if tag is None:
            raise RuntimeError(f"{params.case} geometry: cannot classify curve {c} "
                               f"(bbox {[x0, y0, x1, y1]}, surfaces {sorted(up)})")
        groups.setdefault(tag, []).append(c)
    return {t: v for t, v in groups.items() if v}


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
    fmin = gmsh.model.mesh.field.add("Min")
    gmsh.model.mesh.field.setNumbers(fmin, "FieldsList", fields)
    gmsh.model.mesh.field.setAsBackgroundMesh(fmin)
    for opt in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints",
                "Mesh.MeshSizeFromCurvature"):
        gmsh.option.setNumber(opt, 0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", far)
    gmsh.option.setNumber("Mesh.Algorithm", 6)   # Frontal-Delaunay


def _build_model(params: CaseParameters) -> dict:
    """Build and mesh the gmsh model of ``params`` (current gmsh session, rank 0)."""
    gmsh.model.add(f"gelcell_{params.case}")
    fluid, gel, cell = (_build_shear if params.case == "shear" else _build_normal)(params)
    surfaces = [(fluid, int(Tag.FLUID), "fluid"), (gel, int(Tag.GEL), "gel")]
    surfaces += [(c, cell_region_tag(k + 1), "cell" if len(cell) == 1 else f"cell_{k + 1}")
                 for k, c in enumerate(cell)]
    for tags, tag, name in surfaces:
        if tags:
            gmsh.model.addPhysicalGroup(2, tags, tag)
            gmsh.model.setPhysicalName(2, tag, name)
    groups = _classify_curves(params, fluid, gel, cell)
    for tag, curves in groups.items():
        gmsh.model.addPhysicalGroup(1, curves, int(tag))
        gmsh.model.setPhysicalName(1, int(tag), tag_name(tag).lower())
    _mesh_fields(params, fluid, gel, cell, groups)
    gmsh.model.mesh.generate(2)
    gmsh.model.mesh.setOrder(2)
    return {"curves": {tag_name(t): c for t, c in groups.items()}}


# --------------------------------------------------------------------------- the device
def _owned_tag_counts(msh, tags, values) -> dict[str, int]:
    """Global number of entities per tag value, each entity counted once (owned)."""
    dim = tags.dim
    n_owned = msh.topology.index_map(dim).size_local
    mine = tags.indices < n_owned
    local = np.array([np.count_nonzero(tags.values[mine] == int(v)) for v in values], dtype=np.int64)
    total = msh.comm.allreduce(local, op=MPI.SUM)
    return {tag_name(v): int(n) for v, n in zip(values, total) if n > 0}


class Device:
    """Meshes of one device case.

    Attributes:
        params: the :class:`CaseParameters` it was built from.
        case: ``"shear"`` or ``"normal"``.
        with_cell: whether the cell (Γ2) is present.
        interfaces: names of the interfaces present, e.g. ``["Gamma1", "Gamma2"]``.
        whole: ``(mesh, cell_tags, facet_tags)`` of the whole device, or None.
        build_time: wall time of :func:`build_device` [s].
    """

    def __init__(self, params: CaseParameters, regions: dict, whole, comm: MPI.Comm,
                 build_time: float, layout=None, cell_tags=None):
        from gelcell.boundaries import device_layout
        self.params = params
        self.case = params.case
        self.with_cell = params.with_cell
        self.comm = comm
        self._regions = regions
        self.whole = whole
        self.build_time = build_time
        #: :class:`gelcell.boundaries.DeviceLayout`: conditions, cells, interfaces
        self.layout = layout if layout is not None else device_layout(params)
        #: cell tags of the cell region's mesh (one value per cell, ``CellSpec.region_tag``)
        self.cell_tags = cell_tags
        self.cells = self.layout.cells
        self._interfaces = {name: (tag, ("fluid", "gel")) for name, tag in self.layout.fluid_interfaces.items()}
        self._interfaces.update({c.interface: (c.facet_tag, ("gel", "cell")) for c in self.cells})
        self.interfaces = list(self._interfaces)

    @property
    def regions(self) -> list[str]:
        """Names of the region meshes built (``fluid``, ``gel`` and, with a cell, ``cell``)."""
        return list(self._regions)

    def region(self, name: str):
        """``(mesh, facet_tags)`` of region ``name``; KeyError if absent (e.g. no cell)."""
        if name not in self._regions:
            raise KeyError(f"region {name!r} not in this device (regions: {self.regions})")
        return self._regions[name]

    def interface(self, name: str) -> tuple[Tag, tuple[str, str]]:
        """Facet tag and the two regions sharing interface ``name`` (e.g. ``"Gamma1"``)."""
        if name not in self.interfaces:
            raise KeyError(f"interface {name!r} not in this device (interfaces: {self.interfaces})")
        return self._interfaces[name]

    def counts(self) -> dict:
        """Global counts: per region (and ``whole``) cells, geometry nodes, facets per tag."""
        out = {}
        facet_tags = sorted(set(int(t) for t in _FACET_TAGS) | set(self._facet_values()))
        cell_tags = [int(Tag.FLUID), int(Tag.GEL)] + ([c.region_tag for c in self.cells] or [int(Tag.CELL)])
        for name, (msh, ft) in self._regions.items():
            out[name] = {"cells": msh.topology.index_map(msh.topology.dim).size_global,
                         "nodes": msh.geometry.index_map().size_global,
                         "facets": _owned_tag_counts(msh, ft, facet_tags)}
        if self.whole is not None:
            msh, ct, ft = self.whole
            out["whole"] = {"cells": msh.topology.index_map(msh.topology.dim).size_global,
                            "nodes": msh.geometry.index_map().size_global,
                            "cells_per_tag": _owned_tag_counts(msh, ct, cell_tags),
                            "facets": _owned_tag_counts(msh, ft, facet_tags)}
        return out

    def _facet_values(self) -> list[int]:
        vals = set()
        for _, ft in self._regions.values():
            vals |= set(np.unique(ft.values).tolist())
        return sorted(self.comm.allreduce(vals, op=MPI.BOR) if self.comm.size > 1 else vals)

    def write_xdmf(self, directory: str) -> list[str]:
        """Write ``<region>.xdmf`` (mesh + facet tags) and ``whole.xdmf`` (mesh + cell and
        facet tags) into ``directory``; returns the paths.  Mesh name ``mesh``, tag names
        ``facet_tags`` / ``cell_tags``."""
        if self.comm.rank == 0:
            os.makedirs(directory, exist_ok=True)
        self.comm.Barrier()
        paths = []
        items = [(n, m, [ft]) for n, (m, ft) in self._regions.items()]
        if self.whole is not None:
            items.append(("whole", self.whole[0], [self.whole[1], self.whole[2]]))
        for name, msh, tags in items:
            path = os.path.join(directory, f"{name}.xdmf")
            msh.topology.create_connectivity(msh.topology.dim - 1, msh.topology.dim)
            with _io.XDMFFile(self.comm, path, "w") as xf:
                xf.write_mesh(msh)
                for t in tags:
                    xf.write_meshtags(t)
            paths.append(path)
        return paths

    def __repr__(self) -> str:
        return (f"Device(case={self.case!r}, with_cell={self.with_cell}, regions={self.regions}, "
                f"interfaces={self.interfaces})")


def build_device(params: CaseParameters, comm: MPI.Comm = MPI.COMM_WORLD, *,
                 regions: typing.Iterable[str] | None = None, whole: bool = True) -> Device:
    """Build the gmsh model of ``params`` once and all requested dolfinx meshes from it.

    Args:
        params: the case (validated again here, before any meshing).
        comm: communicator of the meshes; gmsh runs on its rank 0 only.
        regions: region meshes to build (default: fluid, gel and, with a cell, cell).
        whole: also build the whole device as one mesh.

    Returns:
        A :class:`Device`.
    """
    t0 = time.perf_counter()
    params.validate()
    from gelcell.boundaries import device_layout
    layout = device_layout(params)
    available = ["fluid", "gel"] + (["cell"] if layout.cells else [])
    wanted = available if regions is None else list(regions)
    for name in wanted:
        if name not in available:
            raise KeyError(f"region {name!r} not available (case {params.case!r}, "
                           f"with_cell={params.with_cell}: {available})")
    error = None
    if comm.rank == 0:
        gmsh.initialize(readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)
        try:
            if params.case == "file":
                from gelcell.geometryfile import build_file_model
                build_file_model(params)
            else:
                _build_model(params)
        except Exception as exc:       # reported on every rank below
            error = (type(exc).__name__, f"{exc}")
            gmsh.finalize()
    error = comm.bcast(error, root=0)
    if error is not None:
        if error[0] == "ParameterError":
            from gelcell.parameters import ParameterError
            raise ParameterError(error[1])
        raise RuntimeError(f"meshing the {params.case} device failed: {error[0]}: {error[1]}")
    cell_tags = None
    try:
        region_meshes = {}
        for name in wanted:
            tags = layout.cell_region_tags if name == "cell" else [int(REGIONS[name])]
            if name == "cell":
                msh, cell_tags, ft = model_to_region_mesh(gmsh.model, comm, 0, tags, gdim=2, with_cell_tags=True)
                region_meshes[name] = (msh, ft)
            else:
                region_meshes[name] = model_to_region_mesh(gmsh.model, comm, 0, tags, gdim=2)
        whole_mesh = model_to_mesh(gmsh.model, comm, 0, gdim=2) if whole else None
    finally:
        if comm.rank == 0:
            gmsh.finalize()
    return Device(params, region_meshes, whole_mesh, comm, time.perf_counter() - t0, layout, cell_tags)
