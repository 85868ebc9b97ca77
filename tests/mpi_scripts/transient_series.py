"""A short time-dependent partitioned run (shear, coarse mesh); prints its time series as JSON (rank 0)."""
import json

from mpi4py import MPI

from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.device import Device
from gelcell.case import CaseParameters
from gelcell.case import time_scales, TimeSettings
from gelcell.output.timeseries import COLUMNS
from gelcell.run.backends import PartitionedBackend
from gelcell.run.transient import TransientRun

params = CaseParameters.default("shear").with_mesh_size(3.0)
tau = time_scales(params)["consolidation"]
settings = TimeSettings(transient=True, dt=tau / 20, t_end=4 * tau / 20, scheme="bdf2")
device = Device(params, MPI.COMM_WORLD, transient=True, time_scheme="bdf2", inflow=settings.waveform)
config = coupling_config(with_cell=True, transient=True)
config["verbose"] = False
state = TransientRun(PartitionedBackend(device, config, MPI.COMM_WORLD), params, settings, MPI.COMM_WORLD).run()
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps({c: [r[c] for r in state["rows"]] for c in COLUMNS if c not in ("iterations", "residual")}))
