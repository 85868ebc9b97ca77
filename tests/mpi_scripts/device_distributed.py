"""The 2D shear device with a cell at mesh size 3, parallel- and serial-implicit, in one process or
distributed ("fluid:1,gel+cell:1" on 2 ranks); prints (rank 0) per scheme the iterations, every
interface data and the norms of every field, as JSON.

Arguments: MODE (``single``, ``distributed`` or a ``distribute`` spec, e.g. ``fluid:1,gel+cell:2`` on 3
ranks), then optionally the schemes (default: parallel serial).  The linearized prior is computed, not
read from the disk cache, so that the distributed run computes its participants' Jacobians through MPI.
"""
import json
import os
import sys

os.environ["GELCELL_PRIOR_CACHE"] = "0"

from mpi4py import MPI  # noqa: E402

from gelcell.case import CaseParameters  # noqa: E402
from gelcell.coupled.defaults import partitioned_config  # noqa: E402
from gelcell.coupled.device import Device  # noqa: E402

DISTRIBUTE = "fluid:1,gel+cell:1"


def field_norms(device) -> dict:
    """The l2 norm of every field's unknowns, computed where the field lives, known on every rank."""
    fields = {"fluid": lambda d: {"velocity": d.fluid.velocity, "pressure": d.fluid.pressure},
              "gel": lambda d: {"displacement": d.gel.displacement(), "pore_pressure": d.gel.pore_pressure(),
                                "interstitial_velocity": d.gel.interstitial_velocity()},
              "cell": lambda d: {"displacement": d.cell.displacement}}
    out = {}
    for field, functions in fields.items():
        norms = device._from_field(field, lambda fs=functions: {k: f.vector.norm() for k, f in fs(device).items()})
        out.update({f"{field}/{k}": v for k, v in norms.items()})
    return out


def run(scheme: str, distribute: str | None) -> dict:
    params = CaseParameters.default("shear", True).with_mesh_size(3)
    table = {"scheme": f"{scheme}-implicit"}
    if distribute:
        table["distribute"] = distribute
    config = partitioned_config(params, table)
    device = Device(params, MPI.COMM_WORLD, distribute=config.get("distribute"))
    result = device.solve(config, verbose=False)
    return {"iterations": result.iterations, "converged": bool(result.converged),
            "data": {n: device.scheme.latest(n).ravel().tolist() for n in device.scheme.data},
            "fields": field_norms(device)}


def main() -> int:
    mode = sys.argv[1]
    distribute = None if mode == "single" else DISTRIBUTE if mode == "distributed" else mode
    schemes = sys.argv[2:] or ["parallel", "serial"]
    out = {"ranks": MPI.COMM_WORLD.size, "schemes": {scheme: run(scheme, distribute) for scheme in schemes}}
    if MPI.COMM_WORLD.rank == 0:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
