"""The Gamma1 (Gamma3, ...) profiles of a run: v_f and u_s along each fluid-gel interface, as HDF5 and CSV.

In 3D the profiles are the interface's line at mid-height z = H/2, with Z,
v_fz and u_sz columns (``gelcell.post.quantities.gamma_profiles``).
"""

from __future__ import annotations

import csv
import os

import h5py

from mpi4py import MPI

from gelcell.post.fields import DeviceFields
from gelcell.post.quantities import gamma_profiles

__all__ = ["write_profiles"]


def write_profiles(directory: str, fields: DeviceFields, comm: MPI.Comm) -> dict[str, dict]:
    """gamma1_profiles.h5/.csv (and gamma3_* for the normal-flow device), paper units; the columns of
    :func:`gamma_profiles` (3D: X, Y, Z, v_fx, v_fy, v_fz, u_sx, u_sy, u_sz on the mid-height line)."""
    names = list(fields.layout.fluid_interfaces)
    out = {}
    for name in names:
        prof = gamma_profiles(fields, name)
        out[name] = prof
        if comm.rank == 0:
            stem = os.path.join(directory, f"{name.lower()}_profiles")
            with h5py.File(stem + ".h5", "w") as h5:
                if "Z" in prof:
                    h5.attrs["units"] = "X, Y, Z in L0; v_f in V0; u_s in L0 (paper's dimensionless units)"
                    h5.attrs["section"] = f"the interface's line at mid-height z = {prof['Z'][0]:.12g}"
                else:
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
