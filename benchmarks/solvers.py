"""Issue 30's benchmark: direct (MUMPS) against iterative (Krylov + multigrid), the same run.

Each row is one ``gelcell run shear`` command (the baseline with its cell, steady, the defaults:
finite kinematics, partitioned IQN-ILS to 1e-10), ``--no-figures --quiet``, in a process of its
own with an empty prior cache (so both solvers compute their prior where the default has one),
serial or under ``mpirun -n 2``:

* 2D at ``--sizes-2d`` (default mesh-size 1, 0.5, 0.25, 0.125),
* 3D (``--height``, default 0.4) at ``--sizes-3d`` (default 2, 1.5, 1),
* on 2 ranks: the rows of ``--two-ranks`` (default: 2D 0.25 and 3D 2).

Per row: the unknowns, the process's wall time, the solves' total (the fields' solve times of the
summary), the peak memory (largest rank), the coupling iterations, the Krylov iterations per
solve per field (summary ``solver.krylov``), and the iterative/direct ratio of the solves' total.
Then per solver and dimension the cost exponent k of solves' total ~ unknowns^k, and the 2-rank
speedup of the solves' total.  A run that ``gelcell`` refuses (a mesh that will not fit with that
solver: the estimate is printed before meshing) is listed as refused.  Timings are printed, never
asserted.

    .venv/bin/python benchmarks/solvers.py --json solvers.json          # everything (about 2 hours)
    .venv/bin/python benchmarks/solvers.py --sizes-2d 1 0.5 --sizes-3d 4 3 --two-ranks 2d:1 3d:4
    .venv/bin/python benchmarks/solvers.py --table solvers.json again.json   # print stored rows
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SOLVERS = ("direct", "iterative")
FIELDS = ("fluid", "mesh_motion", "gel", "cell")


def command(dim: int, size: float, solver: str, ranks: int, height: float, out: str) -> list[str]:
    executable = os.path.join(os.path.dirname(sys.executable), "gelcell")
    cmd = [executable, "run", "shear", "--mesh-size", f"{size:g}", "--solver", solver,
           "--no-figures", "--quiet", "--out", out]
    if dim == 3:
        cmd[3:3] = ["--height", f"{height:g}"]
    return cmd if ranks == 1 else ["mpirun", "-n", str(ranks), *cmd]


def measure(dim: int, size: float, solver: str, ranks: int, height: float, timeout: float) -> dict:
    """One run: its wall time and what its summary says it cost."""
    work = tempfile.mkdtemp(prefix="gelcell-solvers-")
    out = os.path.join(work, "run")
    env = dict(os.environ, GELCELL_PRIOR_CACHE_DIR=os.path.join(work, "priors"),
               OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    row = {"dim": dim, "mesh_size": size, "solver": solver, "ranks": ranks}
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(command(dim, size, solver, ranks, height, out), cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {**row, "status": f"over {timeout:.0f} s"}
    row["wall"] = time.perf_counter() - t0
    if proc.returncode != 0:
        last = (proc.stderr.strip() or proc.stdout.strip()).splitlines()[-1:] or ["?"]
        refused = "memory" in last[0] or " need about " in last[0]       # gelcell's estimate before meshing
        return {**row, "status": "refused" if refused else "failed", "message": last[0]}
    with open(os.path.join(out, "summary.json")) as fh:
        s = json.load(fh)
    timing = s["timing"]
    row.update(status="ok", unknowns=s["cost"]["unknowns"], peak_mb=s["cost"]["peak_memory_mb"],
               iterations=s["coupling"]["iterations"],
               solves=sum(v for k, v in timing.items() if k.startswith("solve_")),
               krylov={f: k["mean"] for f, k in s["solver"].get("krylov", {}).items()})
    return row


def fit_exponent(unknowns, times) -> float:
    return float(np.polyfit(np.log(unknowns), np.log(times), 1)[0]) if len(times) >= 2 else float("nan")


def _row_line(r: dict, direct: dict | None) -> str:
    head = f"| {r['dim']}D | {r['mesh_size']:g} | {r['ranks']} | {r['solver']} |"
    if r["status"] != "ok":
        return head + f" {r['status']}: {r.get('message', '')} |" + " |" * 7
    n = r["unknowns"]
    per_field = " / ".join(f"{n[f]:,}" for f in FIELDS if f in n)
    krylov = " / ".join(f"{r['krylov'][f]:.0f}" for f in FIELDS if f in r["krylov"]) or "–"
    ratio = (f"{r['solves'] / direct['solves']:.1f}" if direct and direct["status"] == "ok" else "–")
    return (head + f" {sum(n.values()):,} ({per_field}) | {r['wall']:.1f} | {r['solves']:.1f} | "
            f"{r['peak_mb']:.0f} | {r['iterations']} | {krylov} | {ratio} |")


def print_table(rows: list[dict]) -> None:
    print("| dim | mesh size | ranks | solver | unknowns (fluid / mesh motion / gel / cell) | wall s | solves s "
          "| peak MiB | coupling iterations | Krylov per solve (fluid / mesh motion / gel / cell) "
          "| solves / direct |")
    print("|---|---:|---:|---|---|---:|---:|---:|---:|---|---:|")
    key = lambda r: (r["dim"], r["mesh_size"], r["ranks"])  # noqa: E731
    for r in rows:
        direct = next((d for d in rows if key(d) == key(r) and d["solver"] == "direct"), None)
        print(_row_line(r, None if r["solver"] == "direct" else direct))
    print()
    for dim in (2, 3):
        for solver in SOLVERS:
            ok = [r for r in rows if r["dim"] == dim and r["solver"] == solver and r["ranks"] == 1
                  and r["status"] == "ok"]
            if len(ok) >= 2:
                k = fit_exponent([sum(r["unknowns"].values()) for r in ok], [r["solves"] for r in ok])
                print(f"{dim}D {solver}: solves' total ~ unknowns^{k:.2f} over {len(ok)} levels")
    for r in rows:
        if r["ranks"] == 2 and r["status"] == "ok":
            one = next((d for d in rows if d["ranks"] == 1 and d["status"] == "ok" and
                        (d["dim"], d["mesh_size"], d["solver"]) == (r["dim"], r["mesh_size"], r["solver"])), None)
            if one:
                print(f"{r['dim']}D {r['mesh_size']:g} {r['solver']}: 2 ranks {one['solves'] / r['solves']:.2f}x "
                      f"on the solves, {one['wall'] / r['wall']:.2f}x on the wall")


def merged_rows(paths: list[str]) -> list[dict]:
    """The rows of several --json files in the first file's order; a later file's row replaces an earlier's."""
    key = lambda r: (r["dim"], r["mesh_size"], r["ranks"], r["solver"])  # noqa: E731
    rows: dict = {}
    for path in paths:
        with open(path) as fh:
            rows.update((key(r), r) for r in json.load(fh))
    return list(rows.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes-2d", type=float, nargs="*", default=[1.0, 0.5, 0.25, 0.125])
    parser.add_argument("--sizes-3d", type=float, nargs="*", default=[2.0, 1.5, 1.0])
    parser.add_argument("--two-ranks", nargs="*", default=["2d:0.25", "3d:2"], metavar="DIM:SIZE")
    parser.add_argument("--height", type=float, default=0.4, help="3D chip height (units of L0)")
    parser.add_argument("--timeout", type=float, default=3600.0, help="seconds allowed to each run")
    parser.add_argument("--json", help="write the rows as JSON (after every run)")
    parser.add_argument("--table", nargs="+", metavar="JSON",
                        help="print the table of rows written by --json (a later file's row replaces an earlier "
                             "file's row of the same dim, mesh size, ranks and solver) and run nothing")
    args = parser.parse_args()
    if args.table:
        print_table(merged_rows(args.table))
        return
    # the 2-rank rows before the 3D levels: the finest 3D level is the longest run
    plan = [(2, s, 1) for s in args.sizes_2d]
    plan += [(int(d[0]), float(s), 2) for d, s in (item.lower().split(":") for item in args.two_ranks)]
    plan += [(3, s, 1) for s in args.sizes_3d]
    rows = []
    for dim, size, ranks in plan:
        for solver in SOLVERS:
            rows.append(measure(dim, size, solver, ranks, args.height, args.timeout))
            print(json.dumps(rows[-1]), flush=True)
            if args.json:
                with open(args.json + ".tmp", "w") as fh:
                    json.dump(rows, fh, indent=1)
                os.replace(args.json + ".tmp", args.json)
    print_table(rows)


if __name__ == "__main__":
    main()
