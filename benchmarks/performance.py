"""Performance of the shear-flow baseline with a cell: cost per mesh size, monolithic comparison, iterations.

    .venv/bin/python benchmarks/performance.py                       # what `make benchmark` prints
    .venv/bin/python benchmarks/performance.py --sizes 1 0.5 --ranks 2 --json perf.json

For each mesh-size factor (``--sizes``, default 1 0.5 0.25) it runs, each in a
process of its own (``--ranks N``: under ``mpirun -n N``):

* the partitioned solve (serial IQN-ILS to 1e-10, the defaults of ``gelcell run``; where the
  default has the linearized prior and this machine's prior cache does not hold it yet, the run
  is repeated and the warm one is printed, with the first one's solves' total),
* the monolithic solve of the same case,

and prints the dofs per field, the process wall time, the coupling
iterations, the solves' total and its time per coupling iteration per field
(also without the one-off factorisations), the median cost of an iteration
after the first (every solve back-substitutes with a kept factorisation: what
one more iteration costs), the peak memory (resident set of
the largest process), the monolithic Newton solve's time and the ratio of the
two, and the cost exponent fitted to solves' total ~ dofs^k.  Then the
iteration table of the baseline and the stiffness extremes (cell moduli x10,
gel moduli x0.1) at the default mesh, each with the secant model alone
(``jacobian_prior = "none"``) and with the linearized prior (the device default
at this size): computed (its setup time), then loaded from the prior cache (a
temporary directory, so the first run computes it).

Times are wall-clock seconds on whatever machine runs this: they are printed,
never asserted (tests assert physics, not speed).  On a shared machine repeat
the run and compare medians.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STIFFNESS_CASES = (("baseline", {}), ("cell x10", {"cell_moduli": 10.0}), ("gel x0.1", {"gel_moduli": 0.1}))


# -- one measurement, in a process of its own ----------------------------------------------------
def _params(mesh_size: float, cell_moduli: float | None, gel_moduli: float | None):
    from gelcell.case import CaseParameters
    p = CaseParameters.default("shear").with_mesh_size(mesh_size)
    if cell_moduli is not None:
        p = p.with_cell_moduli(cell_moduli)
    if gel_moduli is not None:
        p = p.with_gel_moduli(gel_moduli)
    return p


def _dofs(space) -> int:
    return space.dofmap.index_map.size_global * space.dofmap.index_map_bs


def measure_partitioned(p, comm, jacobian_prior: str = "default") -> dict:
    from gelcell.coupled.device import Device
    from gelcell.coupled.defaults import partitioned_config
    chosen = {} if jacobian_prior == "default" else {"acceleration": {"jacobian_prior": jacobian_prior}}
    config = partitioned_config(p, coupling=chosen)
    t0 = time.perf_counter()
    device = Device(p, comm)
    t1 = time.perf_counter()
    result = device.solve(config, verbose=False)
    t2 = time.perf_counter()
    fluid, gel = device.fluid.stats, device.gel.newton.stats
    cell = device.cell.stats if device.cell is not None else None
    factor = {"fluid": fluid["factor_time"], "gel": gel["factor_time"], "cell": cell["factor_time"] if cell else 0.0}
    dofs = {"fluid": _dofs(device.fluid.W), "gel": _dofs(device.gel.W)}
    if device.cell is not None:
        dofs["cell"] = _dofs(device.cell.V)
    return {"kind": "partitioned", "ranks": comm.size, "dofs": dofs, "iterations": result.iterations,
            "converged": result.converged, "setup": t1 - t0, "solves_total": t2 - t1,
            "field_time": dict(result.timing), "factor_time": factor, "steady_iteration": steady_iteration(result),
            "gel_linear_steps": gel.get("linear_steps"), "gel_newton_iterations": gel["newton_iterations"],
            "prior_setup": getattr(device.linearized_prior, "setup_time", 0.0),
            "prior_source": device.prior_source}


def steady_iteration(result) -> dict:
    """Median solve time per field of the iterations after the first (whose solves factorise).

    What an iteration costs once every field solve back-substitutes with its kept factorisation
    (issue 8, item 3), measured per iteration from the coupling records.
    """
    records = [rec for w in result.windows for rec in w.records][1:]
    names = sorted({n for rec in records for n in rec.solve_time})
    if not records:
        return {}
    out = {n: float(np.median([rec.solve_time.get(n, 0.0) for rec in records])) for n in names}
    out["total"] = float(np.median([sum(rec.solve_time.values()) for rec in records]))
    return out


def measure_monolithic(p, comm) -> dict:
    from gelcell.run.solve import solve_monolithic
    run = solve_monolithic(p, comm, checks=False)
    m = run.summary["monolithic"]
    return {"kind": "monolithic", "ranks": comm.size, "dofs": {"total": m["dofs"], "active": m["active_dofs"]},
            "newton_iterations": m["newton_iterations"], "setup": run.summary["timing"]["setup"],
            "solve": run.summary["timing"]["solve"]}


def child(args) -> None:
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    p = _params(args.mesh_size, args.cell_moduli, args.gel_moduli)
    out = (measure_partitioned(p, comm, args.jacobian_prior) if args.child == "partitioned"
           else measure_monolithic(p, comm))
    # peak resident set of this process (kilobytes on Linux), the largest over the ranks
    out["peak_mib"] = comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, op=MPI.MAX)
    if comm.rank == 0:
        print("RESULT " + json.dumps(out), flush=True)


# -- the driver ------------------------------------------------------------------------------------
def run_child(kind: str, mesh_size: float, ranks: int, timeout: float, env: dict | None = None, **moduli) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--child", kind, "--mesh-size", str(mesh_size)]
    for key, value in moduli.items():          # moduli, and the partitioned run's jacobian_prior
        cmd += [f"--{key.replace('_', '-')}", str(value)]
    if ranks > 1:
        mpirun = shutil.which("mpirun") or "mpirun"
        cmd = [mpirun, "-n", str(ranks)] + cmd
    env = dict(os.environ, **(env or {}), OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", MPLBACKEND="Agg")
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return {"kind": kind, "error": f"timed out after {timeout:.0f} s"}
    wall = time.perf_counter() - t0
    lines = [line for line in stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        return {"kind": kind, "error": f"exit {proc.returncode}: {stderr.strip().splitlines()[-1:]}"}
    out = json.loads(lines[-1][len("RESULT "):])
    out["wall"] = wall
    return out


def _available_mib() -> float:
    """MemAvailable of /proc/meminfo (inf where unknown)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("inf")


