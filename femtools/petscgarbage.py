"""Destroy the PETSc objects Python has dropped, while their meshes' communicators still exist.

petsc4py 3.18 does not destroy a PETSc object when its Python wrapper is
garbage-collected if the object lives on a communicator other than
``COMM_WORLD``/``COMM_SELF``: destruction is collective, and garbage
collection runs at different times on different ranks, so the object is put
on its communicator's garbage list, to be destroyed by the collective
``PETSc.garbage_cleanup(comm)``.  dolfinx gives every mesh a duplicate of the
communicator it was built on, and every solver's matrices, vectors and
factorisations live on it.  When the mesh goes, dolfinx frees that duplicate
and the garbage can no longer be reached (a cleanup then crashes): each
device solved would leave its factorisations behind, and a sweep or a study in
one process would grow without bound (docs/femtools-costs.md).

So the meshes built by :mod:`femtools.mesh` are kept here (:func:`keep`), and
:func:`collect`, at points every rank reaches together (building a device,
the end of a test), cleans their communicators' garbage and forgets the
meshes nothing else uses any more.
"""

from __future__ import annotations

import gc
import sys

from mpi4py import MPI
from petsc4py import PETSc

__all__ = ["keep", "collect"]

_kept: list[tuple[MPI.Comm, object]] = []       # (the communicator the mesh was built on, the mesh)


def keep(mesh, comm: MPI.Comm) -> None:
    """Keep ``mesh`` (hence its communicator) until :func:`collect` finds it unused elsewhere."""
    _kept.append((comm, mesh))


def collect(comm: MPI.Comm, collected: bool = False) -> None:
    """Collective over ``comm``: destroy the dropped PETSc objects of every kept mesh built on it (and
    on any one-rank communicator), then forget the meshes that nothing but this module references.
    ``collected``: the caller has just run ``gc.collect()``."""
    shared = [i for i, (c, _) in enumerate(_kept) if c == comm and c.Get_size() > 1]
    local = [i for i, (c, _) in enumerate(_kept) if c.Get_size() == 1]
    if not shared and not local:
        return
    if not collected:
        gc.collect()                               # wrappers in reference cycles: into the garbage lists
    for i in shared + local:
        PETSc.garbage_cleanup(_kept[i][1].comm)
    # references: the list's tuple, getrefcount's argument
    unused = [sys.getrefcount(_kept[i][1]) <= 2 for i in shared]
    if shared:
        unused = [all(flags) for flags in zip(*comm.allgather(unused))]   # the same decision on every rank
    unused += [sys.getrefcount(_kept[i][1]) <= 2 for i in local]
    drop = {i for i, u in zip(shared + local, unused) if u}
    _kept[:] = [entry for i, entry in enumerate(_kept) if i not in drop]
