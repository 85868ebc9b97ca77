"""femtools.xdmf: the fields it writes are those dolfinx's own XDMF writer writes (the reference).

On a curved (degree-2) mesh of a disc with a hole, on 1 and 2 ranks: a P2
vector field, a P2 scalar, a P1 scalar (interpolated to the geometry nodes)
and a collapsed sub-function, at two times.  The XML file names every dataset
with its shape and time, and the datasets equal dolfinx's to round-off (the
interpolation of the P1 field) or exactly (a reordering).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import h5py
import numpy as np
import pytest
import ufl

from mpi4py import MPI

from dolfinx import fem, io

from femtools.mesh import model_to_mesh
from femtools.xdmf import NodalXDMF


def _curved_mesh(comm):
    import gmsh
    gmsh.initialize(["-nt", "1"])
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        if comm.rank == 0:
            gmsh.model.occ.addDisk(0, 0, 0, 1, 1, 1)
            gmsh.model.occ.addDisk(0.2, 0.1, 0, 0.3, 0.3, 2)
            gmsh.model.occ.cut([(2, 1)], [(2, 2)])
            gmsh.model.occ.synchronize()
            gmsh.model.addPhysicalGroup(2, [s for _, s in gmsh.model.getEntities(2)], 1)
            gmsh.option.setNumber("Mesh.MeshSizeMax", 0.15)
            gmsh.model.mesh.generate(2)
            gmsh.model.mesh.setOrder(2)
        msh, _, _ = model_to_mesh(gmsh.model, comm, 0)
    finally:
        gmsh.finalize()
    return msh


def _fields(msh):
    x = ufl.SpatialCoordinate(msh)
    W = fem.FunctionSpace(msh, ufl.MixedElement([ufl.VectorElement("Lagrange", msh.ufl_cell(), 2),
                                                 ufl.FiniteElement("Lagrange", msh.ufl_cell(), 1)]))
    w = fem.Function(W)
    w.sub(0).interpolate(lambda p: np.vstack([p[0] ** 2 - p[1], np.sin(3 * p[1])]))
    w.sub(1).interpolate(lambda p: np.cos(2 * p[0]) + p[1] ** 3)
    u = w.sub(0).collapse()
    u.name = "u"
    p = w.sub(1).collapse()
    p.name = "p1"
    s = fem.Function(fem.FunctionSpace(msh, ("Lagrange", 2)), name="s")
    s.interpolate(lambda q: q[0] * q[1] + np.exp(q[0]))
    v = fem.Function(u.function_space, name="v")
    v.interpolate(lambda q: np.vstack([-q[1] ** 3, q[0] * q[1]]))
    assert x is not None
    return [u, p, s, v]


def _datasets(path):
    root = ET.parse(str(path) + ".xdmf").getroot()
    out = {}
    with h5py.File(str(path) + ".h5", "r") as h5:
        for grid in root.iter("Grid"):
            if grid.get("GridType") != "Uniform" or grid.find("Attribute") is None:
                continue
            attribute = grid.find("Attribute")
            item = attribute.find("DataItem")
            rows, columns = (int(k) for k in item.get("Dimensions").split())
            file, dataset = item.text.strip().split(":")
            assert file == path.name + ".h5"
            data = h5[dataset][...]
            assert data.shape == (rows, columns)
            out[(attribute.get("Name"), float(grid.find("Time").get("Value")))] = (attribute.get("AttributeType"),
                                                                                  data)
        geometry = h5["/Mesh/mesh/geometry"][...]
    return out, geometry


def test_nodal_xdmf_writes_what_dolfinx_writes(shared_tmp_path):
    comm = MPI.COMM_WORLD
    msh = _curved_mesh(comm)
    assert msh.geometry.cmap.degree == 2
    fields = _fields(msh)
    ours, reference = shared_tmp_path / "ours", shared_tmp_path / "dolfinx"
    writer = NodalXDMF(str(ours) + ".xdmf", msh)
    with io.XDMFFile(comm, str(reference) + ".xdmf", "w") as xf:
        xf.write_mesh(msh)
        for t in (0.0, 2.5e-6):
            for f in fields:
                xf.write_function(f, t)
            writer.write(fields, t)
            for f in fields:            # the second time holds other values
                f.x.array[:] *= 2.0
    comm.Barrier()
    if comm.rank == 0:
        got, x_got = _datasets(ours)
        want, x_want = _datasets(reference)
        assert np.array_equal(x_got, x_want)
        assert sorted(got) == sorted(want) and len(got) == 8
        for key, (kind, data) in want.items():
            assert got[key][0] == kind, key
            tolerance = 1e-12 * np.abs(data).max()         # the P1 field is interpolated to the P2 nodes
            np.testing.assert_allclose(got[key][1], data, rtol=0, atol=tolerance, err_msg=str(key))
        assert want[("u", 2.5e-6)][1] == pytest.approx(2 * want[("u", 0.0)][1])


def test_nodal_xdmf_refuses_what_it_cannot_write(tmp_path):
    from dolfinx import mesh
    a = mesh.create_unit_square(MPI.COMM_SELF, 2, 2)
    b = mesh.create_unit_square(MPI.COMM_SELF, 2, 2)
    writer = NodalXDMF(str(tmp_path / f"a{MPI.COMM_WORLD.rank}.xdmf"), a)
    with pytest.raises(ValueError, match="not a function on this file's mesh"):
        writer.nodal_values(fem.Function(fem.FunctionSpace(b, ("Lagrange", 1)), name="f"))
    with pytest.raises(ValueError, match="only scalar and vector fields are written, not 4 components"):
        writer.nodal_values(fem.Function(fem.TensorFunctionSpace(a, ("Lagrange", 1)), name="stress"))


def test_nodal_average_of_a_cellwise_expression_is_partition_independent():
    """femtools.functions.NodalAverage on 1 and 2 ranks (the same mesh on each rank alone as the reference).

    A continuous expression comes out as its P2 interpolant (exactly); the
    cellwise gradient of a P2 field, discontinuous between cells, comes out as
    the mean over the cells around each node: the value at the centre node of
    the unit square (8 cells meet there in this diagonal mesh) is checked
    against that mean computed by hand, and the field does not depend on the
    partition.
    """
    from dolfinx import mesh

    from femtools.functions import NodalAverage

    def solve(comm):
        msh = mesh.create_unit_square(comm, 4, 4)
        V = fem.FunctionSpace(msh, ("Lagrange", 2))
        x = ufl.SpatialCoordinate(msh)
        g = fem.Function(V)
        g.interpolate(lambda p: np.sin(3 * p[0]) * p[1] ** 2 + p[0] ** 3)
        points = V.element.interpolation_points()
        average = NodalAverage(V)
        smooth = average(fem.Expression(x[0] * x[1] ** 2, points), fem.Function(V))
        exact = fem.Function(V)
        exact.interpolate(lambda p: p[0] * p[1] ** 2)
        assert np.allclose(smooth.x.array, exact.x.array, rtol=0, atol=1e-14)
        rough = average(fem.Expression(g.dx(0), points), fem.Function(V))
        n_owned = V.dofmap.index_map.size_local
        xs = V.tabulate_dof_coordinates()[:n_owned, :2]
        gathered = comm.gather((xs, rough.x.array[:n_owned]), root=0)
        if comm.rank != 0:
            return None
        xs, values = (np.concatenate(a) for a in zip(*gathered))
        key = np.round(xs, 10)      # dof coordinates differ by round-off between partitions
        order = np.lexsort((key[:, 1], key[:, 0]))
        return xs[order], values[order]

    reference = solve(MPI.COMM_SELF)
    ours = solve(MPI.COMM_WORLD)
    if MPI.COMM_WORLD.rank == 0:
        np.testing.assert_allclose(ours[0], reference[0], rtol=0, atol=1e-14)
        np.testing.assert_allclose(ours[1], reference[1], rtol=0, atol=1e-12 * np.abs(reference[1]).max())
        # at (0.5, 0.5): d/dx of the P2 interpolant, one-sided in each of the cells around it
        centre = np.flatnonzero(np.all(np.isclose(reference[0], 0.5), axis=1))[0]
        assert abs(reference[1][centre] - _mean_of_cellwise_dx_at_centre()) < 1e-12


def _mean_of_cellwise_dx_at_centre() -> float:
    """The mean over the cells around (0.5, 0.5) of d/dx of the P2 interpolant there (serial, by hand)."""
    from dolfinx import mesh
    from dolfinx.geometry import BoundingBoxTree, compute_collisions, compute_colliding_cells

    msh = mesh.create_unit_square(MPI.COMM_SELF, 4, 4)
    V = fem.FunctionSpace(msh, ("Lagrange", 2))
    g = fem.Function(V)
    g.interpolate(lambda p: np.sin(3 * p[0]) * p[1] ** 2 + p[0] ** 3)
    D = fem.FunctionSpace(msh, ("DG", 1))
    dx = fem.Function(D)
    dx.interpolate(fem.Expression(g.dx(0), D.element.interpolation_points()))
    point = np.array([[0.5, 0.5, 0.0]])
    tree = BoundingBoxTree(msh, 2)
    cells = compute_colliding_cells(msh, compute_collisions(tree, point), point).links(0)
    assert len(cells) >= 4
    return float(np.mean([dx.eval(point, np.array([c], dtype=np.int32))[0] for c in cells]))
