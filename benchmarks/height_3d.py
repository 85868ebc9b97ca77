"""The 3D devices beside the planar ones: the quantities of a run, their change under refinement, and
how they approach the planar values as the chip height H grows (model.md section 10, issue 29).

For both devices with a cell (default kinematics, finite strain; steady, partitioned):

1. the planar device and the 3D device of H = 0.4 at two mesh sizes (``--levels``, default 3 and 2):
   each quantity at the finer level and its relative change from the coarser one (the mesh-convergence
   estimate), and the ratio 3D / 2D; plus the cell's volume-averaged von Mises strain, which is not a
   summary quantity but converges where the extremes do not yet;
2. at one mesh size (``--sweep-mesh``, default 4): the ratio 3D / 2D of each quantity for
   H = 0.2, 0.4, 0.8, 1.6, and the coupling iterations.

    .venv/bin/python benchmarks/height_3d.py [--levels 3 2] [--sweep-mesh 4] [--cases shear normal]

Printed as markdown tables (docs/three-dimensional.md holds a run of it).  Wall time on the 2-core
machine: about 15 minutes (the H = 0.4 runs at mesh-size 2 take ~2 min and ~5 GB each).
"""

from __future__ import annotations

import argparse
import dataclasses

import ufl
from dolfinx import fem
from mpi4py import MPI

import cell.forms as cell_forms
from femtools.functions import integrate, von_mises
from gelcell.case import CaseParameters
from gelcell.run.solve import solve_partitioned

HEIGHTS = (0.2, 0.4, 0.8, 1.6)
QUANTITIES = [
    ("max interstitial speed", lambda s: s["gel"]["max_interstitial_speed"]),
    ("centroid displacement x", lambda s: s["cell"]["centroid_displacement"][0]),
    ("centroid displacement y", lambda s: s["cell"]["centroid_displacement"][1]),
    ("cell von Mises strain min", lambda s: s["cell"]["von_mises_strain"][0]),
    ("cell von Mises strain max", lambda s: s["cell"]["von_mises_strain"][1]),
    ("cell von Mises strain, mean", lambda s: s["mean_cell_strain"]),
    ("cell von Mises stress max", lambda s: s["cell"]["von_mises_stress"][1]),
    ("traction: pressure", lambda s: s["cell"]["max_traction_von_mises"]["pressure"]),
    ("traction: Brinkman", lambda s: s["cell"]["max_traction_von_mises"]["brinkman"]),
    ("traction: network", lambda s: s["cell"]["max_traction_von_mises"]["network"]),
    ("traction: total", lambda s: s["cell"]["max_traction_von_mises"]["total"]),
]


def case(name: str, mesh_size: float, height: float | None) -> CaseParameters:
    p = CaseParameters.default(name).with_mesh_size(mesh_size)
    if height is not None:
        p = p.replace(geometry=dataclasses.replace(p.geometry, chip_height=height))
    return p


def mean_cell_strain(run) -> float:
    """The cell's volume average of the von Mises Green-Lagrange strain (the summary's measure)."""
    f = run.fields
    dx = ufl.Measure("dx", domain=f.cell_mesh)
    e = von_mises(cell_forms.green_lagrange(f.cell_displacement, fem.Constant(f.cell_mesh,
                                                                               f.params.displacement_scale)))
    return integrate(e, dx) / integrate(fem.Constant(f.cell_mesh, 1.0), dx)


def solve(name: str, mesh_size: float, height: float | None) -> dict:
    run = solve_partitioned(case(name, mesh_size, height), verbose=False, checks=False)
    return {**run.summary, "mean_cell_strain": mean_cell_strain(run)}


def change(fine: float, coarse: float) -> str:
    return "–" if fine == 0 else f"{abs(fine - coarse) / abs(fine) * 100:.1f} %"


def beside_planar(name: str, levels: list[float], say) -> None:
    coarse, fine = levels
    runs = {(h, m): solve(name, m, h) for h in (None, 0.4) for m in levels}
    say(f"\n**{name}**, mesh-size {fine:g} (change from mesh-size {coarse:g}); 3D: H = 0.4, floor and lid walls\n")
    say("| quantity | 2D | 3D | 3D / 2D |\n|---|---|---|---|")
    for label, q in QUANTITIES:
        a, b = q(runs[None, fine]), q(runs[0.4, fine])
        ratio = f"{b / a:.3f}" if a else "–"
        say(f"| {label} | {a:.4e} ({change(a, q(runs[None, coarse]))}) | {b:.4e} ({change(b, q(runs[0.4, coarse]))}) "
            f"| {ratio} |")
    flat, chip = runs[None, fine], runs[0.4, fine]
    say(f"\ncoupling iterations 2D / 3D: {flat['coupling']['iterations']} / {chip['coupling']['iterations']}; "
        f"3D unknowns {sum(chip['cost']['unknowns'].values())}, peak memory {chip['cost']['peak_memory_mb']:.0f} MB")


def height_sweep(name: str, mesh_size: float, say) -> None:
    planar = solve(name, mesh_size, None)
    runs = [solve(name, mesh_size, h) for h in HEIGHTS]
    say(f"\n**{name}**, mesh-size {mesh_size:g}: 3D / 2D against the chip height H\n")
    say("| quantity | " + " | ".join(f"H = {h:g}" for h in HEIGHTS) + " | 2D |\n|---|" + "---|" * (len(HEIGHTS) + 1))
    for label, q in QUANTITIES:
        a = q(planar)
        if a:
            say(f"| {label} | " + " | ".join(f"{q(r) / a:.3f}" for r in runs) + f" | {a:.4e} |")
    say("\ncoupling iterations: " + ", ".join(str(r["coupling"]["iterations"]) for r in runs)
        + f" (2D: {planar['coupling']['iterations']})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--levels", type=float, nargs=2, default=[3.0, 2.0])
    ap.add_argument("--sweep-mesh", type=float, default=4.0)
    ap.add_argument("--cases", nargs="+", default=["shear", "normal"])
    args = ap.parse_args()
    say = print if MPI.COMM_WORLD.rank == 0 else (lambda *a: None)
    for name in args.cases:
        beside_planar(name, args.levels, say)
    for name in args.cases:
        height_sweep(name, args.sweep_mesh, say)


if __name__ == "__main__":
    main()
