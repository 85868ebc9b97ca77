"""timeseries.csv and timeseries.h5 of a time-dependent run: one row of quantities per window."""

from __future__ import annotations

import csv
import os

import h5py
import numpy as np

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.post.quantities import DeviceQuantities

__all__ = ["COLUMNS", "write_timeseries"]

#: the columns of timeseries.csv / timeseries.h5
COLUMNS = ("t", "inflow") + DeviceQuantities.TIMESERIES + ("iterations", "residual")


def write_timeseries(directory: str, rows: list[dict], params: CaseParameters, comm: MPI.Comm) -> None:
    if comm.rank != 0:
        return
    # a 3D centroid_z and, with several cells, each cell's columns after the common ones
    columns = COLUMNS + tuple(c for c in rows[-1] if c not in COLUMNS and c.startswith(("cell_", "centroid_")))
    data = {c: np.array([r.get(c, np.nan) for r in rows], dtype=float) for c in columns}
    with open(os.path.join(directory, "timeseries.csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for k in range(len(rows)):
            w.writerow([f"{data[c][k]:.12e}" if c not in ("iterations",) else int(data[c][k]) for c in columns])
    with h5py.File(os.path.join(directory, "timeseries.h5"), "w") as h5:
        h5.attrs["units"] = ("paper's dimensionless units: t in L0/V0, lengths in L0, velocities in V0, "
                             "stresses in mu_s; strains dimensionless")
        h5.attrs["time_unit_s"] = params.scale("time")
        h5.attrs["case"] = params.case
        for c in columns:
            h5.create_dataset(c, data=data[c])
