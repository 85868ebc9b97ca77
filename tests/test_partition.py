"""Partition-independent runs: the deterministic partitioner and the canonical node order.

A resumed run must repeat the uninterrupted one to 1e-12 also under MPI; the
default partitioner of dolfinx 0.5.2 draws another partition in every
process, which changes round-off (measured 1e-11 between two 2-rank runs of
the same case), and a checkpoint of rank-local arrays cannot be read back on
another partition.
"""

from __future__ import annotations

import numpy as np
import pytest

from mpi4py import MPI

from dolfinx import fem
from dolfinx import mesh as dmesh

from femtools.mesh import PARTITIONER
from femtools.canonical import CanonicalOrder, MixedCanonical
from gelcell.geometry.meshes import build_meshes
from gelcell.case import CaseParameters

COMM = MPI.COMM_WORLD


def test_device_meshes_are_partitioned_the_same_way_every_time():
    p = CaseParameters.default("shear").with_mesh_size(3)
    counts = []
    for _ in range(2):
        msh, _ = build_meshes(p, COMM).region("gel")
        x = msh.geometry.x[: msh.geometry.index_map().size_local]
        counts.append((msh.topology.index_map(2).size_local, np.round(x, 12).tolist()))
    assert counts[0] == counts[1]
    sizes = COMM.allgather(counts[0][0])
    assert max(sizes) - min(sizes) <= 1            # equal bands


def _field(msh, degree=2):
    V = fem.VectorFunctionSpace(msh, ("Lagrange", degree))
    f = fem.Function(V)
    f.interpolate(lambda x: np.vstack([np.sin(3 * x[0]) + x[1], x[0] * x[1]]))
    return f


def test_canonical_order_is_independent_of_the_partition():
    """The same field on two partitions of one mesh gives the same canonical array,
    and scattering one partition's array into the other reproduces the field there."""
    corners = [np.array([0.0, 0.0]), np.array([2.0, 1.0])]
    a = _field(dmesh.create_rectangle(COMM, corners, [12, 6], dmesh.CellType.triangle))
    b = _field(dmesh.create_rectangle(COMM, corners, [12, 6], dmesh.CellType.triangle, partitioner=PARTITIONER))
    order_a, order_b = CanonicalOrder(a.function_space), CanonicalOrder(b.function_space)
    # tabulated P2 node coordinates carry cell-dependent rounding (~1e-16): the same order, not the same bits
    points_atol = 1e-14
    np.testing.assert_allclose(order_a.points, order_b.points, rtol=0, atol=points_atol)
    # so the interpolated values differ by up to |grad f| (<= 4 here) times that, plus their own
    # rounding (2.5 ulp of ~2 seen on one machine); a wrong order would differ by O(1)
    values_atol = 4 * points_atol + 1e-15
    canonical = order_a.gather(a.x.array)
    np.testing.assert_allclose(canonical, order_b.gather(b.x.array), rtol=0, atol=values_atol)
    np.testing.assert_allclose(order_b.scatter(canonical), b.x.array, rtol=0, atol=values_atol)
    # a P1 scalar field has its own node set and order
    Q = fem.FunctionSpace(a.function_space.mesh, ("Lagrange", 1))
    assert CanonicalOrder(Q).size < order_a.size


def test_mixed_canonical_round_trip():
    import ufl
    msh = dmesh.create_unit_square(COMM, 6, 6)
    P2 = ufl.VectorElement("Lagrange", msh.ufl_cell(), 2)
    P1 = ufl.FiniteElement("Lagrange", msh.ufl_cell(), 1)
    W = fem.FunctionSpace(msh, ufl.MixedElement([P2, P1]))
    w = fem.Function(W)
    w.x.array[:] = np.random.default_rng(COMM.rank).standard_normal(w.x.array.size)
    w.x.scatter_forward()
    mixed = MixedCanonical(W, ("v", "p"))
    arrays = mixed.gather(w.x.array)
    out = np.zeros_like(w.x.array)
    mixed.scatter(arrays, out)
    np.testing.assert_array_equal(out, w.x.array)


@pytest.mark.parametrize("comm_size_independent", [True])
def test_canonical_arrays_are_replicated(comm_size_independent):
    f = _field(dmesh.create_unit_square(COMM, 5, 5, partitioner=PARTITIONER))
    arr = CanonicalOrder(f.function_space).gather(f.x.array)
    gathered = COMM.allgather(arr)
    for other in gathered:
        np.testing.assert_array_equal(other, arr)
