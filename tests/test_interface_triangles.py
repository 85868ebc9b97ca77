"""The P2 triangles of a 3D interface (femtools.interface.InterfaceNodes.triangles).

Reference: dolfinx's own integrals over the same tagged facets (the same isoparametric
surface), on 1 and 2 ranks.
"""

from __future__ import annotations

import numpy as np
import pytest

from mpi4py import MPI

import ufl
from dolfinx import fem

import coupling as cp
from cell.meshes import BOUNDARY, PLANE_Z, ball, disk
from femtools.interface import InterfaceNodes


def dolfinx_integral(msh, tags, tag, integrand) -> float:
    ds = ufl.Measure("ds", domain=msh, subdomain_data=tags)
    local = fem.assemble_scalar(fem.form(integrand(ufl.SpatialCoordinate(msh)) * ds(tag)))
    return msh.comm.allreduce(local, op=MPI.SUM)


@pytest.fixture(scope="module")
def half_ball():
    """A half ball of radius 0.5 cut by z = 0 (P2 geometry): a curved and a flat interface."""
    return ball(0.5, 0.2, planes=(2,))


@pytest.mark.parametrize("tag", [BOUNDARY, PLANE_Z])
def test_the_triangles_integrate_like_dolfinx_over_the_same_facets(half_ball, tag):
    msh, tags = half_ball
    nodes = InterfaceNodes(fem.VectorFunctionSpace(msh, ("CG", 2)), tags, tag)
    tri = nodes.triangles()
    n_facets = msh.comm.allreduce(int(np.sum(tags.indices[tags.values == tag] < msh.topology.index_map(2).size_local)),
                                  op=MPI.SUM)
    assert tri.shape == (n_facets, 6)
    M = cp.surface_mass_matrix(nodes.points, tri)          # also checks every node is in a triangle
    x, ones = nodes.points, np.ones(nodes.size)
    # the same P2 surface, integrated by two degree-4 rules: equal to the rules' error on |J|
    assert ones @ M @ ones == pytest.approx(dolfinx_integral(msh, tags, tag, lambda X: 1.0), rel=1e-6)
    assert ones @ M @ x[:, 0] == pytest.approx(dolfinx_integral(msh, tags, tag, lambda X: X[0]), abs=1e-6)
    assert x[:, 0] @ M @ x[:, 0] == pytest.approx(dolfinx_integral(msh, tags, tag, lambda X: X[0] ** 2), rel=1e-6)


def test_a_planar_interface_has_no_triangles():
    msh, tags = disk(0.5, 0.2)
    nodes = InterfaceNodes(fem.VectorFunctionSpace(msh, ("CG", 2)), tags, BOUNDARY)
    with pytest.raises(ValueError, match="interface triangles need a P2 space on tetrahedra"):
        nodes.triangles()