def _predicted_monolithic_mib(previous: list[dict], row: dict) -> float:
    """Peak memory of the monolithic run, from the last measured one times the growth of the dofs^1.15."""
    done = [r for r in previous if "peak_mib" in r["monolithic"] and "dofs" in r["partitioned"]]
    if not done or "dofs" not in row["partitioned"]:
        return 0.0
    last = done[-1]
    ratio = sum(row["partitioned"]["dofs"].values()) / sum(last["partitioned"]["dofs"].values())
    return last["monolithic"]["peak_mib"] * ratio ** 1.15


def fit_exponent(dofs, times) -> float:
    """k of time ~ dofs^k, least squares in log-log."""
    x, y = np.log(np.asarray(dofs, float)), np.log(np.asarray(times, float))
    ok = np.isfinite(x) & np.isfinite(y)
    return float(np.polyfit(x[ok], y[ok], 1)[0]) if ok.sum() >= 2 else float("nan")


def _f(x, fmt="{:.2f}") -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else fmt.format(x)


def _prior(r: dict) -> str:
    """The prior of a run: none, or linearized and where it came from (with the cold run's total)."""
    source = r.get("prior_source")
    if source is None:
        return "none"
    cold = f"; cold: {r['cold_solves_total']:.2f} s" if "cold_solves_total" in r else ""
    return f"linearized ({source}{cold})"


