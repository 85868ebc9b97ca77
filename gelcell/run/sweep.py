"""``gelcell sweep``: one case per value of a parameter, tabulated and plotted.

A value whose run fails (the coupling diverges, a solver fails, ...) does not
discard the others: the sweep writes every completed run, lists the failed
values with their error in sweep.csv/sweep.json, and then raises
:class:`gelcell.errors.SweepError`.

Reuse (``--param ca``).  In the solver's units (stress Ca mu_s, displacement
Ca L0) every value of a Ca sweep is the same coupled problem up to the
strain-sized nonlinearity (gelcell.coupled.defaults.reuse_key).  Each value after the
first therefore starts from the previous values' interface data and field
states extrapolated in Ca (gelcell.coupled.reuse.ReuseStore), with the linearized
prior's factorisation under the prior (the default) and the quasi-Newton
columns otherwise (gelcell.coupled.device.Device.solve); sweep.csv records
``iterations`` and ``reused``.
Other sweeps change the interface operator and start from rest.

Beyond linearity (``--param ca``).  At fixed moduli Ca sets the flow speed;
the flow is Ca-independent in the paper's units and every displacement,
strain and stress is proportional to Ca as long as the response is linear.
``linearity.png`` plots a few of them divided by Ca (normalised by their
value at the smallest Ca, so linear scaling is a flat line at 1) and shows
where that ends.  ``compare_kinematics`` also runs every value on the other
kinematics path (``runs/<param>=<value>-small`` or ``-finite``) and records
``departure``: the largest relative difference of those quantities between
the small-strain and the finite-strain result (relative to the latter).
"""

from __future__ import annotations

import csv
import os
import sys
import traceback

from mpi4py import MPI

from femtools.io import atomic_directory, write_json
from gelcell.case import CaseParameters, OutputSettings, RunConfig
from gelcell.coupled.reuse import ReuseStore
from gelcell.errors import ParameterError, SweepError, exit_code, message
from gelcell.output.sweepfigures import LINEARITY_QUANTITIES, SWEEP_QUANTITIES, plot_linearity, plot_sweep
from gelcell.run.steady import run_case, write_case_file

__all__ = ["run_sweep", "sweep_cases", "swept_case", "run_name", "check_distinct"]


def departure(small: dict, finite: dict) -> float | None:
    """max over LINEARITY_QUANTITIES of |small - finite| / |finite| (None if none is present)."""
    values = [abs(small[k] - finite[k]) / abs(finite[k]) for k in LINEARITY_QUANTITIES
              if small.get(k) is not None and finite.get(k) not in (None, 0)]
    return max(values) if values else None


def _row(summary: dict) -> dict:
    row = {}
    for name, key, sub in SWEEP_QUANTITIES:
        v = summary.get(key)
        row[name] = None if v is None else (v if sub is None else v[sub])
    c = summary.get("coupling") or {}
    row["iterations"] = c.get("iterations")
    row["reused"] = c.get("reused")
    row["converged"] = c.get("converged", True)
    row["Ca"] = summary["parameters"]["dimensionless"]["Ca"] if "dimensionless" in summary["parameters"] else None
    row["model_warnings"] = "; ".join(summary["model"]["warnings"])
    return row


def run_name(param: str, value: float) -> str:
    """The directory of one run: ``runs/<param>=<value>`` (6 significant digits)."""
    return f"{param}={value:g}"


def check_distinct(param: str, values: list[float]) -> None:
    """Raise :class:`ParameterError` if two values would share a run (and its directory)."""
    names = [run_name(param, v) for v in values]
    repeated = sorted({n for n in names if names.count(n) > 1}, key=names.index)
    if repeated:
        raise ParameterError(f"--values gives {', '.join(repeated)} more than once (values equal to 6 "
                             f"significant digits are one run): give each value once")


def swept_case(params: CaseParameters, name: str, value: float) -> CaseParameters:
    """The case with one swept parameter set (model.md section 5)."""
    if name == "ca":
        return params.with_ca(value)
    if name == "cell-moduli":
        return params.with_cell_moduli(value)
    if name == "gel-moduli":
        return params.with_gel_moduli(value)
    if name == "e":
        return params.with_e(value)
    raise ParameterError(f"parameter 'sweep.param' = {name!r} is not one of ca, cell-moduli, gel-moduli, e")


def sweep_cases(config: RunConfig) -> list[CaseParameters]:
    """The case of every value of ``config.sweep``, each validated (before anything is meshed)."""
    sweep = config.sweep
    if sweep is None:
        raise ParameterError("a sweep needs its parameter and values: --param and --values, or a [sweep] table")
    check_distinct(sweep.param, sweep.values)
    return [swept_case(config.case, sweep.param, v) for v in sweep.values]


