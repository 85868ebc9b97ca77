"""Small time-dependent device runs for the tests (coarse meshes, no output files)."""

from __future__ import annotations

import numpy as np

from mpi4py import MPI

from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.device import Device
from gelcell.case import CaseParameters
from gelcell.case import time_scales, TimeSettings
from gelcell.output.timeseries import COLUMNS
from gelcell.run.backends import MonolithicBackend, PartitionedBackend
from gelcell.run.transient import TransientRun

#: every element size x3: the test-sized meshes of the coupling study
MESH_SIZE = 3.0


def case(name: str = "shear", cell: bool = True, mesh_size: float = MESH_SIZE) -> CaseParameters:
    return CaseParameters.default(name, with_cell=cell).with_mesh_size(mesh_size)


def tau(params: CaseParameters) -> float:
    return time_scales(params)["consolidation"]


def backend(params: CaseParameters, settings: TimeSettings, monolithic: bool = False,
            acceleration: str = "iqn-ils", comm=MPI.COMM_WORLD, **coupling):
    if monolithic:
        return MonolithicBackend(params, comm, settings.scheme, settings.waveform)
    device = Device(params, comm, transient=True, time_scheme=settings.scheme, inflow=settings.waveform)
    config = coupling_config(acceleration=acceleration, with_cell=params.with_cell, transient=True)
    config.update(verbose=False, **coupling)
    return PartitionedBackend(device, config, comm)


def run(params: CaseParameters, monolithic: bool = False, acceleration: str = "iqn-ils", **time) -> dict:
    """Run from rest; returns ``{"rows": ..., "series": {column: array}, "run": TransientRun}``."""
    settings = TimeSettings(transient=True, **time)
    run = TransientRun(backend(params, settings, monolithic, acceleration), params, settings, MPI.COMM_WORLD)
    state = run.run()
    series = {c: np.array([r[c] for r in state["rows"]], dtype=float) for c in COLUMNS}
    return {"rows": state["rows"], "series": series, "run": run, "state": state}