def print_tables(sizes_rows: list[dict], iteration_rows: list[dict], ranks: int) -> None:
    print(f"\nShear baseline with a cell, serial IQN-ILS to 1e-10, {ranks} MPI rank(s); times in s, "
          f"memory in MiB (largest process)")
    print("\n| mesh size | dofs fluid / gel / cell | prior | iterations | process wall | setup | solves' total "
          "| per iteration: fluid / gel / cell | ... without factorisations "
          "| iteration after the first: total (fluid / gel / cell) "
          "| factorisations | peak | monolithic dofs | monolithic Newton solve | monolithic wall "
          "| monolithic peak | solves' total / monolithic |")
    print("|---:|---|---|---:|---:|---:|---:|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in sizes_rows:
        part, mono = r["partitioned"], r["monolithic"]
        if "error" in part:
            print(f"| {r['mesh_size']:g} | partitioned: {part['error']} |")
            continue
        d, its, ft, fac = part["dofs"], part["iterations"], part["field_time"], part["factor_time"]
        per = " / ".join(f"{1e3 * ft.get(k, 0.0) / its:.1f}" for k in ("fluid", "gel", "cell")) + " ms"
        marg = " / ".join(f"{1e3 * (ft.get(k, 0.0) - fac.get(k, 0.0)) / max(its - 1, 1):.1f}"
                          for k in ("fluid", "gel", "cell")) + " ms"
        st = part.get("steady_iteration") or {}
        steady = (f"{1e3 * st['total']:.1f} ms (" + " / ".join(f"{1e3 * st.get(k, 0.0):.1f}"
                                                                for k in ("fluid", "gel", "cell")) + ")") if st else "-"
        mono_ok = "error" not in mono
        ratio = part["solves_total"] / mono["solve"] if mono_ok and mono["solve"] > 0 else None
        print(f"| {r['mesh_size']:g} | {d['fluid']} / {d['gel']} / {d.get('cell', 0)} | {_prior(part)} | {its} "
              f"| {part['wall']:.2f} "
              f"| {part['setup']:.2f} | {part['solves_total']:.2f} | {per} | {marg} | {steady} "
              f"| {sum(fac.values()):.2f} "
              f"| {part['peak_mib']:.0f} "
              + (f"| {mono['dofs']['total']} | {mono['solve']:.2f} ({mono['newton_iterations']} Newton) "
                 f"| {mono['wall']:.2f} | {mono['peak_mib']:.0f} | {_f(ratio)} |" if mono_ok
                 else f"| {mono['error']} | | | | |"))
    ok = [r for r in sizes_rows if "error" not in r["partitioned"]]
    if len(ok) >= 2:
        dofs = [sum(r["partitioned"]["dofs"].values()) for r in ok]
        k_part = fit_exponent(dofs, [r["partitioned"]["solves_total"] for r in ok])
        mono = [r for r in ok if "error" not in r["monolithic"]]
        k_mono = fit_exponent([sum(r["partitioned"]["dofs"].values()) for r in mono],
                              [r["monolithic"]["solve"] for r in mono]) if len(mono) >= 2 else float("nan")
        print(f"\nfitted cost exponent (time ~ dofs^k, dofs {min(dofs)} -> {max(dofs)}): partitioned solves' total "
              f"k = {k_part:.2f}, monolithic Newton solve k = {_f(k_mono)}")
    print("\nIterations to 1e-10 at the default mesh (serial IQN-ILS; prior: none = the secant model alone,"
          " or the linearized prior, computed or loaded from the prior cache; coupling.acceleration.jacobian_prior)")
    print("\n| case | prior | iterations | solves' total | of which the prior's setup | per iteration |")
    print("|---|---|---:|---:|---:|---:|")
    for r in iteration_rows:
        if "error" in r:
            print(f"| {r['case']} | {r['prior']} | {r['error']} | | | |")
            continue
        print(f"| {r['case']} | {_prior(r)} | {r['iterations']} | {r['solves_total']:.2f} | "
              f"{r.get('prior_setup', 0.0):.2f} | {1e3 * r['solves_total'] / r['iterations']:.0f} ms |")


# -- fixed costs of `gelcell run shear` ------------------------------------------------------------
def _wall(cmd: list[str], timeout: float) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT, env=dict(os.environ, MPLBACKEND="Agg"), stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, check=True, timeout=timeout)
    return time.perf_counter() - t0


