"""The dolfinx meshes of a device: one per region and the whole device, from one gmsh mesh.

:func:`build_meshes` builds the gmsh model of a case once (on rank 0: a
built-in device by :mod:`gelcell.geometry.builtin_model`, a geometry file
by :mod:`gelcell.geometry.files.build`), meshes it with curved P2 triangles
and turns it into

* one dolfinx mesh per region (fluid, gel, cell) with that region's facet
  tags: its outer boundaries and the interfaces it shares (Γ1, Γ2, Γ3);
* the whole device as one mesh with cell and facet tags (for the monolithic
  reference).

All meshes come from the same gmsh mesh, so the nodes of an interface have
bit-identical coordinates in the two region meshes that share it.  The
meshed model of a built-in device is kept in a disk cache
(:mod:`gelcell.geometry.meshcache`), so a warm run neither imports gmsh
nor meshes.  Geometry and refinement: ``docs/geometry.md``.

Example::

    from gelcell.case import CaseParameters
    from gelcell.geometry import Tag
    from gelcell.geometry.meshes import build_meshes
    meshes = build_meshes(CaseParameters.default("normal"), comm=MPI.COMM_WORLD)
    gel_mesh, gel_facets = meshes.region("gel")
    gamma1 = gel_facets.find(Tag.GAMMA1)
"""

from __future__ import annotations

import os
import time
import typing

import numpy as np

from mpi4py import MPI

from dolfinx import io as _io

from femtools import petscgarbage
from femtools.gmshimport import gmsh_session
from femtools.mesh import ModelArrays, model_to_mesh, model_to_region_mesh
from gelcell.case import CaseParameters
from gelcell.errors import ModelLimitError, ParameterError
from gelcell.geometry import meshcache
from gelcell.geometry.describe import described, device_layout
from gelcell.geometry.layout import DeviceLayout
from gelcell.geometry.tags import FACET_TAGS, REGIONS, Tag, tag_name

__all__ = ["DeviceMeshes", "build_meshes"]


# --------------------------------------------------------------------------- gmsh model
def _mesh_with_gmsh(params: CaseParameters) -> ModelArrays:
    """Mesh the device of ``params`` with gmsh (rank 0) and return the raw arrays of its mesh.

    A user's geometry file is meshed in a child process (stoppable, bounded:
    :mod:`gelcell.geometry.files.child`), a built-in device in this one."""
    if params.case == "file":
        from gelcell.geometry.files.build import mesh_file
        return ModelArrays(**mesh_file(params))
    with gmsh_session() as gmsh:
        _build_builtin_model(params)
        return ModelArrays.from_model(gmsh.model)


def _build_builtin_model(params: CaseParameters) -> None:
    """Build and mesh the gmsh model of a built-in device, planar or 3D (current gmsh session)."""
    if getattr(params.geometry, "dimension", 2) == 3:
        from gelcell.geometry.builtin_model3d import build_model_3d     # imports gmsh
        build_model_3d(params)
    else:
        from gelcell.geometry.builtin_model import build_model          # imports gmsh
        build_model(params)


def _device_arrays(params: CaseParameters) -> ModelArrays:
    """Raw mesh arrays of the device of ``params`` (rank 0): from the mesh cache, else meshed and cached."""
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


class DeviceMeshes:
    """The meshes of one device case.

    Attributes:
        params: the :class:`CaseParameters` it was built from.
        case: ``"shear"`` or ``"normal"``.
        with_cell: whether the cell (Γ2) is present.
        interfaces: names of the interfaces present, e.g. ``["Gamma1", "Gamma2"]``.
        whole: ``(mesh, cell_tags, facet_tags)`` of the whole device, or None.
        build_time: wall time of :func:`build_meshes` [s].
    """

    def __init__(self, params: CaseParameters, regions: dict, whole, comm: MPI.Comm,
                 build_time: float, layout: DeviceLayout | None = None, cell_tags=None):
        self.params = params
        self.case = params.case
        self.with_cell = params.with_cell
        self.comm = comm
        self._regions = regions
        self.whole = whole
        self.build_time = build_time
        #: :class:`~gelcell.geometry.layout.DeviceLayout`: conditions, cells, interfaces
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
        facet_tags = sorted(set(int(t) for t in FACET_TAGS) | set(self._facet_values()))
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
        return (f"DeviceMeshes(case={self.case!r}, with_cell={self.with_cell}, regions={self.regions}, "
                f"interfaces={self.interfaces})")


def build_meshes(params: CaseParameters, comm: MPI.Comm = MPI.COMM_WORLD, *,
                 regions: typing.Iterable[str] | None = None, whole: bool = True) -> DeviceMeshes:
    """Build the gmsh model of ``params`` once and all requested dolfinx meshes from it.

    Args:
        params: the case (validated again here, before any meshing).
        comm: communicator of the meshes; gmsh runs on its rank 0 only.
        regions: region meshes to build (default: fluid, gel and, with a cell, cell).
        whole: also build the whole device as one mesh.

    Returns:
        A :class:`DeviceMeshes`.
    """
    t0 = time.perf_counter()
    params = described(params)
    params.validate()
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
            raise ParameterError(error[1])
        if error[0] == "ModelLimitError":
            raise ModelLimitError(error[1])
        raise RuntimeError(f"meshing the {params.case} device failed: {error[0]}: {error[1]}")
    cell_tags = None
    region_meshes = {}
    gdim = getattr(params.geometry, "dimension", 2)
    for name in wanted:
        tags = layout.cell_region_tags if name == "cell" else [int(REGIONS[name])]
        if name == "cell":
            msh, cell_tags, ft = model_to_region_mesh(arrays, comm, 0, tags, gdim=gdim, with_cell_tags=True)
            region_meshes[name] = (msh, ft)
        else:
            region_meshes[name] = model_to_region_mesh(arrays, comm, 0, tags, gdim=gdim)
    whole_mesh = model_to_mesh(arrays, comm, 0, gdim=gdim) if whole else None
    return DeviceMeshes(params, region_meshes, whole_mesh, comm, time.perf_counter() - t0, layout, cell_tags)
