"""Frames of a time-dependent run: every field at a window, written whole, in a partition-independent order.

The frames are kept in ``DIR.partial/frames/`` while the run goes on and
written into the XDMF files at its end (:mod:`gelcell.run.transient_case`).
"""

from __future__ import annotations

import io
import os

import numpy as np

from mpi4py import MPI

from coupling.serialization import write_bytes
from femtools.canonical import CanonicalOrder
from gelcell.post.fields import DeviceFields

__all__ = ["FRAMES_DIR", "write_frame", "read_frame"]

#: the frames of a run in its ``DIR.partial/``
FRAMES_DIR = "frames"


# ----------------------------------------------------------------------------- frames
def _frame_functions(fields: DeviceFields) -> dict:
    out = {"fluid_velocity": fields.fluid_velocity, "fluid_pressure": fields.fluid_pressure,
           "interstitial_velocity": fields.interstitial_velocity, "displacement": fields.displacement,
           "pore_pressure": fields.pore_pressure}
    if fields.cell_displacement is not None:
        out["cell_displacement"] = fields.cell_displacement
    if fields.fluid_mesh_displacement is not None:
        out["fluid_mesh_displacement"] = fields.fluid_mesh_displacement
    return out


_ORDERS: dict = {}


def _order(f) -> CanonicalOrder:
    key = id(f.function_space)
    if key not in _ORDERS:
        _ORDERS[key] = (f.function_space, CanonicalOrder(f.function_space))
    return _ORDERS[key][1]


def write_frame(directory: str, index: int, fields: DeviceFields, comm: MPI.Comm) -> None:
    """Every field in the partition-independent order, ``frame_{index:05d}.npz`` (rank 0, written whole)."""
    arrays = {k: _order(f).gather(f.x.array) for k, f in _frame_functions(fields).items()}
    failed = None                       # an OSError of rank 0 (a full disk), raised on every rank
    if comm.rank == 0:
        path = os.path.join(directory, f"frame_{index:05d}.npz")
        try:
            os.makedirs(directory, exist_ok=True)
            buffer = io.BytesIO()       # built in memory: a failed write leaves no half archive behind
            np.savez(buffer, **arrays)
            write_bytes(path + ".tmp", buffer.getbuffer())
            os.replace(path + ".tmp", path)
        except OSError as exc:
            failed = (exc.errno, exc.strerror or str(exc), exc.filename or path + ".tmp")
            if os.path.exists(path + ".tmp"):
                os.remove(path + ".tmp")
    failed = comm.bcast(failed, root=0)
    if failed is not None:
        raise OSError(*failed)


def read_frame(directory: str, index: int, fields: DeviceFields, comm: MPI.Comm) -> None:
    """Load a frame written by :func:`write_frame` into ``fields`` (any partition)."""
    with np.load(os.path.join(directory, f"frame_{index:05d}.npz")) as data:
        for key, f in _frame_functions(fields).items():
            f.x.array[:] = _order(f).scatter(data[key])
