"""Time-dependent runs with and without the per-dt linearized prior (issue 31 target 2), printed.

Each run is one ``gelcell run DEVICE --transient`` process, from rest until steady (the default),
serial, run in turn; "before" is ``--jacobian-prior none`` (the secant model reusing 40 windows,
the default before the per-dt prior), "after" the default.  Printed per run: windows, coupling
iterations (total, mean per window, mean after window 5), whole-process wall and CPU time
(user + system), the prior the run
says it used, and t50/t90/t99.

    python benchmarks/transient_prior.py                 # default mesh, shear (the issue's baseline)
    python benchmarks/transient_prior.py --mesh-size 3 --devices shear normal
    python benchmarks/transient_prior.py --monolithic    # also the monolithic BE at dt = 5e-8
    python benchmarks/transient_prior.py --mesh-size 3 --scheme bdf2 --adaptive --t-end 3e-6

The prior's disk cache does not serve time-dependent runs: every "after" run computes its
factorisations.  Wall times on a shared machine are upper bounds; compare runs of one call.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

GELCELL = [sys.executable, "-m", "gelcell.cli"]


def _run(args: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "out")
        t0, c0 = time.perf_counter(), _children_cpu()
        proc = subprocess.run(GELCELL + args + ["--no-figures", "--quiet", "--out", out],
                              capture_output=True, text=True)
        wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
        if proc.returncode != 0:
            raise RuntimeError(f"gelcell {' '.join(args)} failed:\n{proc.stderr[-2000:]}")
        with open(os.path.join(out, "summary.json")) as fh:
            summary = json.load(fh)
        with open(os.path.join(out, "timeseries.csv")) as fh:
            header, *rows = [line.strip().split(",") for line in fh if line.strip()]
    iterations = [int(float(r[header.index("iterations")])) for r in rows[1:]]
    prior = [line for line in proc.stdout.splitlines() if line.startswith("coupling prior:")]
    t = summary["transient"]
    return {"windows": len(iterations), "iterations": sum(iterations), "per_window": iterations,
            "wall": wall, "cpu": cpu, "prior": prior[-1][len("coupling prior: "):] if prior else "-",
            "milestones": (t.get("t50"), t.get("t90"), t.get("t99"))}


def _children_cpu() -> float:
    """User + system seconds of the finished child processes (steadier than the wall on a shared machine)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _line(label: str, r: dict) -> str:
    its = r["per_window"]
    late = its[5:] or its
    ms = "/".join("n/a" if m is None else f"{m:.4e}" for m in r["milestones"])
    return (f"{label:44s} {r['windows']:5d} {r['iterations']:6d} {r['iterations'] / max(r['windows'], 1):6.2f} "
            f"{sum(late) / len(late):6.2f} {r['wall']:7.1f} {r['cpu']:7.1f}  {ms}  [{r['prior']}]")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh-size", type=float, default=None, help="element size factor (default: the default mesh)")
    ap.add_argument("--devices", nargs="+", default=["shear"])
    ap.add_argument("--scheme", default="be", choices=("be", "bdf2"))
    ap.add_argument("--monolithic", action="store_true", help="also the monolithic BE run at dt = 5e-8")
    ap.add_argument("--adaptive", action="store_true", help="adaptive dt (the default tolerance)")
    ap.add_argument("--t-end", default=None, help="end time (default: until steady)")
    opts = ap.parse_args()
    mesh = [] if opts.mesh_size is None else ["--mesh-size", str(opts.mesh_size)]
    columns = f"{'wins':>5s} {'its':>6s} {'/win':>6s} {'/w>5':>6s} {'wall s':>7s} {'cpu s':>7s}"
    print(f"{'run':44s} {columns}  t50/t90/t99  [prior]")
    for device in opts.devices:
        base = ["run", device, "--transient", "--time-scheme", opts.scheme] + mesh
        base += (["--adaptive"] if opts.adaptive else []) + (["--t-end", opts.t_end] if opts.t_end else [])
        for label, extra in (("before (--jacobian-prior none)", ["--jacobian-prior", "none"]),
                             ("after (default: linearized per dt)", [])):
            kind = f"{opts.scheme}{' adaptive' if opts.adaptive else ''}"
            print(_line(f"{device} {kind} {label}", _run(base + extra)), flush=True)
        if opts.monolithic:
            args = ["run", device, "--transient", "--monolithic", "--dt", "5e-8", "--t-end", "3.35e-6"] + mesh
            print(_line(f"{device} monolithic BE dt 5e-8", _run(args)), flush=True)


if __name__ == "__main__":
    main()
