"""The layer device as a 3D slab: errors against the closed form, observed rates and coupling iterations.

Prints, for Couette and Poiseuille over the gel layer (docs/verification-coupled.md section 7), on
delta/h = 1, 2, 4 (and 8 with ``--fine``): every error of the slab, its rate from the previous level,
the planar device's coupling iterations beside the slab's, and the slab's iterations with the
linearized prior of the quasi-Newton step (``jacobian_prior="linearized"``).

    .venv/bin/python benchmarks/layer_3d.py [--fine]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from mpi4py import MPI

from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.layer import LayerCase, LayerDevice

DEPTH = 0.25


def main(fine: bool) -> None:
    levels = (4, 8, 16, 32) if fine else (4, 8, 16)
    root = MPI.COMM_WORLD.rank == 0
    for flow in ("couette", "poiseuille"):
        previous = None
        for n in levels:
            t0 = time.perf_counter()
            slab = LayerDevice(LayerCase(flow), n=n, depth=DEPTH)
            iterations = slab.solve().iterations
            seconds = time.perf_counter() - t0
            errors = slab.errors()
            planar = LayerDevice(LayerCase(flow), n=n).solve().iterations
            prior = LayerDevice(LayerCase(flow), n=n, depth=DEPTH).solve(
                coupling_config(with_cell=False, jacobian_prior="linearized")).iterations
            if root:
                print(f"{flow} delta/h = {n // 4}: slab {iterations} iterations ({seconds:.1f} s), "
                      f"planar {planar}, slab with the linearized prior {prior}")
                for k, e in errors.items():
                    rate = "" if previous is None else f"  rate {np.log2(previous[k] / e):.2f}"
                    print(f"    {k:30s} {e:.3e}{rate}")
            previous = errors


if __name__ == "__main__":
    main("--fine" in sys.argv[1:])
