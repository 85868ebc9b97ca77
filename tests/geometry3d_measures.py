"""Measures of the 3D device meshes (volumes, areas per tag, interface nodes), reduced over all ranks.

Shared by tests/test_geometry_3d.py and benchmarks/geometry_3d.py.
"""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

import ufl
from dolfinx import fem, mesh as dmesh

from gelcell.geometry import tag_name
from gelcell.geometry.meshes import build_meshes

#: P2 tetrahedron: the geometry node of local edge e is 4 + e; edge e joins these vertices (dolfinx order)
_TET_EDGES = ((2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1))


def integrate(form) -> float:
    return MPI.COMM_WORLD.allreduce(fem.assemble_scalar(fem.form(form)), op=MPI.SUM)


def _tag_values(ft) -> list[int]:
    return sorted(MPI.COMM_WORLD.allreduce(set(ft.values.tolist()), op=MPI.BOR))


def facet_nodes(msh, facets) -> np.ndarray:
    """Coordinates of the geometry nodes (vertices and P2 edge nodes) of ``facets``, all ranks, unique."""
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    msh.topology.create_connectivity(tdim, tdim - 1)
    f2c, c2f = msh.topology.connectivity(tdim - 1, tdim), msh.topology.connectivity(tdim, tdim - 1)
    dofs, x = msh.geometry.dofmap, msh.geometry.x
    pts = []
    for f in facets:
        c = f2c.links(f)[0]
        i = int(np.flatnonzero(c2f.links(c) == f)[0])     # facet i is opposite vertex i
        nodes = dofs.links(c)
        pts += [x[nodes[j]] for j in range(4) if j != i]
        pts += [x[nodes[4 + e]] for e, ends in enumerate(_TET_EDGES) if i not in ends]
    local = np.array(pts).reshape(-1, 3)
    return np.unique(np.vstack(MPI.COMM_WORLD.allgather(local)), axis=0)


def region_measures(msh, ft) -> dict:
    """Volume, area per tag, and the tagging of one region mesh's boundary."""
    ds = ufl.Measure("ds", domain=msh, subdomain_data=ft, metadata={"quadrature_degree": 6})
    one = fem.Constant(msh, 1.0)
    volume = integrate(one * ufl.dx(domain=msh, metadata={"quadrature_degree": 4}))
    area = {tag_name(v): integrate(one * ds(int(v))) for v in _tag_values(ft)}
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    n_owned = msh.topology.index_map(tdim - 1).size_local
    ext = dmesh.exterior_facet_indices(msh.topology)
    ext, tagged = ext[ext < n_owned], ft.indices[ft.indices < n_owned]
    untagged = MPI.COMM_WORLD.allreduce(np.setdiff1d(ext, tagged).size, op=MPI.SUM)
    interior = MPI.COMM_WORLD.allreduce(np.setdiff1d(tagged, ext).size, op=MPI.SUM)
    return {"volume": volume, "area": area, "untagged_boundary_facets": untagged,
            "tagged_interior_facets": interior}


def measure(params) -> dict:
    """Measures of every region mesh of ``params``, its counts, and whether each interface's nodes coincide."""
    dev = build_meshes(params, MPI.COMM_WORLD, whole=False)
    out = {"counts": dev.counts(), "regions": {n: region_measures(*dev.region(n)) for n in dev.regions},
           "nodes_equal": {}, "interface_nodes": {}}
    for name in dev.interfaces:
        tag, (a, b) = dev.interface(name)
        na = facet_nodes(dev.region(a)[0], dev.region(a)[1].find(tag))
        nb = facet_nodes(dev.region(b)[0], dev.region(b)[1].find(tag))
        out["nodes_equal"][name] = bool(na.shape == nb.shape and np.array_equal(na, nb))
        out["interface_nodes"][name] = int(na.shape[0])
    return out


def _summed(area: dict, name: str) -> float:
    """The area of tag ``name``; GAMMA2: summed over every cell's Γ2 (GAMMA2, GAMMA2_2, ...)."""
    if name == "GAMMA2":
        return sum(v for k, v in area.items() if k == "GAMMA2" or k.startswith("GAMMA2_"))
    return area.get(name, 0.0)


def errors(params, m: dict) -> dict:
    """Relative errors of the measured volumes and areas against :func:`closed_form_measures_3d`."""
    from gelcell.geometry.builtin import closed_form_measures_3d
    exact = closed_form_measures_3d(params)
    out = {}
    for name, r in m["regions"].items():
        out[(name, "volume")] = abs(r["volume"] - exact[name]["volume"]) / exact[name]["volume"]
        for tag, a in exact[name]["area"].items():
            out[(name, tag_name(tag))] = abs(_summed(r["area"], tag_name(tag)) - a) / a
    return out