def _run_value(config: RunConfig, params: CaseParameters, name: str, tmp: str, final: str, comm: MPI.Comm,
               stores: dict) -> list[dict]:
    """The runs of one value (and of its other kinematics path if compared); their summaries."""
    other = ("small" if params.kinematics == "finite" else "finite") if config.sweep.compare_kinematics else None
    runs = [(name, params)] + ([(f"{name}-{other}", params.with_kinematics(other))] if other else [])
    output = OutputSettings(figures=False, progress=config.output.progress)
    return [run_case(config.replace(case=p, output=output, sweep=None), os.path.join(tmp, "runs", n), comm=comm,
                     fields=False, shown_path=os.path.join(final, "runs", n),
                     reuse=stores.setdefault(p.kinematics, ReuseStore()))
            for n, p in runs]


def _value_row(param: str, value: float, params: CaseParameters, summaries: list[dict], compared: bool) -> dict:
    row = {param: value, "status": "ok", "error": "", "kinematics": params.kinematics, **_row(summaries[0])}
    if compared:
        other = "small" if params.kinematics == "finite" else "finite"
        names = {n for n, _, _ in SWEEP_QUANTITIES} | {"iterations"}
        row.update({f"{other}.{k}": v for k, v in _row(summaries[1]).items() if k in names})
        by_path = {params.kinematics: _row(summaries[0]), other: _row(summaries[1])}
        row["departure"] = departure(by_path["small"], by_path["finite"])
    return row


def _write_tables(tmp: str, rows: list[dict], config: RunConfig, cases: list[CaseParameters], comm: MPI.Comm) -> None:
    """sweep.json, sweep.csv, the sweep's case.toml and its figures."""
    write_json(os.path.join(tmp, "sweep.json"), rows, comm)
    write_case_file(tmp, config.to_tables(), comm)
    if comm.rank != 0:
        return
    with open(os.path.join(tmp, "sweep.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)), restval="")
        w.writeheader()
        w.writerows(rows)
    done = [r for r in rows if r["status"] == "ok"]
    if done:
        plot_sweep(os.path.join(tmp, "sweep.png"), done, config.sweep.param, cases[0])
        if config.sweep.param == "ca":
            plot_linearity(os.path.join(tmp, "linearity.png"), done, cases[0])


def run_sweep(config: RunConfig, out: str, *, comm: MPI.Comm = MPI.COMM_WORLD, debug: bool = False) -> list[dict]:
    """Run every value of ``config.sweep``; write sweep.csv/json, sweep.png and runs/<param>=<value>/.

    ``param == "ca"`` also draws linearity.png; ``compare_kinematics`` runs each value on the other
    kinematics path too (module docstring).

    Values must be distinct (:func:`check_distinct`).  A value that fails is
    recorded (``status`` "failed", ``error``) and the sweep goes on; if any
    failed, :class:`SweepError` is raised after the completed runs are written.
    An interruption (SIGINT, SIGTERM) discards the whole sweep.
    """
    cases = sweep_cases(config)
    param, values = config.sweep.param, config.sweep.values
    final = os.path.abspath(out)
    rows, failures = [], []
    # one store per kinematics path: consecutive values of the same scaled problem (a Ca sweep) reuse the
    # previous values' interface data and the prior or the quasi-Newton columns
    stores: dict[str, ReuseStore] = {}
    with atomic_directory(out, comm) as tmp:
        for value, params in zip(values, cases):
            name = run_name(param, value)
            try:
                summaries = _run_value(config, params, name, tmp, final, comm, stores)
            except Exception as exc:  # noqa: BLE001  (one failed value must not discard the others)
                if comm.rank == 0:
                    if debug:
                        traceback.print_exc()
                    print(f"gelcell sweep: {name} failed: {message(exc)}", file=sys.stderr, flush=True)
                failures.append((value, message(exc), exit_code(exc)))
                rows.append({param: value, "status": "failed", "error": message(exc)})
                continue
            rows.append(_value_row(param, value, params, summaries, config.sweep.compare_kinematics))
        _write_tables(tmp, rows, config, cases, comm)
    if comm.rank == 0:
        print(f"gelcell sweep: wrote {final}: sweep.csv, sweep.json"
              + (", sweep.png" if len(failures) < len(values) else "")
              + (", linearity.png" if len(failures) < len(values) and param == "ca" else "") + ", case.toml"
              + f", runs/ ({len(values) - len(failures)} of {len(values)} values)", flush=True)
    if failures:
        raise SweepError(f"{len(failures)} of {len(values)} values failed ("
                         + ", ".join(run_name(param, v) for v, _, _ in failures)
                         + f"; why: the lines above and the error column of sweep.csv); the completed "
                         f"runs are in {final}", failures)
    return rows


