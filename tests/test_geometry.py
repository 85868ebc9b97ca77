"""Device geometries and meshes against closed-form areas and lengths.

Runs under ``pytest`` and under ``mpirun -n 2 python -m pytest`` (all checks
reduce over MPI first).  ``test_two_ranks`` also launches this file as a
script on 2 ranks from a serial run and compares with serial.

Tolerance of the area/length checks: straight boundaries are exact to
rounding; a circle (arc) meshed by n curved P2 edges has a relative area
error of about 3.2 n^-4 and a relative length error of about 1.6 n^-4
(measured 6.1e-7 and 3.1e-7 for the cell's 48 edges; the bowl and the posts
have many more edges per radian and errors below 4e-8).  ``REL_TOL = 2e-6``
is 3x the worst measured error, while a single missing or mis-tagged edge
changes a length by at least 1/160 of it (the longest tagged curve has 158
edges), three orders of magnitude above the tolerance.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from mpi4py import MPI

import ufl
from dolfinx import fem, io, mesh as dmesh

from gelcell.geometry import INTERFACES, REGIONS, Tag
from gelcell.geometry.builtin import closed_form_measures
from gelcell.geometry.meshes import build_meshes
from gelcell.case import CaseParameters

REL_TOL = 2e-6

# (label, parameters): the four baseline cases and variants with other lengths
CASES = {
    "shear_cell": lambda: CaseParameters.default("shear", True),
    "shear_nocell": lambda: CaseParameters.default("shear", False),
    "normal_cell": lambda: CaseParameters.default("normal", True),
    "normal_nocell": lambda: CaseParameters.default("normal", False),
}
VARIANTS = {
    "shear_variant": lambda: CaseParameters.default("shear").replace(
        geometry=dataclasses.replace(CaseParameters.default("shear").geometry, half_angle=math.pi / 2,
                                     chamber_width=1.5, channel_height=0.3, cell_diameter=0.1,
                                     e=0.4, cell_offset_x=0.2)),
    "normal_variant": lambda: CaseParameters.default("normal").replace(
        geometry=dataclasses.replace(CaseParameters.default("normal").geometry, post_diameter=0.3,
                                     post_clearance=0.1, gel_length=2.0, height=0.4, e=0.3,
                                     cell_diameter=0.08)),
}


# --------------------------------------------------------------------------- measurements
def _integrate(form) -> float:
    return MPI.COMM_WORLD.allreduce(fem.assemble_scalar(fem.form(form)), op=MPI.SUM)


def _facet_nodes(msh, facets) -> np.ndarray:
    """Coordinates of the geometry nodes (vertices and P2 mid-nodes) of ``facets``, all ranks."""
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    msh.topology.create_connectivity(tdim, tdim - 1)
    f2c, c2f = msh.topology.connectivity(tdim - 1, tdim), msh.topology.connectivity(tdim, tdim - 1)
    dofs, x = msh.geometry.dofmap, msh.geometry.x
    pts = []
    for f in facets:
        c = f2c.links(f)[0]
        i = int(np.flatnonzero(c2f.links(c) == f)[0])
        nodes = dofs.links(c)
        verts = [nodes[j] for j in range(3) if j != i]
        mid = nodes[3 + i]       # P2 triangle: edge i (opposite vertex i) has node 3 + i
        a, b, m = x[verts[0], :2], x[verts[1], :2], x[mid, :2]
        assert np.linalg.norm(m - 0.5 * (a + b)) < 0.25 * np.linalg.norm(b - a), "P2 node layout"
        pts += [x[verts[0], :2], x[verts[1], :2], m]
    local = np.array(pts).reshape(-1, 2)
    allpts = np.vstack(MPI.COMM_WORLD.allgather(local))
    return np.unique(allpts, axis=0)


def _owned(msh, dim, entities):
    return entities[entities < msh.topology.index_map(dim).size_local]


def _region_checks(msh, ft) -> dict:
    """Area, length per tag, and tagging sanity of one region mesh."""
    ds = ufl.Measure("ds", domain=msh, subdomain_data=ft, metadata={"quadrature_degree": 8})
    one = fem.Constant(msh, 1.0)
    area = _integrate(one * ufl.dx(domain=msh, metadata={"quadrature_degree": 4}))
    lengths = {Tag(int(v)).name: _integrate(one * ds(int(v)))
               for v in sorted(set(MPI.COMM_WORLD.allreduce(set(ft.values.tolist()), op=MPI.BOR)))}
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    ext = _owned(msh, tdim - 1, dmesh.exterior_facet_indices(msh.topology))
    tagged = _owned(msh, tdim - 1, ft.indices)
    untagged = MPI.COMM_WORLD.allreduce(np.setdiff1d(ext, tagged).size, op=MPI.SUM)
    duplicate = MPI.COMM_WORLD.allreduce(tagged.size - np.unique(tagged).size, op=MPI.SUM)
    not_boundary = MPI.COMM_WORLD.allreduce(np.setdiff1d(tagged, ext).size, op=MPI.SUM)
    return {"area": area, "length": lengths, "untagged_boundary_facets": untagged,
            "duplicate_tags": duplicate, "tagged_interior_facets": not_boundary}


def _whole_checks(msh, ct, ft) -> dict:
    tdim = msh.topology.dim
    dx = ufl.Measure("dx", domain=msh, subdomain_data=ct, metadata={"quadrature_degree": 4})
    ds = ufl.Measure("ds", domain=msh, subdomain_data=ft, metadata={"quadrature_degree": 8})
    dS = ufl.Measure("dS", domain=msh, subdomain_data=ft, metadata={"quadrature_degree": 8})
    one = fem.Constant(msh, 1.0)
    values = sorted(set(MPI.COMM_WORLD.allreduce(set(ft.values.tolist()), op=MPI.BOR)))
    area = {Tag(v).name: _integrate(one * dx(int(v))) for v in REGIONS.values()}
    length = {}
    for v in values:
        length[Tag(v).name] = _integrate(one * ds(int(v))) + _integrate(one("+") * dS(int(v)))
    # every facet between two different regions is tagged with the interface tag
    msh.topology.create_connectivity(tdim - 1, tdim)
    f2c = msh.topology.connectivity(tdim - 1, tdim)
    cell_value = np.zeros(msh.topology.index_map(tdim).size_local
                          + msh.topology.index_map(tdim).num_ghosts, dtype=np.int32)
    cell_value[ct.indices] = ct.values
    tag_of = dict(zip(ft.indices.tolist(), ft.values.tolist()))
    wrong = 0
    expected = {frozenset((1, 2)): (Tag.GAMMA1, Tag.GAMMA3), frozenset((2, 3)): (Tag.GAMMA2,)}
    for f in range(msh.topology.index_map(tdim - 1).size_local):
        cells = f2c.links(f)
        if len(cells) == 2 and cell_value[cells[0]] != cell_value[cells[1]]:
            pair = frozenset(int(cell_value[c]) for c in cells)
            wrong += tag_of.get(f) not in expected.get(pair, ())
    ext = _owned(msh, tdim - 1, dmesh.exterior_facet_indices(msh.topology))
    untagged = np.setdiff1d(ext, ft.indices).size
    return {"area": area, "length": length,
            "untagged_interface_facets": MPI.COMM_WORLD.allreduce(wrong, op=MPI.SUM),
            "untagged_boundary_facets": MPI.COMM_WORLD.allreduce(untagged, op=MPI.SUM)}


def measure(params: CaseParameters) -> dict:
    """Everything the tests compare, reduced over all ranks (identical on every rank)."""
    dev = build_meshes(params, MPI.COMM_WORLD)
    out = {"counts": dev.counts(), "interfaces": dev.interfaces, "regions": {}, "nodes_equal": {}}
    for name in dev.regions:
        out["regions"][name] = _region_checks(*dev.region(name))
    out["whole"] = _whole_checks(*dev.whole)
    for name in dev.interfaces:
        tag, (a, b) = INTERFACES[name]
        na = _facet_nodes(dev.region(a)[0], dev.region(a)[1].find(tag))
        nb = _facet_nodes(dev.region(b)[0], dev.region(b)[1].find(tag))
        out["nodes_equal"][name] = bool(na.shape == nb.shape and np.array_equal(na, nb))
        out.setdefault("interface_nodes", {})[name] = int(na.shape[0])
    return out


def _rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def check(label: str, params: CaseParameters, m: dict) -> None:
    exact = closed_form_measures(params)
    for name, r in m["regions"].items():
        assert _rel(r["area"], exact[name]["area"]) < REL_TOL, (label, name, r["area"])
        assert set(r["length"]) == {t.name for t in exact[name]["length"]}, (label, name, r["length"])
        for tag, length in exact[name]["length"].items():
            assert _rel(r["length"][tag.name], length) < REL_TOL, (label, name, tag.name)
        assert r["untagged_boundary_facets"] == 0, (label, name)
        assert r["duplicate_tags"] == 0, (label, name)
        assert r["tagged_interior_facets"] == 0, (label, name)
    w = m["whole"]
    for tag, a in exact["whole"]["area"].items():
        assert _rel(w["area"][tag.name], a) < REL_TOL, (label, "whole", tag.name)
    assert set(w["length"]) == {t.name for t in exact["whole"]["length"]}, (label, w["length"])
    for tag, length in exact["whole"]["length"].items():
        assert _rel(w["length"][tag.name], length) < REL_TOL, (label, "whole", tag.name)
    assert w["untagged_interface_facets"] == 0 and w["untagged_boundary_facets"] == 0, label
    assert all(m["nodes_equal"].values()), (label, m["nodes_equal"])
    # an interface has 2 n + 1 nodes (open curve of n P2 edges) or 2 n (closed)
    for name in m["interfaces"]:
        tag, (a, b) = INTERFACES[name]
        n = m["counts"][a]["facets"][tag.name]
        assert n == m["counts"][b]["facets"][tag.name] == m["counts"]["whole"]["facets"][tag.name]
        closed = params.case == "shear" and name == "Gamma2"
        assert m["interface_nodes"][name] == 2 * n + (0 if closed else 1), (label, name)


# --------------------------------------------------------------------------- tests
@pytest.fixture(scope="module")
def measured():
    return {label: measure(make()) for label, make in CASES.items()}


@pytest.mark.mpi
@pytest.mark.parametrize("label", list(CASES))
def test_areas_lengths_tags(measured, label):
    check(label, CASES[label](), measured[label])


@pytest.mark.mpi
@pytest.mark.parametrize("label", list(VARIANTS))
def test_other_lengths(label):
    params = VARIANTS[label]()
    check(label, params, measure(params))


@pytest.mark.mpi
def test_interfaces_and_regions(measured):
    assert measured["shear_cell"]["interfaces"] == ["Gamma1", "Gamma2"]
    assert measured["shear_nocell"]["interfaces"] == ["Gamma1"]
    assert measured["normal_cell"]["interfaces"] == ["Gamma1", "Gamma3", "Gamma2"]
    assert measured["normal_nocell"]["interfaces"] == ["Gamma1", "Gamma3"]
    assert set(measured["shear_nocell"]["regions"]) == {"fluid", "gel"}
    assert "GAMMA2" not in measured["normal_nocell"]["counts"]["whole"]["facets"]


@pytest.mark.mpi
def test_cell_resolution(measured):
    """≥ 40 edges around the full circle (≥ 20 on the half cell); default 48."""
    assert measured["shear_cell"]["counts"]["cell"]["facets"]["GAMMA2"] >= 40
    assert measured["normal_cell"]["counts"]["cell"]["facets"]["GAMMA2"] >= 20


@pytest.mark.mpi
def test_mesh_size_factor():
    """size_factor 2 halves the number of edges on every tagged boundary (to ±1 edge)."""
    p = CaseParameters.default("normal")
    fine = build_meshes(p, regions=["cell"], whole=False).counts()["cell"]["facets"]
    coarse = build_meshes(p.with_mesh_size(2.0), regions=["cell"], whole=False).counts()["cell"]["facets"]
    for tag, n in fine.items():
        assert abs(coarse[tag] - n / 2) <= 1, (tag, n, coarse[tag])


@pytest.mark.mpi
def test_region_selection_and_missing_cell():
    dev = build_meshes(CaseParameters.default("shear", with_cell=False), regions=["gel"], whole=False)
    assert dev.regions == ["gel"] and dev.whole is None
    with pytest.raises(KeyError):
        dev.region("cell")
    with pytest.raises(KeyError):
        build_meshes(CaseParameters.default("shear", with_cell=False), regions=["cell"])


@pytest.mark.mpi
def test_xdmf_roundtrip(tmp_path_factory):
    """write_xdmf files read back with the same number of cells and tags."""
    directory = MPI.COMM_WORLD.bcast(str(tmp_path_factory.mktemp("xdmf")), root=0)
    dev = build_meshes(CaseParameters.default("normal"))
    counts = dev.counts()
    paths = dev.write_xdmf(directory)
    assert sorted(os.path.basename(p) for p in paths) == ["cell.xdmf", "fluid.xdmf", "gel.xdmf",
                                                          "whole.xdmf"]
    for name in ("gel", "whole"):
        with io.XDMFFile(MPI.COMM_WORLD, os.path.join(directory, f"{name}.xdmf"), "r") as xf:
            msh = xf.read_mesh(name="mesh")
            msh.topology.create_connectivity(1, 2)
            ft = xf.read_meshtags(msh, name="facet_tags")
        assert msh.geometry.cmap.degree == 2
        assert msh.topology.index_map(2).size_global == counts[name]["cells"]
        n = MPI.COMM_WORLD.allreduce(np.count_nonzero(
            ft.values[ft.indices < msh.topology.index_map(1).size_local] == Tag.GAMMA2), op=MPI.SUM)
        assert n == counts[name]["facets"]["GAMMA2"]


@pytest.mark.skip_in_parallel
def test_two_ranks(measured):
    """The same meshes, areas, lengths and tags on 2 ranks as in serial."""
    from mpi_run import run_mpi
    par = run_mpi(os.path.abspath(__file__), 2)
    for label, m in par.items():
        check(label, CASES[label](), m)
        ser = measured[label]
        assert m["counts"] == ser["counts"], label
        for name, r in m["regions"].items():
            assert r["area"] == pytest.approx(ser["regions"][name]["area"], rel=1e-12)


@pytest.mark.skip_in_parallel
def test_cli_mesh(tmp_path):
    """``gelcell mesh shear --cell --out DIR`` writes the meshes and prints the counts."""
    out = tmp_path / "mesh_shear"
    proc = subprocess.run([sys.executable, "-m", "gelcell.cli", "mesh", "shear", "--cell",
                           "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    files = sorted(os.listdir(out))
    for name in ("fluid", "gel", "cell", "whole"):
        assert f"{name}.xdmf" in files and f"{name}.h5" in files
    counts = json.loads((out / "counts.json").read_text())
    assert counts["cell"]["facets"]["GAMMA2"] == 48
    line = next(ln for ln in proc.stdout.splitlines() if ln.split()[:1] == ["GAMMA2"])
    assert line.split()[1:] == [str(int(Tag.GAMMA2)), "-", str(counts["gel"]["facets"]["GAMMA2"]),
                                str(counts["cell"]["facets"]["GAMMA2"]),
                                str(counts["whole"]["facets"]["GAMMA2"])]
    assert json.loads((out / "parameters.json").read_text())["case"] == "shear"
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".tmp")]


if __name__ == "__main__":      # run by test_two_ranks under mpirun
    result = {label: measure(make()) for label, make in CASES.items()}
    if MPI.COMM_WORLD.rank == 0:
        print(json.dumps(result))
