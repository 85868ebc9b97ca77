"""Issue 31's benchmark in one call: every way to run a device from rest to steady, side by side.

Per device (default: both, with their cell, default mesh), in this order in one process:

* ``steady``: the steady partitioned run;
* ``default``: ``--transient`` as it is (BDF2, dt = tau_c/40, graded start);
* ``default dt/2``, ``default dt/4``: the same at half and a quarter of the step, for the
  Richardson limit of the milestones (formal order 2):  m0 = m4 + (m4 - m2) / 3;
* ``BE tau_c/40``: backward Euler at the default step;
* ``BDF2 tau_c/40, BE start``: BDF2 started by one backward Euler step of dt (no graded start);
* ``adaptive tol``: ``--adaptive --time-tol tol`` for each ``--time-tol``;
* ``monolithic BE 5e-8``: the monolithic reference, backward Euler at dt = 5e-8 (the source
  paper's step), to t_end = 3.35e-6 for the shear device (the run issue 31 measured) and until
  steady for the normal device (3.35e-6 is a fraction of its consolidation time).

Printed per run: windows, coupling iterations (Newton iterations for the monolithic run), wall
time of the call, its ratio to the steady and to the monolithic run, and t50/t90/t99 with their
relative error against the Richardson limit.  Timings are printed, never asserted.

    .venv/bin/python benchmarks/transient_table.py [--case shear normal] [--mesh-size 1] [--json table.json]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from unittest import mock

from mpi4py import MPI

from gelcell.case import CaseParameters, RunConfig, SolverSettings, TimeSettings
from gelcell.run.solve import solve_partitioned
from gelcell.run.transient_case import run_transient_case

MILESTONES = ("t50", "t90", "t99")
#: the monolithic reference of issue 31: the source paper's step, and the shear run's end
MONOLITHIC_DT, SHEAR_T_END = 5e-8, 3.35e-6


def steady_row(params: CaseParameters, comm) -> dict:
    t0 = time.perf_counter()
    result = solve_partitioned(params, comm=comm, verbose=False, checks=False)
    return {"wall": time.perf_counter() - t0, "iterations": result.summary["coupling"]["iterations"]}


def transient_row(params: CaseParameters, settings: TimeSettings, comm, method: str = "partitioned",
                  graded_start: bool = True) -> dict:
    """One run from rest: its windows, iterations, wall and milestones (from its summary)."""
    config = RunConfig(params, solver=SolverSettings(method=method), time=settings)
    t0 = time.perf_counter()
    with open(os.devnull, "w") as quiet:
        if graded_start:
            summary = run_transient_case(config, None, comm=comm, stream=quiet)
        else:
            with mock.patch("gelcell.run.transient.BDF2_START", ()):
                summary = run_transient_case(config, None, comm=comm, stream=quiet)
    wall = time.perf_counter() - t0
    tr = summary["transient"]
    estimated = (summary.get("time") or {}).get("estimated_error") or {}
    return {"wall": wall, "windows": tr["windows"], "iterations": tr["iterations_total"],
            "rejected": tr["rejected_windows"], "t_end": tr["t_end"], "steady": tr["steady"],
            "estimated": {q: estimated.get(q) for q in MILESTONES}, **{q: tr[q] for q in MILESTONES}}


def device_rows(case: str, mesh_size: float, tolerances: list[float], comm) -> dict:
    """Every run of one device, in the order of the module docstring."""
    params = CaseParameters.default(case).with_mesh_size(mesh_size)
    dt = TimeSettings(transient=True).resolved(params)["dt"]
    rows = {"steady": steady_row(params, comm),
            "default": transient_row(params, TimeSettings(transient=True), comm)}
    for k in (2, 4):
        rows[f"default dt/{k}"] = transient_row(params, TimeSettings(transient=True, dt=dt / k), comm)
    rows["BE tau_c/40"] = transient_row(params, TimeSettings(transient=True, scheme="be"), comm)
    rows["BDF2 tau_c/40, BE start"] = transient_row(params, TimeSettings(transient=True), comm, graded_start=False)
    for tol in tolerances:
        rows[f"adaptive {tol:g}"] = transient_row(params, TimeSettings(transient=True, adaptive=True,
                                                                       time_tol=tol), comm)
    mono = TimeSettings(transient=True, scheme="be", dt=MONOLITHIC_DT,
                        t_end=SHEAR_T_END if case == "shear" else None)
    rows["monolithic BE 5e-8"] = transient_row(params, mono, comm, method="monolithic")
    return rows


def limits(rows: dict) -> dict:
    """The Richardson limit of each milestone from the default scheme at dt, dt/2, dt/4."""
    m = [rows[k] for k in ("default", "default dt/2", "default dt/4")]
    return {q: m[2][q] + (m[2][q] - m[1][q]) / 3 for q in MILESTONES}


def table(case: str, rows: dict) -> list[str]:
    limit = limits(rows)
    steady, mono = rows["steady"]["wall"], rows["monolithic BE 5e-8"]["wall"]
    lines = [f"{case}: steady {steady:.1f} s ({rows['steady']['iterations']} iterations); Richardson limits "
             + ", ".join(f"{q} {limit[q]:.5e}" for q in MILESTONES),
             "| run | windows | iterations | wall | /steady | /monolithic | "
             + " | ".join(f"{q} (error)" for q in MILESTONES) + " |",
             "|---" * 9 + "|"]
    for label, r in rows.items():
        if label == "steady":
            continue
        cells = " | ".join(f"{r[q]:.4e} ({(r[q] - limit[q]) / limit[q]:+.2%})" for q in MILESTONES)
        lines.append(f"| {label} | {r['windows']} | {r['iterations']} | {r['wall']:.1f} s | "
                     f"{r['wall'] / steady:.2f} | {r['wall'] / mono:.2f} | {cells} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--case", nargs="+", default=["shear", "normal"], choices=("shear", "normal"))
    parser.add_argument("--mesh-size", type=float, default=1.0)
    parser.add_argument("--time-tol", nargs="+", type=float, default=[1e-3, 1e-4],
                        help="the tolerances of the adaptive rows")
    parser.add_argument("--json", help="also write every row to this file")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    results = {case: device_rows(case, args.mesh_size, args.time_tol, comm) for case in args.case}
    if comm.rank != 0:
        return
    print(f"mesh size {args.mesh_size:g}, with the cell, from rest, {comm.size} rank(s); "
          f"errors against the Richardson limit of the default scheme")
    for case, rows in results.items():
        print("\n".join(table(case, rows)))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()
