"""Output that is written whole or not at all."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import typing

import numpy as np

from mpi4py import MPI

__all__ = ["atomic_path", "write_json", "atomic_directory"]


@contextlib.contextmanager
def _commit(tmp: str, path: str, comm: MPI.Comm, directory: bool):
    """Move ``tmp`` to ``path`` if the block succeeded on every rank, else delete it."""
    ok = False
    try:
        yield
        ok = True
    finally:
        ok = comm.allreduce(ok, op=MPI.LAND)
        comm.Barrier()
        if comm.rank == 0:
            if ok:
                os.chmod(tmp, 0o755 if directory else 0o644)  # mkdtemp/mkstemp make them private
                if directory and os.path.isdir(path):
                    shutil.rmtree(path)
                os.replace(tmp, path)
            elif directory:
                shutil.rmtree(tmp, ignore_errors=True)
            elif os.path.exists(tmp):
                os.remove(tmp)


@contextlib.contextmanager
def atomic_path(path: str, comm: MPI.Comm = MPI.COMM_WORLD):
    """Yield a temporary path next to ``path``; rename it to ``path`` on success.

    Rank 0 chooses the name; every rank may write to it (e.g. XDMF/HDF5 in
    parallel).  On an exception the temporary file is removed and ``path``
    is left untouched.
    """
    path = os.path.abspath(path)
    tmp = None
    if comm.rank == 0:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.basename(path),
                                   dir=os.path.dirname(path))
        os.close(fd)
    tmp = comm.bcast(tmp, root=0)
    with _commit(tmp, path, comm, directory=False):
        yield tmp


def _promote(work: str, path: str) -> None:
    """Replace ``path`` by ``work``: the old results aside, the new ones in, then the old ones deleted."""
    old = None
    if os.path.exists(path):
        old = tempfile.mkdtemp(prefix=".old-" + os.path.basename(path) + "-", dir=os.path.dirname(path))
        os.rmdir(old)
        os.replace(path, old)
    os.replace(work, path)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_directory(path: str, comm: MPI.Comm = MPI.COMM_WORLD, partial: bool = False):
    """Yield a temporary directory; on success it replaces ``path`` as a whole.

    ``partial=True``: the working directory is the fixed sibling
    ``path + ".partial"`` (created if missing, reused if present, e.g. to
    resume an interrupted run from the checkpoint it holds); it is kept on
    failure or interruption and promoted to ``path`` on success.
    """
    path = os.path.abspath(path)
    if partial:
        work = path + ".partial"
        if comm.rank == 0:
            os.makedirs(work, exist_ok=True)
        comm.Barrier()
        ok = False
        try:
            yield work
            ok = True
        finally:
            ok = comm.allreduce(ok, op=MPI.LAND)
            comm.Barrier()
            if ok and comm.rank == 0:
                _promote(work, path)
            comm.Barrier()
        return
    tmp = None
    if comm.rank == 0:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=".tmp-" + os.path.basename(path) + "-", dir=os.path.dirname(path))
    tmp = comm.bcast(tmp, root=0)
    with _commit(tmp, path, comm, directory=True):
        yield tmp


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def write_json(path: str, data: typing.Any, comm: MPI.Comm = MPI.COMM_WORLD) -> None:
    """Write ``data`` as JSON (rank 0), atomically; numpy types are converted."""
    with atomic_path(path, comm) as tmp:
        if comm.rank == 0:
            with open(tmp, "w") as f:
                json.dump(_jsonable(data), f, indent=2)
                f.write("\n")
