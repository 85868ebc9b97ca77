"""Nothing of a field's size is gathered onto one rank or onto every rank (issue 30, item 4).

A steady device run with the linearized prior, on any number of ranks: every object the
field solvers' interface Jacobians gather (``femtools.linalg.GATHERED``: condensed matrices,
interface rows of the data matrices, interface entries of scale vectors) has at most as many
rows and columns as the coupling data have values, which are replicated anyway (the
Participant API takes (N, dim) arrays); the fields' own matrices are many times larger.  The
mesh partitioner gathers the dual graph on rank 0 only (``femtools.mesh.DUAL_GRAPHS``).
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from dolfinx import mesh as dmesh

from femtools import linalg
from femtools import mesh as fmesh
from gelcell.case import CaseParameters
from gelcell.run.solve import solve_partitioned

COMM = MPI.COMM_WORLD


def test_the_prior_gathers_interface_sized_objects_only(monkeypatch):
    monkeypatch.setenv("GELCELL_PRIOR_CACHE", "0")            # compute the prior, do not load it
    monkeypatch.setattr(linalg, "GATHERED", [])
    p = CaseParameters.default("shear", True).with_mesh_size(3.0)
    run = solve_partitioned(p, verbose=False, checks=False,
                            coupling={"acceleration": {"jacobian_prior": "linearized"}})
    assert run.summary["coupling"]["converged"]
    assert run.summary["coupling"]["prior_source"] == "computed"
    scheme = run.solver.scheme
    interface = sum(int(np.prod(v.shape)) for v in scheme.values.values())
    gathered = linalg.GATHERED
    assert {what for what, *_ in gathered} >= {"schur", "submatrix", "entries"}     # gel, fluid and cell built
    assert all(rows <= interface and cols <= interface for _, rows, cols, _ in gathered), (interface, gathered)
    # the bound separates: the gel's system (once gathered whole to rank 0) is larger
    assert max(A.getSize()[0] for A in _field_matrices(run)) > interface


def _field_matrices(run):
    """The Newton matrix of each field solver that has one (gel, cell): the size of its global system."""
    out = []
    for participant in run.solver.participants:
        solver = getattr(participant, "solver", None)
        newton = getattr(solver, "_newton", None)
        if newton is not None:
            out.append(newton.A)
    return out


def test_the_partitioner_gathers_the_dual_graph_on_rank_0_only(monkeypatch):
    monkeypatch.setattr(fmesh, "DUAL_GRAPHS", [])
    corners = [np.array([0.0, 0.0]), np.array([2.0, 1.0])]
    msh = dmesh.create_rectangle(COMM, corners, [12, 6], dmesh.CellType.triangle, partitioner=fmesh.PARTITIONER)
    cells = msh.topology.index_map(2).size_global
    expected = [(cells, 3 * cells - 2 * (12 + 6))] if COMM.rank == 0 else []    # interior facets, twice
    assert fmesh.DUAL_GRAPHS == expected
