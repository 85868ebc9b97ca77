"""Meshes from a gmsh model on dolfinx 0.5.2: the whole model, or one region.

dolfinx 0.5.2's ``create_submesh`` keeps only the vertices of curved (P2)
cells, so each field solver gets a mesh built straight from the gmsh model,
restricted to its physical surface(s).  Nodes on an interface between two
regions are then bit-identical in both region meshes, which is what the
interface maps rely on.

The meshes are built from :class:`ModelArrays`, the raw arrays of a meshed
gmsh model, which can be read once from the model (or from a cache) and
reused for every region.  gmsh itself (its import loads libgmsh) is imported
only where a model is read, through :func:`femtools.gmshimport.import_gmsh`.

:func:`rectangle_mesh` is the one mesh made without gmsh: dolfinx's
triangulated rectangle with its four sides tagged (flat layers, tests).
"""

from __future__ import annotations

import dataclasses
import typing

import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import cpp as _cpp
from dolfinx.mesh import (CellType, DiagonalType, create_mesh, create_rectangle, locate_entities_boundary, meshtags,
                          meshtags_from_entities)

from femtools import petscgarbage
from femtools.gmshimport import import_gmsh

__all__ = ["model_to_mesh", "model_to_region_mesh", "connected_components", "PARTITIONER", "ModelArrays",
           "settle_coordinate_element", "as_tags", "tagged_facets", "rectangle_mesh", "LEFT", "RIGHT", "BOTTOM",
           "TOP"]

#: gmsh element type -> (cell shape, degree) of the elements meshes are made of (dolfinx.io.gmshio's table)
_GMSH_CELLS = {1: ("interval", 1), 2: ("triangle", 1), 3: ("quadrilateral", 1), 4: ("tetrahedron", 1),
               5: ("hexahedron", 1), 8: ("interval", 2), 9: ("triangle", 2), 10: ("quadrilateral", 2),
               11: ("tetrahedron", 2), 12: ("hexahedron", 2)}


@dataclasses.dataclass
class ModelArrays:
    """The raw arrays of a meshed gmsh model that dolfinx meshes are built from.

    ``x``: node coordinates ``(n, 3)``; per gmsh element type ``k``:
    ``topology[k]`` (zero-based node numbers, one row per element),
    ``markers[k]`` (physical tag of each element) and ``dims[k]`` (its
    topological dimension).  Only elements of physical groups are kept.
    """

    x: np.ndarray
    topology: dict[int, np.ndarray]
    markers: dict[int, np.ndarray]
    dims: dict[int, int]

    @classmethod
    def from_model(cls, model) -> "ModelArrays":
        """Read the arrays of the current mesh of the gmsh ``model`` (e.g. ``gmsh.model``)."""
        import_gmsh()                # before gmshio, whose import imports gmsh
        from dolfinx.io import gmshio
        topo = gmshio.extract_topology_and_markers(model)
        return cls(x=gmshio.extract_geometry(model),
                   topology={int(k): v["topology"] for k, v in topo.items()},
                   markers={int(k): v["cell_data"] for k, v in topo.items()},
                   dims={int(k): int(model.mesh.getElementProperties(k)[1]) for k in topo})


def as_tags(tags, what: str = "tags") -> tuple[int, ...]:
    """An int or an iterable of ints (facet or cell tags) as a tuple of ints; ``what`` names the
    parameter in the TypeError (not ints) or ValueError (none given)."""
    if isinstance(tags, (str, bytes)):
        raise TypeError(f"{what}: tags must be an int or an iterable of ints, got {tags!r}")
    if np.isscalar(tags):
        tags = (tags,)
    try:
        out = tuple(int(t) for t in tags)
    except (TypeError, ValueError):
        raise TypeError(f"{what}: tags must be an int or an iterable of ints, got {tags!r}") from None
    if not out:
        raise ValueError(f"{what}: empty tag list")
    return out


def tagged_facets(facet_tags, tags) -> np.ndarray:
    """This rank's facets carrying any of ``tags`` (an int or ints; none: none): sorted, unique, int32."""
    found = [facet_tags.find(int(t)) for t in ([tags] if np.isscalar(tags) else tags)]
    return np.unique(np.hstack(found + [np.empty(0, np.int32)])).astype(np.int32)


