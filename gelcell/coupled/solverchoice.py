"""Which linear solver each field of a device uses: ``[solver] kind`` ("direct", "iterative" or "auto").

``direct``: MUMPS (``femtools.linalg.DirectSolver``) for every field;
``iterative``: the Krylov solvers with multigrid of ``femtools.krylov`` for
every field (the fluid's mesh motion follows the fluid); ``auto``: per field,
direct on a 2D mesh and on a 3D mesh with at most
:data:`AUTO_ITERATIVE_MIN_UNKNOWNS` unknowns, iterative above.  The unknowns
are counted from the mesh before the field's solver is built (P2 nodes =
vertices + edges, P1 nodes = vertices): the fluid gdim P2 + P1 (Taylor-Hood),
the gel 2 gdim P2 + P1 (w, u, p), the cell gdim P2.

The threshold.  In 2D the direct path is the faster at every size measured
(benchmarks/krylov_fields.py: 6-17x at 2.5k-36k unknowns per field), and a 2D
device's fields stay far below the sizes where MUMPS's fill hurts (issue 30:
762k unknowns in 15.7 s and 2.4 GB), so auto is direct in 2D.  In 3D
(benchmarks/solver_auto_3d.py, P2 elasticity on a cube, 6.6k-152k unknowns)
the direct path is still 6.4-8.6x faster, the ratio falling only slowly
(~N^-0.07 at the finest step): time does not favour the Krylov path at the
sizes measured.  Memory does: MUMPS's factorisation takes 43, 335,
1279 MB at 6.6k, 28k, 73k unknowns (N^1.38, the N^(4/3) fill of a 3D
mesh), so ~2 GB at 100k, and a device factorises four such systems (fluid,
its mesh motion, gel, cell) within the issue's 12 GB aim up to about there;
above it the iterative path's O(N) memory is the one that fits.

PETSc options per field (``[solver.petsc.FIELD]``) go to that field's solver:
on the direct path on top of the device's MUMPS options of a steady run
(:data:`~gelcell.coupled.defaults.STEADY_SOLVER_OPTIONS`), on the iterative
path alone (MUMPS options mean nothing to a Krylov solver).
"""

from __future__ import annotations

import typing

from gelcell.coupled.defaults import STEADY_SOLVER_OPTIONS

__all__ = ["AUTO_ITERATIVE_MIN_UNKNOWNS", "field_unknowns", "choose", "field_options", "FIELDS", "KINDS"]

#: the values of ``solver.kind`` (gelcell.case.SOLVER_KINDS)
KINDS = ("direct", "iterative", "auto")

#: the fields of a device, in the order they are built
FIELDS = ("fluid", "gel", "cell")

#: auto: a field of a 3D device with more unknowns than this is solved iteratively (MUMPS would need
#: more than ~2 GB for it; module docstring)
AUTO_ITERATIVE_MIN_UNKNOWNS = 100_000

#: per field: (P2 vector fields, P1 scalar fields) of its unknowns
_SPACES = {"fluid": (1, 1), "gel": (2, 1), "cell": (1, 0)}


def field_unknowns(mesh, field: str) -> int:
    """The global number of unknowns of ``field``'s solver on ``mesh`` (P2 and P1 Lagrange nodes)."""
    topology, gdim = mesh.topology, mesh.geometry.dim
    topology.create_entities(1)                        # the edges: P2 builds them anyway
    vertices = topology.index_map(0).size_global
    p2 = vertices + topology.index_map(1).size_global
    vectors, scalars = _SPACES[field]
    return int(vectors * gdim * p2 + scalars * vertices)


def choose(kind: str, mesh, field: str) -> str:
    """``"direct"`` or ``"iterative"`` for ``field`` on ``mesh`` under ``solver.kind = kind``."""
    if kind != "auto":
        return kind
    if mesh.geometry.dim < 3:
        return "direct"
    return "iterative" if field_unknowns(mesh, field) > AUTO_ITERATIVE_MIN_UNKNOWNS else "direct"


def field_options(chosen: str, transient: bool, user: typing.Mapping | None) -> dict | None:
    """The ``petsc_options`` of a field solver: MUMPS's for a steady direct solve, then the user's."""
    base = dict(STEADY_SOLVER_OPTIONS) if chosen == "direct" and not transient else {}
    options = {**base, **dict(user or {})}
    return options or None
