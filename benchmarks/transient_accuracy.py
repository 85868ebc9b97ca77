"""Time-discretisation error of the milestones t50/t90/t99 (issue 31, target 1).

Runs a device from rest to steady at dt = tau_c/40 times each factor (default 1, 1/2, 1/4),
per scheme, and prints per milestone the value at each dt, the observed order of the three
finest-to-coarsest levels m1, m2, m4 (dt, dt/2, dt/4),

    p = log2((m1 - m2) / (m2 - m4)),

the Richardson limit with the scheme's formal order q (1 backward Euler, 2 BDF2),

    m0 = m4 + (m4 - m2) / (2^q - 1),

and each run's relative error against it.  The runs' summaries are kept in ``--json``
(one entry per case, scheme, method, factor), so a run already there is not repeated.

    .venv/bin/python benchmarks/transient_accuracy.py --case shear --mesh-size 3 --json acc.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
from unittest import mock

import numpy as np

from mpi4py import MPI

from gelcell.case import CaseParameters, RunConfig, SolverSettings, TimeSettings
from gelcell.post.milestones import _crossing, estimated_errors, transient_summary
from gelcell.run.transient import BDF2_START
from gelcell.run.transient_case import run_transient_case

MILESTONES = ("t50", "t90", "t99")
ORDER = {"be": 1, "bdf2": 2, "bdf2-uniform": 2}


def measure(case: str, mesh_size: float, scheme: str, factor: float, method: str, comm) -> dict:
    """One run from rest to steady at dt = factor tau_c/40: its milestones and cost."""
    params = CaseParameters.default(case).with_mesh_size(mesh_size)
    # "bdf2-uniform": BDF2 without the graded start (one backward Euler step of dt first)
    start = () if scheme == "bdf2-uniform" else BDF2_START
    scheme = scheme.partition("-")[0]
    settings = TimeSettings(transient=True, scheme=scheme)
    dt = settings.resolved(params)["dt"] * factor
    config = RunConfig(params, solver=SolverSettings(method=method),
                       time=TimeSettings(transient=True, scheme=scheme, dt=dt))
    captured = {}

    def keep_rows(state, *args):
        # the whole series, which summary.json does not hold, for milestones recomputed from it
        captured["rows"] = state["rows"]
        return transient_summary(state, *args)

    with (open(os.devnull, "w") as quiet, mock.patch("gelcell.run.transient_case.transient_summary", keep_rows),
          mock.patch("gelcell.run.transient.BDF2_START", start)):
        summary = run_transient_case(config, None, comm=comm, stream=quiet)
    series = {k: [r[k] for r in captured["rows"]] for k in ("t", summary["transient"]["quantity"])}
    tr = summary["transient"]
    row = {k: tr[k] for k in MILESTONES}
    row["series"] = {"t": list(series["t"]), "x": list(series[tr["quantity"]])}
    row.update(dt=dt, windows=tr["windows"], iterations=tr["iterations_total"], wall=tr["wall_time"],
               estimated=summary.get("time", {}).get("estimated_error"))
    return row


def richardson(m1: float, m2: float, m4: float, order: int) -> dict:
    """Observed order of three levels (dt, dt/2, dt/4) and the limit extrapolated with the formal order."""
    ratio = (m1 - m2) / (m2 - m4) if m2 != m4 else math.nan
    observed = math.log2(ratio) if ratio > 0 else math.nan
    return {"observed_order": observed, "limit": m4 + (m4 - m2) / (2**order - 1)}


def milestones(row: dict, scheme: str) -> tuple[dict, dict]:
    """The milestones of a stored series (gelcell's crossing) and their estimated relative errors."""
    t, x = np.array(row["series"]["t"]), np.array(row["series"]["x"])
    ratio = x / x[-1]
    found = {q: _crossing(t, ratio, int(q[1:]) / 100) for q in MILESTONES}
    return found, estimated_errors(t, ratio, scheme.partition("-")[0], found)


def table(runs: dict, case: str, scheme: str, method: str) -> list[str]:
    """Lines of the milestone table of one case and scheme."""
    mine = {float(k.split("|")[3]): milestones(v, scheme) + (v,) for k, v in runs.items()
            if k.startswith(f"{case}|{scheme}|{method}|")}
    if not all(f in mine for f in (1.0, 0.5, 0.25)):
        return [f"{case} {scheme} {method}: dt, dt/2, dt/4 not all measured ({sorted(mine)})"]
    lines = [f"{case}, {scheme}, {method}: dt = tau_c/40 x factor; milestone (error against the limit, "
             f"estimated error)"]
    limits = {}
    for q in MILESTONES:
        r = richardson(*(mine[f][0][q] for f in (1.0, 0.5, 0.25)), ORDER[scheme])
        limits[q] = r["limit"]
        lines.append(f"  {q}: observed order {r['observed_order']:.2f}, limit {r['limit']:.5e}")
    for f in sorted(mine, reverse=True):
        found, estimate, row = mine[f]
        cells = "  ".join(f"{q} {found[q]:.5e} ({(found[q] - limits[q]) / limits[q]:+.3%}, {estimate[q]:+.3%})"
                          for q in MILESTONES)
        lines.append(f"  x {f:<5g} windows {row['windows']:4d} iterations {row['iterations']:5d} "
                     f"wall {row['wall']:6.1f} s  {cells}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--case", nargs="+", default=["shear", "normal"])
    parser.add_argument("--scheme", nargs="+", default=["be", "bdf2"], choices=("be", "bdf2", "bdf2-uniform"),
                        help="bdf2-uniform: BDF2 started by one backward Euler step of dt (before the graded start)")
    parser.add_argument("--factor", nargs="+", type=float, default=[1.0, 0.5, 0.25])
    parser.add_argument("--mesh-size", type=float, default=3.0)
    parser.add_argument("--method", default="partitioned", choices=("partitioned", "monolithic"))
    parser.add_argument("--json", default="transient_accuracy.json")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    runs = json.load(open(args.json)) if os.path.exists(args.json) else {}
    for case in args.case:
        for scheme in args.scheme:
            for factor in args.factor:
                key = f"{case}|{scheme}|{args.method}|{factor:g}|{args.mesh_size:g}"
                if key not in runs:
                    runs[key] = measure(case, args.mesh_size, scheme, factor, args.method, comm)
                    if comm.rank == 0:
                        with open(args.json, "w") as fh:
                            json.dump(runs, fh, indent=1)
    if comm.rank == 0:
        print(f"mesh size {args.mesh_size:g}, from rest until steady, dt = tau_c/40 x factor")
        mesh = {k: v for k, v in runs.items() if k.endswith(f"|{args.mesh_size:g}")}
        for case in args.case:
            for scheme in args.scheme:
                print("\n".join(table(mesh, case, scheme, args.method)))


if __name__ == "__main__":
    main()