def settle_coordinate_element(msh):
    """Give ``msh``'s ufl coordinate element the ``equispaced`` variant now; returns ``msh``.

    FFCx 0.5 sets that variant on the shared ufl domain of every form it
    compiles (not on a cache hit).  A test or trial function made before such
    a compilation then differs (repr and hash) from one of the same space
    made after it, and a form holding both fails ("Found different Arguments
    with same number and part") on the first run on a machine only.  Meshes
    from gmsh (:func:`model_to_mesh`) are built with the variant; dolfinx's
    own ``create_rectangle`` etc. are not, so the field solvers, the mesh
    motion and the monolithic solver settle their mesh before they make any form.
    """
    domain = msh.ufl_domain()
    element = domain.ufl_coordinate_element()
    if element.variant() is None:
        sub = element.sub_elements()[0]
        domain._ufl_coordinate_element = ufl.VectorElement(ufl.FiniteElement(
            sub.family(), sub.cell(), sub.degree(), sub.quadrature_scheme(), variant="equispaced"),
            dim=element.value_shape()[0])
    return msh


def _ufl_mesh(gmsh_type: int, gdim: int) -> ufl.Mesh:
    """The ufl mesh of elements of gmsh type ``gmsh_type`` (as ``dolfinx.io.gmshio.ufl_mesh``, without gmsh)."""
    shape, degree = _GMSH_CELLS[gmsh_type]
    cell = ufl.Cell(shape, geometric_dimension=gdim)
    return ufl.Mesh(ufl.VectorElement(ufl.FiniteElement("Lagrange", cell, degree, variant="equispaced")))


def _band_partition(comm: MPI.Comm, nparts: int, graph, ghosting: bool):
    """Cells in the reverse Cuthill-McKee order of the dual graph, cut into ``nparts`` equal bands.

    A deterministic graph partitioner: the same mesh always gets the same
    partition (dolfinx 0.5.2's SCOTCH partitioner draws another one in every
    process, which changes round-off from run to run).  With ``ghosting``,
    each cell also lists the other parts that own a neighbour of it.  The
    ordering is sequential: rank 0 gathers the dual graph (the meshes built
    here hand every cell to create_mesh on rank 0 anyway), and each rank
    receives the parts of its own cells only.
    """
    offsets, links = np.asarray(graph.offsets), np.asarray(graph.array)
    n_local = graph.num_nodes
    counts = comm.allgather(n_local)
    start = int(sum(counts[:comm.rank]))
    rows = np.repeat(np.arange(n_local, dtype=np.int64) + start, np.diff(offsets))
    pieces = comm.gather((rows, links.astype(np.int64)), root=0)
    mine = comm.scatter(_band_parts(pieces, counts, nparts, ghosting) if comm.rank == 0 else None, root=0)
    if not ghosting or nparts == 1:
        return _cpp.graph.AdjacencyList_int32(mine[0])
    return _cpp.graph.AdjacencyList_int32(*mine)


