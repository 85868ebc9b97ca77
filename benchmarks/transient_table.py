"""Issue 31's benchmark in one call: every way to run a device from rest to steady, side by side.

Per device (default: both, with their cell, default mesh), one ``gelcell run`` process after
another (``--no-figures --quiet --out`` a temporary directory), the wall time of each command
as a user sees it:

* ``steady, prior computed`` and ``steady, prior from cache``: ``gelcell run CASE`` with an
  empty prior cache, then again (the linearized prior is cached on disk: a steady run's, and
  a time-dependent run's per operator);
* ``default``: ``--transient`` (BDF2, dt = tau_c/40, graded start, until steady), then again
  with its priors from the cache (``default, priors cached``);
* ``default dt/2``, ``default dt/4``: the same with ``--dt``, for the Richardson limit of the
  milestones (formal order 2):  m0 = m4 + (m4 - m2) / 3;
* ``BE tau_c/40``: ``--time-scheme be``;
* ``adaptive TOL``: ``--adaptive --time-tol TOL`` for each ``--time-tol``, each again with the
  priors the first run left in the cache (at most half the cache per run: some are computed again);
* ``monolithic BE 5e-8``: ``--monolithic --time-scheme be --dt 5e-8``, to ``--t-end 3.35e-6``
  for the shear device (the run issue 31 measured) and until steady for the normal device
  (3.35e-6 is half its consolidation time).

Printed per run: windows, coupling iterations (Newton iterations for the monolithic run), the
priors computed and loaded (partitioned time-dependent runs), wall,
its ratio to the steady run (prior from cache) and to the monolithic run, and t50/t90/t99 with
their relative error against the Richardson limit.  Timings are printed, never asserted.

    .venv/bin/python benchmarks/transient_table.py [--case shear normal] [--mesh-size 1] [--json table.json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MILESTONES = ("t50", "t90", "t99")
#: the monolithic reference of issue 31: the source paper's step, and the shear run's end
MONOLITHIC_DT, SHEAR_T_END = 5e-8, 3.35e-6


def gelcell(args: list[str], work: str, env: dict) -> tuple[float, dict]:
    """Run ``gelcell run ARGS`` into a new directory under ``work``: its wall time and summary."""
    out = tempfile.mkdtemp(dir=work)
    os.rmdir(out)                                   # gelcell creates DIR itself
    executable = os.path.join(os.path.dirname(sys.executable), "gelcell")
    command = [executable, "run", *args, "--no-figures", "--quiet", "--out", out]
    t0 = time.perf_counter()
    subprocess.run(command, check=True, cwd=ROOT, env=env, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    with open(os.path.join(out, "summary.json")) as fh:
        return wall, json.load(fh)


def transient_row(wall: float, summary: dict) -> dict:
    tr = summary["transient"]
    priors = re.search(r"(\d+) computed, (\d+) from the disk cache", summary["coupling"].get("jacobian_prior") or "")
    return {"wall": wall, "windows": tr["windows"], "iterations": tr["iterations_total"],
            "priors": "–" if priors is None else f"{priors.group(1)}/{priors.group(2)}",
            "rejected": tr["rejected_windows"], "t_end": tr["t_end"], **{q: tr[q] for q in MILESTONES}}


def device_rows(case: str, mesh_size: float, tolerances: list[float], work: str) -> dict:
    """Every run of one device, in the order of the module docstring."""
    env = dict(os.environ, GELCELL_PRIOR_CACHE_DIR=tempfile.mkdtemp(dir=work))
    base = [case, "--mesh-size", f"{mesh_size:g}"]
    rows = {}
    for label in ("steady, prior computed", "steady, prior from cache"):
        wall, summary = gelcell(base, work, env)
        rows[label] = {"wall": wall, "iterations": summary["coupling"]["iterations"]}
    wall, summary = gelcell(base + ["--transient"], work, env)
    rows["default"] = transient_row(wall, summary)
    rows["default, priors cached"] = transient_row(*gelcell(base + ["--transient"], work, env))
    dt = summary["transient"]["settings"]["dt_used"]
    for k in (2, 4):
        rows[f"default dt/{k}"] = transient_row(*gelcell(base + ["--transient", "--dt", repr(dt / k)], work, env))
    rows["BE tau_c/40"] = transient_row(*gelcell(base + ["--transient", "--time-scheme", "be"], work, env))
    for tol in tolerances:
        adaptive = base + ["--transient", "--adaptive", "--time-tol", f"{tol:g}"]
        rows[f"adaptive {tol:g}"] = transient_row(*gelcell(adaptive, work, env))
        rows[f"adaptive {tol:g}, priors cached"] = transient_row(*gelcell(adaptive, work, env))
    mono = base + ["--transient", "--monolithic", "--time-scheme", "be", "--dt", f"{MONOLITHIC_DT:g}"]
    mono += ["--t-end", f"{SHEAR_T_END:g}"] if case == "shear" else []
    rows["monolithic BE 5e-8"] = transient_row(*gelcell(mono, work, env))
    return rows


def limits(rows: dict) -> dict:
    """The Richardson limit of each milestone from the default scheme at dt, dt/2, dt/4."""
    m = [rows[k] for k in ("default", "default dt/2", "default dt/4")]
    return {q: m[2][q] + (m[2][q] - m[1][q]) / 3 for q in MILESTONES}


def table(case: str, rows: dict) -> list[str]:
    limit = limits(rows)
    cold, warm = rows["steady, prior computed"], rows["steady, prior from cache"]
    steady, mono = warm["wall"], rows["monolithic BE 5e-8"]["wall"]
    lines = [f"{case}: steady {cold['wall']:.1f} s (prior computed), {steady:.1f} s (prior from cache), "
             f"{warm['iterations']} iterations; Richardson limits "
             + ", ".join(f"{q} {limit[q]:.5e}" for q in MILESTONES),
             "| run | windows | iterations | priors computed/loaded | wall | /steady | /monolithic | "
             + " | ".join(f"{q} (error)" for q in MILESTONES) + " |",
             "|---" * 10 + "|"]
    for label, r in rows.items():
        if label.startswith("steady"):
            continue
        cells = " | ".join(f"{r[q]:.4e} ({(r[q] - limit[q]) / limit[q]:+.2%})" for q in MILESTONES)
        lines.append(f"| {label} | {r['windows']} | {r['iterations']} | {r['priors']} | {r['wall']:.1f} s | "
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
    with tempfile.TemporaryDirectory() as work:
        results = {case: device_rows(case, args.mesh_size, args.time_tol, work) for case in args.case}
    print(f"mesh size {args.mesh_size:g}, with the cell, from rest, serial, one command after another; "
          f"errors against the Richardson limit of the default scheme")
    for case, rows in results.items():
        print("\n".join(table(case, rows)))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()
