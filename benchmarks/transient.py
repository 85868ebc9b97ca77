"""Benchmark of time-dependent runs (issue 11): from rest to steady, fixed and adaptive dt.

Prints, for one device (default: the shear baseline with a cell, default mesh):
windows, windows to 99 % of the steady centroid displacement, mean coupling
iterations per window (all, and after the first five), wall time, and the
ratios to the steady partitioned run and to the monolithic time-dependent run
with the same time discretisation, solved in the same process.  Timings are
printed, never asserted.

    .venv/bin/python benchmarks/transient.py [--case shear] [--mesh-size 1] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import time

from mpi4py import MPI

from gelcell.case import CaseParameters, RunConfig, SolverSettings, TimeSettings
from gelcell.run.solve import solve_partitioned
from gelcell.run.transient_case import run_transient_case


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--case", default="shear", choices=("shear", "normal"))
    parser.add_argument("--mesh-size", type=float, default=1.0)
    parser.add_argument("--scheme", default="be", choices=("be", "bdf2"))
    parser.add_argument("--time-tol", type=float, default=1e-3)
    parser.add_argument("--no-monolithic", action="store_true", help="skip the monolithic time-dependent run")
    parser.add_argument("--json", help="also write the numbers to this file")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    params = CaseParameters.default(args.case).with_mesh_size(args.mesh_size)
    quiet = open("/dev/null", "w")

    t0 = time.perf_counter()
    steady = solve_partitioned(params, comm=comm, verbose=False, checks=False)
    rows = {"steady": {"wall_time": time.perf_counter() - t0, "iterations": steady.summary["coupling"]["iterations"],
                       "centroid_x": steady.summary["cell"]["centroid_displacement"][0]
                       if params.with_cell else None}}
    runs = [("fixed dt", False, TimeSettings(transient=True, scheme=args.scheme)),
            ("adaptive dt", False, TimeSettings(transient=True, scheme=args.scheme, adaptive=True,
                                                time_tol=args.time_tol))]
    if not args.no_monolithic:
        runs.append(("monolithic, fixed dt", True, TimeSettings(transient=True, scheme=args.scheme)))
    for label, monolithic, settings in runs:
        t0 = time.perf_counter()
        config = RunConfig(params, solver=SolverSettings(method="monolithic" if monolithic else "partitioned"),
                           time=settings)
        summary = run_transient_case(config, None, comm=comm, stream=quiet)
        tr = summary["transient"]
        rows[label] = {"wall_time": time.perf_counter() - t0, "windows": tr["windows"],
                       "windows_to_t99": tr["windows_to_t99"], "rejected": tr["rejected_windows"],
                       "iterations_mean": tr["iterations_mean"],
                       "iterations_mean_after_5": tr["iterations_mean_after_5"],
                       "t50": tr["t50"], "t90": tr["t90"], "t99": tr["t99"], "t99_s": tr["t99_s"],
                       "relaxation_time": tr["relaxation_time"], "t_end": tr["t_end"],
                       "centroid_x": summary["cell.centroid_displacement"][0] if params.with_cell else None}
    if comm.rank != 0:
        return
    base = rows["steady"]["wall_time"]
    mono = rows.get("monolithic, fixed dt", {}).get("wall_time")
    print(f"{args.case} device, mesh size {args.mesh_size:g}, {args.scheme}, from rest until steady "
          f"(steady_tol 1e-4 per consolidation time), {comm.size} rank(s)")
    print(f"steady partitioned run: {base:.1f} s, {rows['steady']['iterations']} iterations")
    head = (f"{'run':24s} {'windows':>7s} {'to t99':>7s} {'rejected':>8s} {'it/window':>9s} {'after 5':>8s} "
            f"{'wall [s]':>9s} {'/steady':>8s} {'/mono':>7s} {'t99 [s]':>10s}")
    print(head)
    print("-" * len(head))
    for label, r in rows.items():
        if label == "steady":
            continue
        after = "-" if r["iterations_mean_after_5"] is None else f"{r['iterations_mean_after_5']:.2f}"
        to_mono = "-" if mono is None else f"{r['wall_time'] / mono:.2f}"
        t99 = "-" if r["t99_s"] is None else f"{r['t99_s']:.3e}"
        print(f"{label:24s} {r['windows']:7d} {str(r['windows_to_t99'] or '-'):>7s} {r['rejected']:8d} "
              f"{r['iterations_mean']:9.2f} {after:>8s} {r['wall_time']:9.1f} {r['wall_time'] / base:8.1f} "
              f"{to_mono:>7s} {t99:>10s}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
