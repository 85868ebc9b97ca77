"""Coupling iterations of a 3D device under a coarse-mesh surrogate prior (issue 29, item 5).

The 3D devices have too many interface unknowns for the default's dense linearized prior, and
couple with the secant model alone.  This measures the alternative of computing the linearized
prior on a coarser device and carrying it over (``coupling.CoarseSurrogate``,
``Device.coarse_surrogate``): for each (fine, coarse) pair of mesh sizes, the coupling
iterations to the default's 1e-10 with

* the secant model alone (the default at these sizes),
* the coarse device's prior carried over,
* the fine device's own linearized prior (the target; only where it is affordable).

Shear device with its cell, chip height 0.4, the default finite kinematics, steady, partitioned;
each run on a fresh device.

    .venv/bin/python benchmarks/coarse_surrogate_3d.py [--pairs 5:6 4.8:5 4:6] [--case shear]
        [--fine-prior-max 9000]

Printed as a markdown table (docs/three-dimensional.md holds a run of it).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from gelcell.case import CaseParameters
from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.device import Device

HEIGHT = 0.4


def device(case: str, mesh_size: float) -> Device:
    p = CaseParameters.default(case).with_mesh_size(mesh_size)
    return Device(p.replace(geometry=dataclasses.replace(p.geometry, chip_height=HEIGHT)))


def config(d: Device, prior: str) -> dict:
    return coupling_config(with_cell=True, params=d.params, jacobian_prior=prior)


def timed_solve(d: Device, prior: str, surrogate=None) -> tuple[int, float]:
    t0 = time.perf_counter()
    result = d.solve(config(d, prior), verbose=False, surrogate=surrogate)
    if not result.converged:
        raise RuntimeError(f"{d.params.mesh.size_factor}: did not converge ({prior})")
    return result.iterations, time.perf_counter() - t0


def row(case: str, fine_size: float, coarse_size: float, fine_prior_max: int) -> str:
    coarse = device(case, coarse_size)
    coarse_iterations, coarse_wall = timed_solve(coarse, "linearized")
    secant = device(case, fine_size)
    secant_iterations, secant_wall = timed_solve(secant, "none")
    carried = device(case, fine_size)
    carried_iterations, carried_wall = timed_solve(carried, "none", surrogate=carried.coarse_surrogate(coarse))
    unknowns = carried.scheme.layout.size
    own = "–"
    if unknowns <= fine_prior_max:
        own_iterations, own_wall = timed_solve(device(case, fine_size), "linearized")
        own = f"{own_iterations} ({own_wall:.0f} s)"
    return (f"| {fine_size:g} | {unknowns} | {coarse_size:g} | {coarse.scheme.layout.size} "
            f"({coarse_iterations} it., {coarse_wall:.0f} s) | {secant_iterations} ({secant_wall:.0f} s) | "
            f"{carried_iterations} ({carried_wall:.0f} s) | {own} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", nargs="+", default=["5:6", "4.8:5", "4:6"],
                        help="FINE:COARSE mesh sizes (default 5:6 4.8:5 4:6)")
    parser.add_argument("--case", default="shear", choices=["shear", "normal"])
    parser.add_argument("--fine-prior-max", type=int, default=9000,
                        help="compute the fine device's own prior up to this many interface unknowns")
    args = parser.parse_args()
    print(f"**{args.case}**, H = {HEIGHT}, with its cell; iterations to 1e-10 (wall of the solve, the "
          f"coarse one including its prior)\n")
    print("| fine --mesh-size | interface unknowns | coarse --mesh-size | coarse unknowns | secant model alone "
          "| coarse prior carried over | fine linearized prior |")
    print("|---|---|---|---|---|---|---|")
    for pair in args.pairs:
        fine, coarse = (float(v) for v in pair.split(":"))
        print(row(args.case, fine, coarse, args.fine_prior_max), flush=True)


if __name__ == "__main__":
    main()
