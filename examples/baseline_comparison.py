"""Baseline (Table 1) of both devices: partitioned (IQN-ILS, Aitken) and monolithic side by side.

    .venv/bin/python examples/baseline_comparison.py --mesh-size 1 --json baseline.json

Prints, per device, every summary quantity for each method, the relative
difference to the monolithic result, coupling iterations, wall times and
dofs.  A benchmark, not a test (tests/test_device.py checks the agreement
at a coarse mesh).
"""

from __future__ import annotations

import argparse
import json

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.run.solve import solve_monolithic, solve_partitioned
from gelcell.post.quantities import flat_quantities
from gelcell.run.study import quantity_error


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh-size", type=float, default=1.0)
    parser.add_argument("--cases", nargs="+", default=["shear", "normal"])
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    out = {}
    for case in args.cases:
        p = CaseParameters.default(case, True).with_mesh_size(args.mesh_size)
        runs = {"monolithic": solve_monolithic(p, comm).summary}
        for scheme, acc in (("serial", "iqn-ils"), ("serial", "aitken"), ("parallel", "iqn-ils")):
            coupling = {"scheme": f"{scheme}-implicit", "acceleration": {"type": acc}}
            runs[f"{scheme} {acc}"] = solve_partitioned(p, coupling, comm=comm, verbose=False).summary
        out[case] = {k: {"quantities": flat_quantities(v), "timing": v["timing"], "mesh": v["mesh"],
                         "iterations": (v["coupling"] or {}).get("iterations"),
                         "monolithic": v.get("monolithic"),
                         "error_vs_monolithic": quantity_error(v, runs["monolithic"]),
                         "interface_residual": max(x for r in v["interface_residuals"].values()
                                                   for x in r.values())}
                     for k, v in runs.items()}
        if comm.rank == 0:
            names = list(runs)
            print(f"\n## {case} (mesh size factor {args.mesh_size:g})\n")
            print("| quantity | " + " | ".join(names) + " |")
            print("|---|" + "---:|" * len(names))
            for q in out[case]["monolithic"]["quantities"]:
                print(f"| {q} | " + " | ".join(f"{out[case][n]['quantities'][q]:.6e}" for n in names) + " |")
            print("| worst relative difference to monolithic | " + " | ".join(
                f"{out[case][n]['error_vs_monolithic']:.1e}" for n in names) + " |")
            print("| worst interface-condition residual | " + " | ".join(
                f"{out[case][n]['interface_residual']:.1e}" for n in names) + " |")
            print("| coupling iterations (monolithic: Newton) | " + " | ".join(
                str(out[case][n]["iterations"] if n != "monolithic"
                    else out[case][n]["monolithic"]["newton_iterations"]) for n in names) + " |")
            print("| wall time total [s] | " + " | ".join(
                f"{out[case][n]['timing']['total']:.2f}" for n in names) + " |")
            m = out[case]["monolithic"]["monolithic"]
            part = out[case]["serial iqn-ils"]["mesh"]
            print(f"\ndofs: monolithic {m['dofs']} ({m['active_dofs']} active); partitioned fluid "
                  f"{part['fluid']['dofs']}, gel {part['gel']['dofs']}, cell {part['cell']['dofs']}; cells: "
                  f"fluid {part['fluid']['cells']}, gel {part['gel']['cells']}, cell {part['cell']['cells']}")
    if args.json and comm.rank == 0:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
