"""What a run cost: its unknowns per field and the process's peak memory (summary.json ``cost``).

Unknowns are global (owned degrees of freedom summed over the ranks, times
the block size), so 1 and 2 ranks report the same numbers.  Peak memory is
``ru_maxrss`` of each rank's process up to the moment it is read (the end of
the solve): the process's lifetime peak, so in a sweep the peak so far.
"""

from __future__ import annotations

import resource

from mpi4py import MPI

__all__ = ["space_unknowns", "device_unknowns", "monolithic_unknowns", "cost_summary"]


def space_unknowns(space) -> int:
    """Global number of degrees of freedom of a dolfinx function space (owned, summed over ranks)."""
    return space.dofmap.index_map.size_global * space.dofmap.index_map_bs


def device_unknowns(device) -> dict[str, int]:
    """``{field: unknowns}`` of a partitioned :class:`~gelcell.coupled.device.Device`.

    ``fluid``: velocity and pressure; ``mesh_motion``: the fluid mesh's
    displacement (finite kinematics only); ``gel``: its mixed space; ``cell``
    (with a cell): its displacement.  Each is counted by its field's solver,
    on its process group if the device is distributed (the same numbers on
    every rank).
    """
    out = device._from_field("fluid", lambda: _fluid_unknowns(device.fluid))
    out["gel"] = device._from_field("gel", lambda: space_unknowns(device.gel.W))
    if device.params.with_cell:
        out["cell"] = device._from_field("cell", lambda: space_unknowns(device.cell.displacement.function_space))
    return out


def _fluid_unknowns(fluid) -> dict[str, int]:
    """``fluid`` and (with a moving mesh) ``mesh_motion`` of :func:`device_unknowns`."""
    out = {"fluid": space_unknowns(fluid.W)}
    mesh_space = getattr(fluid, "mesh_space", None)
    if mesh_space is not None:
        out["mesh_motion"] = space_unknowns(mesh_space)
    return out


def monolithic_unknowns(solver) -> dict[str, int]:
    """``{"monolithic": unknowns}``: the size of the monolithic reference's one mixed system."""
    return {"monolithic": space_unknowns(solver.W)}


def _peak_memory_mb() -> float:
    # Linux reports ru_maxrss in KiB
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cost_summary(unknowns: dict[str, int], comm: MPI.Comm) -> dict:
    """``cost`` of the summary: ``unknowns`` per field, ``peak_memory_mb`` (max over ranks) and per rank."""
    per_rank = comm.allgather(_peak_memory_mb())
    return {"unknowns": dict(unknowns), "peak_memory_mb": max(per_rank), "peak_memory_mb_per_rank": per_rank}

