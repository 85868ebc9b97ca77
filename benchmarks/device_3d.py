"""Cost of the 3D devices (model.md section 10): unknowns, wall time, peak memory, coupling iterations.

    .venv/bin/python benchmarks/device_3d.py                          # shear at 4 3 2, normal at 2
    .venv/bin/python benchmarks/device_3d.py --shear 4 3 2 1.5 --normal 2
    .venv/bin/python benchmarks/device_3d.py --shear 4 3 --normal 4 --height 0.4 --json cost3d.json

Each run (the device with its default cell, chip height ``--height``, no-slip
walls, the defaults of ``gelcell run``: finite kinematics, IQN-ILS to 1e-10)
is the partitioned solve in a process of its own, so its peak memory (the
process's resident set, ``summary["cost"]["peak_memory_mb"]``) is its own.
Per run: the tetrahedra, the unknowns per field, the process's wall time and
CPU time (user + system: on a shared machine the wall time also holds the
waits for a core), the setup (meshing, or the mesh cache, and the fields'
set-up), the peak memory, the coupling iterations and the solve time per
coupling iteration per field (``summary["timing"]["solve_<field>"]`` over the
iterations; the mesh motion is in the fluid's).  Times are wall-clock seconds on whatever machine runs this:
printed, never asserted.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIELDS = ("fluid", "mesh_motion", "gel", "cell")


def child(case: str, mesh_size: float, height: float) -> None:
    """Solve one 3D case and print its summary's cost, timing, coupling and mesh blocks."""
    from gelcell.case import CaseParameters
    from gelcell.run.solve import solve_partitioned
    p = CaseParameters.default(case)
    p = p.replace(geometry=dataclasses.replace(p.geometry, chip_height=height)).with_mesh_size(mesh_size)
    s = solve_partitioned(p, checks=False, verbose=False).summary
    usage = resource.getrusage(resource.RUSAGE_SELF)
    out = {"cost": s["cost"], "timing": s["timing"], "mesh": s["mesh"], "cpu": usage.ru_utime + usage.ru_stime,
           "iterations": s["coupling"]["iterations"], "converged": s["coupling"]["converged"]}
    print("RESULT " + json.dumps(out, default=float), flush=True)


def run_child(case: str, mesh_size: float, height: float, timeout: float) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--child", case, "--mesh-size", str(mesh_size),
           "--height", str(height)]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                              env=dict(os.environ, MPLBACKEND="Agg"))
    except subprocess.TimeoutExpired:
        return {"case": case, "mesh_size": mesh_size, "error": f"timed out after {timeout:.0f} s"}
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        return {"case": case, "mesh_size": mesh_size,
                "error": f"exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1:]}"}
    out = json.loads(lines[-1][len("RESULT "):])
    out.update(case=case, mesh_size=mesh_size, wall=time.perf_counter() - t0)
    return out


def _row(r: dict) -> str:
    if "error" in r:
        return f"| {r['case']} | {r['mesh_size']:g} | {r['error']} |"
    unknowns, timing, it = r["cost"]["unknowns"], r["timing"], max(r["iterations"], 1)
    tets = sum(m["cells"] for m in r["mesh"].values())
    dofs = " / ".join(f"{unknowns[f]:,}" for f in FIELDS if f in unknowns)
    per_it = " / ".join(f"{timing[f'solve_{f}'] / it:.2f}" for f in FIELDS if f"solve_{f}" in timing)
    return (f"| {r['case']} | {r['mesh_size']:g} | {tets:,} | {dofs} | {r['wall']:.0f} | {r['cpu']:.0f} "
            f"| {timing['setup']:.0f} "
            f"| {r['cost']['peak_memory_mb']:.0f} | {r['iterations']}{'' if r['converged'] else ' (not converged)'} "
            f"| {per_it} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shear", type=float, nargs="*", default=[4.0, 3.0, 2.0], help="shear mesh sizes")
    parser.add_argument("--normal", type=float, nargs="*", default=[2.0], help="normal mesh sizes")
    parser.add_argument("--height", type=float, default=0.4, help="chip height (units of L0)")
    parser.add_argument("--timeout", type=float, default=3600.0, help="seconds per run")
    parser.add_argument("--json", help="write the measurements to this file")
    parser.add_argument("--child", choices=("shear", "normal"), help=argparse.SUPPRESS)
    parser.add_argument("--mesh-size", type=float, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.mesh_size, args.height)
        return
    runs = [(c, f) for c, sizes in (("shear", args.shear), ("normal", args.normal)) for f in sizes]
    print(f"3D devices, chip height {args.height:g}, no-slip walls, finite kinematics, with the default cell\n")
    print("| device | --mesh-size | tetrahedra | unknowns fluid / mesh motion / gel / cell | wall s | CPU s | setup s "
          "| peak MiB | iterations | s per iteration fluid / gel / cell |")
    print("|---|---:|---:|---|---:|---:|---:|---:|---:|---|")
    results = []
    for case, size in runs:
        results.append(run_child(case, size, args.height, args.timeout))
        print(_row(results[-1]), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