def _band_parts(pieces: list, counts: list, nparts: int, ghosting: bool) -> list:
    """On rank 0: per rank, the parts of its cells (``(parts,)``, or with ``ghosting``
    ``(owner and the other parts of each cell's neighbours, offsets)``) from the gathered dual graph."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import reverse_cuthill_mckee
    rows, cols = (np.concatenate([p[k] for p in pieces]) for k in range(2))
    n = int(sum(counts))
    _record_dual_graph(n, rows.size)
    adjacency = csr_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(n, n))
    order = reverse_cuthill_mckee(adjacency, symmetric_mode=True)
    parts = np.empty(n, dtype=np.int32)
    parts[order] = (np.arange(n, dtype=np.int64) * nparts // max(n, 1)).astype(np.int32)
    bounds = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    if not ghosting or nparts == 1:
        return [(parts[bounds[r]:bounds[r + 1]].copy(),) for r in range(len(counts))]
    # each cell: its owner, then the other parts among its neighbours, sorted
    other = parts[cols] != parts[rows]
    keys = np.unique(np.concatenate([np.arange(n, dtype=np.int64) * (nparts + 1),
                                     rows[other] * (nparts + 1) + parts[cols[other]] + 1]))
    cell, slot = keys // (nparts + 1), keys % (nparts + 1)
    data = np.where(slot == 0, parts[cell], slot - 1).astype(np.int32)
    ends = np.searchsorted(cell, bounds)
    out = []
    for r in range(len(counts)):
        here = cell[ends[r]:ends[r + 1]] - bounds[r]
        offsets = np.concatenate([[0], np.cumsum(np.bincount(here, minlength=counts[r]))]).astype(np.int32)
        out.append((data[ends[r]:ends[r + 1]].copy(), offsets))
    return out


#: when a list, :func:`_band_parts` appends ``(cells, links)`` of each dual graph it gathers on rank 0
DUAL_GRAPHS: list | None = None


def _record_dual_graph(cells: int, links: int) -> None:
    if DUAL_GRAPHS is not None:
        DUAL_GRAPHS.append((cells, links))


#: the cell partitioner of every mesh built here (deterministic, see ``_band_partition``)
PARTITIONER = _cpp.mesh.create_cell_partitioner(_band_partition)


def _region_arrays(model, region_tags):
    """The cells with physical tags ``region_tags`` (all if None), renumbered onto their own nodes, and the
    facets of the model all of whose nodes they use: ``(cell_id, cells, cell values, x, facets, facet values)``."""
    data = model if isinstance(model, ModelArrays) else ModelArrays.from_model(model)
    x, dims = data.x, data.dims
    cell_id = max(data.topology, key=lambda k: dims[k])
    tdim = dims[cell_id]
    facet_ids = [k for k in data.topology if dims[k] == tdim - 1]
    cells, cvals = data.topology[cell_id], data.markers[cell_id].astype(np.int32)
    if region_tags is not None:
        keep = np.isin(cvals, region_tags)
        cells, cvals = cells[keep], cvals[keep]
        if cells.shape[0] == 0:
            raise ValueError(f"the gmsh model has no cells with physical tags {region_tags.tolist()}")
    used = np.unique(cells)
    new = np.full(x.shape[0], -1, np.int64)
    new[used] = np.arange(used.size)
    cells, x = new[cells], x[used]
    if facet_ids:
        f, fv = data.topology[facet_ids[0]], data.markers[facet_ids[0]]
        keep = np.all(new[f] >= 0, axis=1)
        facets, fvals = new[f[keep]], fv[keep].astype(np.int32)
    else:
        facets, fvals = np.empty((0, 2), np.int64), np.empty(0, np.int32)
    return cell_id, cells, cvals, x, facets, fvals


def _entity_tags(msh, dim: int, entities_in, values_in, name: str):
    """Meshtags of dimension ``dim`` from (gmsh-ordered, dolfinx-permuted) entities given on any rank."""
    entities, values = _cpp.io.distribute_entity_data(msh._mesh, dim, entities_in, values_in)
    msh.topology.create_connectivity(dim, 0)
    t = meshtags_from_entities(msh, dim, _cpp.graph.AdjacencyList_int32(entities), values.astype(np.int32))
    t.name = name
    return t


def _model_mesh(model, comm: MPI.Comm, rank: int, region_tags, gdim: int):
    """Mesh of the cells with physical tags ``region_tags`` (all cells if None): (mesh, cell_tags, facet_tags).

    ``model`` (used on rank ``rank`` only) is a gmsh model or its :class:`ModelArrays`.
    """
    if comm.rank == rank:
        cell_id, cells, cvals, x, facets, fvals = _region_arrays(model, region_tags)
        meta = comm.bcast((cell_id, cells.shape[1], facets.shape[1]), root=rank)
    else:
        cell_id, nn, nf = comm.bcast(None, root=rank)
        cells, cvals, x = np.empty((0, nn), np.int64), np.empty(0, np.int32), np.empty((0, 3))
        facets, fvals = np.empty((0, nf), np.int64), np.empty(0, np.int32)
        meta = (cell_id, nn, nf)
    cell_id, nn, nf = meta
    domain = _ufl_mesh(cell_id, gdim)
    ctype = _cpp.mesh.to_type(str(domain.ufl_cell()))
    cells = cells[:, _cpp.io.perm_gmsh(ctype, nn)]
    msh = create_mesh(comm, cells, x[:, :gdim], domain, partitioner=PARTITIONER)
    petscgarbage.keep(msh, comm)          # its communicator outlives the solvers' PETSc objects
    tdim = msh.topology.dim
    cell_tags = _entity_tags(msh, tdim, cells, cvals, "cell_tags")
    ftype = _cpp.mesh.cell_entity_type(ctype, tdim - 1, 0)
    facets = facets[:, _cpp.io.perm_gmsh(ftype, nf)]
    msh.topology.create_connectivity(tdim - 1, tdim)
    facet_tags = _entity_tags(msh, tdim - 1, facets, fvals, "facet_tags")
    return msh, cell_tags, facet_tags


def model_to_mesh(model, comm: MPI.Comm, rank: int = 0, gdim: int = 2):
    """Whole gmsh model (or its :class:`ModelArrays`) as one dolfinx mesh: ``(mesh, cell_tags, facet_tags)``."""
    return _model_mesh(model, comm, rank, None, gdim)


def model_to_region_mesh(model, comm: MPI.Comm, rank: int, region_tags: typing.Iterable[int],
                         gdim: int = 2, with_cell_tags: bool = False):
    """Mesh of the cells of the physical surfaces ``region_tags`` only (``model``: gmsh model or :class:`ModelArrays`).

    Returns ``(mesh, facet_tags)`` (``(mesh, cell_tags, facet_tags)`` with
    ``with_cell_tags``).  The facet tags keep every tagged facet of the gmsh
    model whose nodes all belong to the region, i.e. the region's own
    boundaries and the interfaces it shares with its neighbours.
    """
    msh, cell_tags, facet_tags = _model_mesh(model, comm, rank, np.asarray(list(region_tags), dtype=np.int64), gdim)
    return (msh, cell_tags, facet_tags) if with_cell_tags else (msh, facet_tags)


#: facet tags of the sides of :func:`rectangle_mesh`: x = x0, x = x1, y = y0, y = y1
LEFT, RIGHT, BOTTOM, TOP = 1, 2, 3, 4


def rectangle_mesh(x0: float, y0: float, x1: float, y1: float, nx: int, ny: int,
                   comm: MPI.Comm = MPI.COMM_WORLD, diagonal: DiagonalType = DiagonalType.right):
    """Rectangle [x0, x1] x [y0, y1] with nx x ny cell pairs (dolfinx's ``create_rectangle``, P1
    triangles); returns ``(mesh, facet_tags)``.

    Facet tags: LEFT (x = x0) = 1, RIGHT (x = x1) = 2, BOTTOM (y = y0) = 3, TOP (y = y1) = 4.
    """
    msh = create_rectangle(comm, [np.array([x0, y0]), np.array([x1, y1])], [nx, ny],
                           CellType.triangle, diagonal=diagonal)
    tol = 1e-10 * max(x1 - x0, y1 - y0)
    sides = ((LEFT, 0, x0), (RIGHT, 0, x1), (BOTTOM, 1, y0), (TOP, 1, y1))
    idx, val = [], []
    for tag, axis, coord in sides:
        facets = locate_entities_boundary(
            msh, 1, lambda x, a=axis, c=coord: np.isclose(x[a], c, rtol=0.0, atol=tol))
        idx.append(facets)
        val.append(np.full(facets.size, tag, dtype=np.int32))
    idx, val = np.hstack(idx), np.hstack(val)
    order = np.argsort(idx)
    return msh, meshtags(msh, 1, idx[order].astype(np.int32), val[order])


def connected_components(msh) -> tuple[np.ndarray, int]:
    """Connected parts of ``msh`` (cells joined through facets), on any number of ranks.

    Returns ``(labels, count)``: a component number in ``range(count)`` for each
    local cell (owned and ghost), the same on every rank.  Every rank gathers the
    cell-to-cell adjacency by global indices (fine for the device's 2-D meshes):
    facets with two local cells give an edge directly; a facet with one local
    cell is paired with the other rank's copy of it (an exterior facet has none).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as components
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    f2c = msh.topology.connectivity(tdim - 1, tdim)
    cmap, fmap = msh.topology.index_map(tdim), msh.topology.index_map(tdim - 1)
    n_cells = cmap.size_local + cmap.num_ghosts
    cell_ids = cmap.local_to_global(np.arange(n_cells, dtype=np.int32))
    n_links = np.diff(f2c.offsets)
    first = cell_ids[f2c.array[f2c.offsets[:-1]]]
    two = n_links == 2
    edges = [np.column_stack([first[two], cell_ids[f2c.array[f2c.offsets[:-1][two] + 1]]])]
    single = np.flatnonzero(n_links == 1).astype(np.int32)
    halves = np.column_stack([fmap.local_to_global(single), first[single]])
    halves = np.vstack(msh.comm.allgather(halves))
    halves = halves[np.lexsort((halves[:, 1], halves[:, 0]))]
    pair = np.flatnonzero((halves[1:, 0] == halves[:-1, 0]) & (halves[1:, 1] != halves[:-1, 1]))
    edges.append(np.column_stack([halves[pair, 1], halves[pair + 1, 1]]))
    edges = np.vstack(msh.comm.allgather(np.vstack(edges)))
    n = cmap.size_global
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    count, labels = components(graph, directed=False)
    return labels[cell_ids], int(count)
