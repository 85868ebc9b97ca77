"""The two device geometries (gmsh OCC) and their dolfinx meshes.

:func:`build_device` builds the gmsh model of a case once (on rank 0,
:mod:`gelcell.gmshmodel`), meshes it with curved P2 triangles and turns it
into

* one dolfinx mesh per region (fluid, gel, cell) with that region's facet
  tags: its outer boundaries and the interfaces it shares (Γ1, Γ2, Γ3);
* the whole device as one mesh with cell and facet tags (for the monolithic
  reference).

All meshes come from the same gmsh mesh, so the nodes of an interface have
bit-identical coordinates in the two region meshes that share it.  Surfaces
are classified with the ``fragment`` output map; curves by the surfaces
they bound and, for outer boundaries, by their bounding box.  Every boundary
and interface curve carries exactly one :class:`Tag`.  The meshed model of a
built-in device is kept in a disk cache (:mod:`gelcell.meshcache`), so a
warm run neither imports gmsh nor meshes.

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

from dolfinx import io as _io

from femtools import petscgarbage
from femtools.gmshimport import gmsh_session
from femtools.mesh import ModelArrays, model_to_mesh, model_to_region_mesh
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
def _build_model(params: CaseParameters) -> dict:
    """Build and mesh the gmsh model of ``params`` (current gmsh session, rank 0; see :mod:`gelcell.gmshmodel`)."""
    from gelcell.gmshmodel import build_model   # imports gmsh: only when a device is meshed
    return build_model(params)


def _mesh_with_gmsh(params: CaseParameters) -> ModelArrays:
    """Mesh the device of ``params`` with gmsh (rank 0) and return the raw arrays of its mesh."""
    with gmsh_session() as gmsh:
        if params.case == "file":
            from gelcell.geometryfile import build_file_model
            build_file_model(params)
        else:
            _build_model(params)
        return ModelArrays.from_model(gmsh.model)


def _device_arrays(params: CaseParameters) -> ModelArrays:
    """Raw mesh arrays of the device of ``params`` (rank 0): from the mesh cache, else meshed and cached."""
    from gelcell import meshcache
    arrays = meshcache.load(params)
    if arrays is None:
        arrays = _mesh_with_gmsh(params)
        meshcache.store(params, arrays)
    return arrays


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
    petscgarbage.collect(comm)          # the PETSc objects of devices dropped since the last build
    arrays, error = None, None
    if comm.rank == 0:
        try:
            arrays = _device_arrays(params)
        except Exception as exc:       # reported on every rank below
            error = (type(exc).__name__, f"{exc}")
    error = comm.bcast(error, root=0)
    if error is not None:
        if error[0] == "ParameterError":
            from gelcell.parameters import ParameterError
            raise ParameterError(error[1])
        raise RuntimeError(f"meshing the {params.case} device failed: {error[0]}: {error[1]}")
    cell_tags = None
    region_meshes = {}
    for name in wanted:
        tags = layout.cell_region_tags if name == "cell" else [int(REGIONS[name])]
        if name == "cell":
            msh, cell_tags, ft = model_to_region_mesh(arrays, comm, 0, tags, gdim=2, with_cell_tags=True)
            region_meshes[name] = (msh, ft)
        else:
            region_meshes[name] = model_to_region_mesh(arrays, comm, 0, tags, gdim=2)
    whole_mesh = model_to_mesh(arrays, comm, 0, gdim=2) if whole else None
    return Device(params, region_meshes, whole_mesh, comm, time.perf_counter() - t0, layout, cell_tags)
