"""Errors of the channel-over-gel-layer device against its closed forms (docs/verification-coupled.md).

Runs the partitioned device (gelcell/layer.py) on a sequence of meshes for each
case and prints, per case, a Markdown table: the error of every field and
interface quantity on each mesh and the least-squares rate.

    .venv/bin/python examples/layer_convergence.py                       # the tables of the docs
    .venv/bin/python examples/layer_convergence.py --cases couette --meshes 8 16 32 64
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from mpi4py import MPI

from gelcell.coupled.layer import FLOWS, LayerCase, LayerDevice

CASES = {**{f: (lambda f=f: LayerCase(f)) for f in FLOWS},
         **{f"{f}-table1": (lambda f=f: LayerCase.table1(f)) for f in FLOWS}}


def study(name: str, meshes: list[int]) -> dict:
    case = CASES[name]()
    rows = []
    for n in meshes:
        t0 = time.perf_counter()
        device = LayerDevice(case, n=n)
        result = device.solve()
        rows.append({"n": n, "h": case.H_g / n, "iterations": result.iterations, "converged": result.converged,
                     "seconds": time.perf_counter() - t0, "errors": device.errors()})
    h = np.array([r["h"] for r in rows])
    keys = list(rows[0]["errors"])
    rates = {}
    if len(rows) > 1:
        for k in keys:
            err = np.array([r["errors"][k] for r in rows])
            rates[k] = float(np.polyfit(np.log(h), np.log(err), 1)[0]) if np.all(err > 0) else None
    return {"case": name, "delta": case.brinkman_length, "runs": rows, "rates": rates,
            "max_strain": device.closed_form.max_strain()}


def markdown(res: dict) -> str:
    runs = res["runs"]
    delta = res["delta"]
    head = "| quantity | " + " | ".join(f"h = δ/{delta / r['h']:.3g}" for r in runs) + " | rate |"
    lines = [f"**{res['case']}** (max |F - I| = {res['max_strain']:.1e}; coupling iterations "
             + ", ".join(str(r["iterations"]) for r in runs) + ")", "", head,
             "|---|" + "---:|" * (len(runs) + 1)]
    for k in runs[0]["errors"]:
        rate = res["rates"].get(k)
        lines.append(f"| {k} | " + " | ".join(f"{r['errors'][k]:.2e}" for r in runs)
                     + f" | {'-' if rate is None else f'{rate:.2f}'} |")
    return "\n".join(lines)


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES),
                        default=["poiseuille", "couette", "poiseuille-table1", "couette-table1"])
    parser.add_argument("--meshes", nargs="+", type=int, default=[8, 16, 32],
                        help="cells across the gel (default 8 16 32: h = delta/2, delta/4, delta/8)")
    parser.add_argument("--json", help="also write the results as JSON")
    args = parser.parse_args(argv)
    results = [study(name, args.meshes) for name in args.cases]
    if MPI.COMM_WORLD.rank == 0:
        for res in results:
            print(markdown(res), end="\n\n")
        if args.json:
            with open(args.json, "w") as f:
                json.dump(results, f, indent=1)
    return results


if __name__ == "__main__":
    main()
