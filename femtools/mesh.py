"""Meshes from a gmsh model on dolfinx 0.5.2: the whole model, or one region.

dolfinx 0.5.2's ``create_submesh`` keeps only the vertices of curved (P2)
cells, so each field solver gets a mesh built straight from the gmsh model,
restricted to its physical surface(s).  Nodes on an interface between two
regions are then bit-identical in both region meshes, which is what the
interface maps rely on.
"""

from __future__ import annotations

import typing

import numpy as np

from mpi4py import MPI

from dolfinx import cpp as _cpp
from dolfinx.io import gmshio
from dolfinx.mesh import create_mesh, meshtags_from_entities

__all__ = ["model_to_mesh", "model_to_region_mesh", "connected_components"]


def model_to_mesh(model, comm: MPI.Comm, rank: int = 0, gdim: int = 2):
    """Whole gmsh model as one dolfinx mesh: ``(mesh, cell_tags, facet_tags)``."""
    msh, cell_tags, facet_tags = gmshio.model_to_mesh(model, comm, rank, gdim=gdim)
    cell_tags.name, facet_tags.name = "cell_tags", "facet_tags"
    return msh, cell_tags, facet_tags


def model_to_region_mesh(model, comm: MPI.Comm, rank: int, region_tags: typing.Iterable[int],
                         gdim: int = 2):
    """Mesh of the cells of the physical surfaces ``region_tags`` only.

    Returns ``(mesh, facet_tags)``.  The facet tags keep every tagged facet of
    the gmsh model whose nodes all belong to the region, i.e. the region's own
    boundaries and the interfaces it shares with its neighbours.
    """
    region_tags = np.asarray(list(region_tags), dtype=np.int64)
    if comm.rank == rank:
        x = gmshio.extract_geometry(model)
        topo = gmshio.extract_topology_and_markers(model)
        info = {k: model.mesh.getElementProperties(k) for k in topo}
        cell_id = max(topo, key=lambda k: info[k][1])
        tdim = info[cell_id][1]
        facet_ids = [k for k in topo if info[k][1] == tdim - 1]
        in_region = np.isin(topo[cell_id]["cell_data"], region_tags)
        cells = topo[cell_id]["topology"][in_region]
        if cells.shape[0] == 0:
            raise ValueError(f"the gmsh model has no cells with physical tags {region_tags.tolist()}")
        used = np.unique(cells)
        new = np.full(x.shape[0], -1, np.int64)
        new[used] = np.arange(used.size)
        cells, x = new[cells], x[used]
        if facet_ids:
            f, fv = topo[facet_ids[0]]["topology"], topo[facet_ids[0]]["cell_data"]
            keep = np.all(new[f] >= 0, axis=1)
            facets, fvals = new[f[keep]], fv[keep].astype(np.int32)
        else:
            facets, fvals = np.empty((0, 2), np.int64), np.empty(0, np.int32)
        meta = comm.bcast((cell_id, cells.shape[1], facets.shape[1]), root=rank)
    else:
        cell_id, nn, nf = comm.bcast(None, root=rank)
        cells, x = np.empty((0, nn), np.int64), np.empty((0, 3))
        facets, fvals = np.empty((0, nf), np.int64), np.empty(0, np.int32)
        meta = (cell_id, nn, nf)
    cell_id, nn, nf = meta
    domain = gmshio.ufl_mesh(cell_id, gdim)
    ctype = _cpp.mesh.to_type(str(domain.ufl_cell()))
    cells = cells[:, gmshio.cell_perm_array(ctype, nn)]
    msh = create_mesh(comm, cells, x[:, :gdim], domain)
    tdim = msh.topology.dim
    ftype = _cpp.mesh.cell_entity_type(ctype, tdim - 1, 0)
    facets = facets[:, gmshio.cell_perm_array(ftype, nf)]
    entities, values = _cpp.io.distribute_entity_data(msh._mesh, tdim - 1, facets, fvals)
    msh.topology.create_connectivity(tdim - 1, tdim)
    facet_tags = meshtags_from_entities(msh, tdim - 1, _cpp.graph.AdjacencyList_int32(entities),
                                        values.astype(np.int32))
    facet_tags.name = "facet_tags"
    return msh, facet_tags


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