def measure_fixed_costs(repeats: int, timeout: float) -> dict:
    """Median process walls of the phases of ``gelcell run shear`` (warm caches: one run first).

    interpreter (``python -c pass``), imports of the run path, the run without figures and the
    whole run; setup (meshing, forms, matrices) and the solves from the summary.json of the run
    without figures (in the whole run the figure worker imports matplotlib on the other core
    meanwhile, which slows the solves on a loaded machine).
    """
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "run")
        run = [py, "-m", "gelcell.cli", "run", "shear", "--quiet", "--out", out]
        _wall(run, timeout)                                  # warm the FFCx and mesh caches
        walls = {"interpreter": [], "imports": [], "run_no_figures": [], "run": []}
        timing = []
        for _ in range(repeats):
            walls["interpreter"].append(_wall([py, "-c", "pass"], timeout))
            walls["imports"].append(_wall([py, "-c", "import gelcell.cli, gelcell.run.steady"], timeout))
            walls["run_no_figures"].append(_wall(run + ["--no-figures"], timeout))
            with open(os.path.join(out, "summary.json")) as fh:     # the phases of the run they add up to
                timing.append(json.load(fh)["timing"])
            walls["run"].append(_wall(run, timeout))
    med = {k: float(np.median(v)) for k, v in walls.items()}
    med["setup"] = float(np.median([t["setup"] for t in timing]))
    med["solves"] = float(np.median([t["coupling"] for t in timing]))
    return med


def print_fixed_costs(c: dict) -> None:
    print("\nFixed costs of `gelcell run shear` (default mesh, warm caches; median process walls, s)")
    print("\n| python start | imports of the run path | setup (meshing, forms, matrices) | solves "
          "| results, checks, XDMF, profiles | figures | whole run |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    rest = c["run_no_figures"] - c["imports"] - c["setup"] - c["solves"]
    print(f"| {c['interpreter']:.2f} | {c['imports'] - c['interpreter']:.2f} | {c['setup']:.2f} | {c['solves']:.2f} "
          f"| {rest:.2f} | {c['run'] - c['run_no_figures']:.2f} | {c['run']:.2f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", type=float, default=[1.0, 0.5, 0.25])
    parser.add_argument("--ranks", type=int, default=1, help="MPI ranks of every measured run")
    parser.add_argument("--no-monolithic", action="store_true", help="skip the monolithic solves")
    parser.add_argument("--no-iterations", action="store_true", help="skip the iteration table")
    parser.add_argument("--fixed-costs", type=int, default=3, metavar="N",
                        help="repeats of the fixed-cost phases of `gelcell run shear` (0: skip)")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds allowed to each run")
    parser.add_argument("--json", help="write every measurement as JSON")
    # a single measurement (used by the driver)
    parser.add_argument("--child", choices=("partitioned", "monolithic"), help=argparse.SUPPRESS)
    parser.add_argument("--mesh-size", type=float, default=1.0, help=argparse.SUPPRESS)
    parser.add_argument("--cell-moduli", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--gel-moduli", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--jacobian-prior", choices=("default", "none", "linearized"), default="default",
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args)
        return 0
    sizes_rows, iteration_rows = [], []
    for size in args.sizes:
        part = run_child("partitioned", size, args.ranks, args.timeout)
        if part.get("prior_source") == "computed":            # the warm run; the first one's cost kept
            cold = part["solves_total"]
            part = {**run_child("partitioned", size, args.ranks, args.timeout), "cold_solves_total": cold}
        row = {"mesh_size": size, "partitioned": part}
        need = _predicted_monolithic_mib(sizes_rows, row)
        if args.no_monolithic:
            row["monolithic"] = {"error": "skipped"}
        elif need > 0.8 * _available_mib():
            row["monolithic"] = {"error": f"skipped: needs about {need / 1024:.1f} GiB (extrapolated), "
                                          f"{_available_mib() / 1024:.1f} GiB available"}
        else:
            row["monolithic"] = run_child("monolithic", size, args.ranks, args.timeout)
        sizes_rows.append(row)
        print(f"mesh size {size:g}: done", file=sys.stderr, flush=True)
    if not args.no_iterations:
        with tempfile.TemporaryDirectory() as priors:
            env = {"GELCELL_PRIOR_CACHE_DIR": priors}
            for name, moduli in STIFFNESS_CASES:
                for prior in ("none", "linearized", "linearized"):        # computed, then loaded
                    r = run_child("partitioned", 1.0, args.ranks, args.timeout, env, jacobian_prior=prior, **moduli)
                    iteration_rows.append({"case": name, "prior": prior, **r})
    fixed = measure_fixed_costs(args.fixed_costs, args.timeout) if args.fixed_costs > 0 and args.ranks == 1 else None
    print_tables(sizes_rows, iteration_rows, args.ranks)
    if fixed is not None:
        print_fixed_costs(fixed)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"ranks": args.ranks, "sizes": sizes_rows, "iterations": iteration_rows, "fixed_costs": fixed},
                      fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
