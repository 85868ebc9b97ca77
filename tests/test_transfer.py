"""femtools.transfer.NodalTransfer from a space on a process group to a space on the world.

The source lives on a sub-communicator (the first half of the ranks, rounded
up, like a group of ``coupling.Distribution``: on 2 ranks groups of 1 + 1, on
3 of 2 + 1) and is
``None`` on the other ranks; the copy on the world mesh must equal the same
expression evaluated there.  On one rank the group is the world.
"""

from __future__ import annotations

import numpy as np
import pytest

from mpi4py import MPI

from dolfinx import fem, mesh

from femtools.transfer import NodalTransfer


def _group(world: MPI.Comm):
    """The communicator of the first half of the ranks (None on the others) and the split one (to free)."""
    inside = world.rank < (world.size + 1) // 2
    group = world.Split(0 if inside else 1, world.rank)
    return (group if inside else None), group


def _square(comm, side: float = 1.0):
    return mesh.create_rectangle(comm, [np.zeros(2), np.array([side, side])], [6, 5])


@pytest.mark.mpi
@pytest.mark.parametrize("shape", [None, (2,)], ids=["scalar", "vector"])
def test_group_field_copied_onto_the_world_mesh(shape):
    world = MPI.COMM_WORLD
    group, split = _group(world)
    expression = lambda x: x[0] + 2 * x[1]  # noqa: E731

    def space(msh):
        kind = fem.FunctionSpace if shape is None else fem.VectorFunctionSpace
        return kind(msh, ("Lagrange", 2))

    def fill(V):
        f = fem.Function(V)
        f.interpolate(expression if shape is None else (lambda x: np.vstack([expression(x), -3 * expression(x)])))
        return f

    src = fill(space(_square(group))) if group is not None else None
    V = space(_square(world))
    copy = NodalTransfer(None if src is None else src.function_space, V, comm=world).apply(src, fem.Function(V))
    error = world.allreduce(np.abs(copy.x.array - fill(V).x.array).max(initial=0.0), op=MPI.MAX)
    assert world.allreduce(copy.x.array.size, op=MPI.SUM) > 0
    assert error <= 1e-14
    split.Free()


@pytest.mark.mpi
def test_missing_source_node_is_raised_on_every_rank():
    world = MPI.COMM_WORLD
    group, split = _group(world)
    src = fem.FunctionSpace(_square(group), ("Lagrange", 2)) if group is not None else None
    V = fem.FunctionSpace(_square(world, side=2.0), ("Lagrange", 2))      # nodes outside the source's square
    with pytest.raises(ValueError, match="no source node within"):
        NodalTransfer(src, V, comm=world)
    split.Free()
