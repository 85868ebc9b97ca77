"""Mesh convergence of the device results (a benchmark, not a test).

Runs the partitioned solver for a sequence of mesh-size factors (every element
size is multiplied by F) and prints, for max |v_f| in the gel and the cell's
max von Mises strain, the value, the change from the previous mesh, the
observed order and a Richardson estimate of the mesh-converged value.

    .venv/bin/python examples/mesh_convergence.py shear --sizes 2 1 0.5 --json out.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.run.solve import solve_partitioned

QUANTITIES = {"max |v_f|": ("gel", "max_interstitial_speed", None),
              "cell max von Mises strain": ("cell", "von_mises_strain", 1),
              "cell max von Mises stress": ("cell", "von_mises_stress", 1),
              "max |u_s|": ("gel", "max_network_displacement", None)}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("case", choices=("shear", "normal"))
    parser.add_argument("--sizes", nargs="+", type=float, default=[2.0, 1.0, 0.5])
    parser.add_argument("--json", help="write the table as JSON")
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    rows = []
    for f in args.sizes:
        t0 = time.perf_counter()
        run = solve_partitioned(CaseParameters.default(args.case, True).with_mesh_size(f), verbose=False,
                                checks=False)
        s = run.summary
        row = {"size_factor": f, "wall_time": time.perf_counter() - t0,
               "gel_cells": s["mesh"]["gel"]["cells"], "cell_cells": s["mesh"]["cell"]["cells"],
               "iterations": s["coupling"]["iterations"]}
        for name, (block, key, idx) in QUANTITIES.items():
            v = s[block][key]
            row[name] = v if idx is None else v[idx]
        rows.append(row)
    out = {"case": args.case, "rows": rows, "estimates": {}}
    for name in QUANTITIES:
        v = np.array([r[name] for r in rows])
        est = {}
        if len(v) >= 3:
            # h halves between entries: order p = log2(|v1 - v0| / |v2 - v1|), Richardson on the last two
            d1, d2 = v[-2] - v[-3], v[-1] - v[-2]
            p = np.log2(abs(d1 / d2)) if d2 != 0 and d1 != 0 else np.nan
            extrapolated = v[-1] + d2 / (2**p - 1) if np.isfinite(p) and p > 0 else v[-1]
            est = {"observed_order": float(p), "extrapolated": float(extrapolated),
                   "relative_error_per_size": [float(abs(x - extrapolated) / abs(extrapolated)) for x in v]}
        out["estimates"][name] = est
    if comm.rank == 0:
        print(f"{args.case}: mesh convergence (every element size x F)")
        header = f"{'F':>6} {'gel cells':>9} {'cell cells':>10} {'its':>4} {'time[s]':>8}" + "".join(
            f" {n:>26}" for n in QUANTITIES)
        print(header)
        for r in rows:
            print(f"{r['size_factor']:6.3g} {r['gel_cells']:9d} {r['cell_cells']:10d} {r['iterations']:4d} "
                  f"{r['wall_time']:8.1f}" + "".join(f" {r[n]:26.10e}" for n in QUANTITIES))
        for n, e in out["estimates"].items():
            if e:
                errs = ", ".join(f"{x:.1e}" for x in e["relative_error_per_size"])
                print(f"{n}: observed order {e['observed_order']:.2f}, extrapolated {e['extrapolated']:.8e}, "
                      f"relative error per mesh [{errs}]")
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(out, fh, indent=2)
    return out


if __name__ == "__main__":
    main()
