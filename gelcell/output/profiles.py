"""The Gamma1 (Gamma3, ...) profiles of a run: v_f and u_s along each fluid-gel interface, as HDF5 and CSV."""

from __future__ import annotations

import csv
import os

import h5py

from mpi4py import MPI

from gelcell.post.fields import DeviceFields
from gelcell.post.quantities import gamma_profiles

__all__ = ["write_profiles"]


def write_profiles(directory: str, fields: DeviceFields, comm: MPI.Comm) -> dict[str, dict]:
    """gamma1_profiles.h5/.csv (and gamma3_* for the normal-flow device), paper units."""
    names = list(fields.layout.fluid_interfaces)
    out = {}
    for name in names:
        prof = gamma_profiles(fields, name)
        out[name] = prof
        if comm.rank == 0:
            stem = os.path.join(directory, f"{name.lower()}_profiles")
            with h5py.File(stem + ".h5", "w") as h5:
                h5.attrs["units"] = "X, Y in L0; v_f in V0; u_s in L0 (paper's dimensionless units)"
                h5.attrs["case"] = fields.params.case
                for key, values in prof.items():
                    h5.create_dataset(key, data=values)
            with open(stem + ".csv", "w", newline="") as f:
                w = csv.writer(f)
                w.writerow(list(prof))
                for row in zip(*prof.values()):
                    w.writerow([f"{v:.12e}" for v in row])
    return out
