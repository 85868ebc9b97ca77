"""The layer device as a 3D slab, partitioned; prints its errors, interface sums and iterations as JSON (rank 0)."""
import json
import sys

import numpy as np
from mpi4py import MPI

from gelcell.coupled.layer import LayerCase, LayerDevice

flow, n = sys.argv[1], int(sys.argv[2])
device = LayerDevice(LayerCase(flow), n=n, depth=0.25)
result = device.solve()
out = dict(device.errors())
out["iterations"] = result.iterations
# replicated interface values: order-independent sums
for key, values in device.interface_values().items():
    for c in range(values.shape[1]):
        out[f"sum {key}[{c}]"] = float(np.sum(values[:, c]))
out["Q_f"], out["Q_p"] = device.flow_rates()
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(out))
