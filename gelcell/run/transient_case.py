"""A time-dependent run of one case from rest (or resumed), written whole into one directory.

While it runs, ``DIR.partial/`` holds its configuration (``case.toml``),
the last window's checkpoint and the frames; when every file has been
written it becomes ``DIR`` (:func:`femtools.io.atomic_directory`).
"""

from __future__ import annotations

import os
import shutil
import sys
import time

import numpy as np

from mpi4py import MPI

from femtools.io import atomic_directory, write_json
from gelcell.case import RunConfig
from gelcell.coupled.defaults import partitioned_config
from gelcell.coupled.device import Device
from gelcell.geometry import described
from gelcell.output.fields import DerivedFields, FieldSeries
from gelcell.output.figures import FigureWorker, collect_figures, figure_data, figure_worker
from gelcell.output.profiles import write_profiles
from gelcell.output.summary import format_summary, report
from gelcell.output.timeseries import write_timeseries
from gelcell.post.milestones import time_summary, transient_summary
from gelcell.post.validity import model_warnings
from gelcell.run.backends import MonolithicBackend, PartitionedBackend
from gelcell.run.cost import cost_summary, device_unknowns, monolithic_unknowns
from gelcell.run.frames import FRAMES_DIR, read_frame
from gelcell.run.resume import CHECKPOINT
from gelcell.run.solve import monolithic_solver_kind, monolithic_solver_summary, solver_summary
from gelcell.run.steady import run_header, solver_arguments, write_case_file
from gelcell.run.transient import TransientRun

__all__ = ["run_transient_case"]


def _fmt(value) -> str:
    """A time for the progress line: 4 digits, or 'n/a' when undefined (e.g. no motion)."""
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.4e}"


def _header(config: RunConfig, coupling: dict | None, plan: dict) -> list[str]:
    params, settings, scales = config.case, config.time, plan["scales"]
    stepping = f", time-dependent ({settings.scheme}, {'adaptive' if settings.adaptive else 'fixed'} dt)"
    until = "steady" if plan["t_end"] is None else f"t = {plan['t_end']:.4e}"
    if plan["until_periodic"]:
        until = (f"periodic (period {plan['period']:.4e}, {plan['steps_per_period']} steps per period, "
                 f"periodic_tol {settings.periodic_tol:.1e}, at most {settings.max_cycles} cycles)")
    return [run_header(config, coupling, stepping) + f", inflow {settings.inflow}",
            f"time scales: consolidation {scales['consolidation']:.3e} "
            f"({params.to_si(scales['consolidation'], 'time'):.3e} s), Kelvin-Voigt {scales['kelvin_voigt']:.3e}; "
            f"dt = {plan['dt']:.3e}, until {until}"
            f"{' or steady' if plan['t_end'] is not None and settings.until_steady else ''}"]


def _backend(config: RunConfig, coupling: dict | None, comm: MPI.Comm):
    settings = config.time
    if coupling is None:
        return MonolithicBackend(config.case, comm, settings.scheme, settings.waveform,
                                 solver=monolithic_solver_kind(config.solver.kind))
    device = Device(config.case, comm, gamma2=config.solver.gamma2, transient=True, time_scheme=settings.scheme,
                    inflow=settings.waveform, distribute=coupling.get("distribute"), **solver_arguments(config))
    return PartitionedBackend(device, {**coupling, "verbose": False}, comm)


def _prior_words(backend: PartitionedBackend) -> str:
    if backend.scheme.linearized_prior is None:
        return "the secant model alone (jacobian_prior = none)"
    return ("linearized per dt: the exact interface Jacobian of one step, factorised for each step size "
            "and scheme (jacobian_prior = linearized)")


def _summary(run: TransientRun, backend, state: dict, config: RunConfig, setup_time: float) -> dict:
    """summary.json of the finished run: the final state's quantities, the milestones, the model's limits."""
    params = config.case
    raw = run.quantities.summary()
    raw["method"] = backend.method
    summary = report(raw, params)
    summary["coupling"] = backend.describe()
    summary["solver"] = (solver_summary(backend.device) if backend.method == "partitioned" else
                         monolithic_solver_summary(config.solver.kind, backend.solver))
    summary["cost"] = cost_summary(device_unknowns(backend.device) if backend.method == "partitioned" else
                                   monolithic_unknowns(backend.solver), backend.comm)
    summary["transient"] = transient_summary(state, params, config.time, run.plan)
    summary["time"] = time_summary(state, params, config.time, run.plan, summary["transient"], run.start_steps)
    if run.periodic is not None:
        summary["periodic"] = run.periodic.summary(state["rows"], params)
    if params.with_cell:
        # the model's limits over the whole run, not only at its end (e.g. the peaks of a pulsatile inflow)
        model = summary["model"]
        model["max_cell_strain"] = max(r["cell_strain_max"] for r in state["rows"])
        model["warnings"] = model_warnings(model)
    summary["timing"] = {"setup": setup_time, "time_stepping": state["wall_time"]}
    return summary


def _say_summary(summary: dict, say, comm: MPI.Comm) -> None:
    if comm.rank == 0:
        for warning in summary["model"]["warnings"]:
            print(f"gelcell: warning: {warning}", file=sys.stderr, flush=True)
    t = summary["transient"]
    say(format_summary(summary))
    say(f"time-dependent: {t['windows']} windows to t = {t['t_end']:.4e} ({t['t_end_s']:.3e} s), "
        f"{t['iterations_total']} iterations (mean {t['iterations_mean']:.2f}), "
        f"t50/t90/t99 = {_fmt(t['t50'])}/{_fmt(t['t90'])}/{_fmt(t['t99'])}, "
        f"relaxation time {_fmt(t['relaxation_time'])} (paper units)")
    say(_time_words(summary["time"]))
    if "periodic" in summary:
        _say_periodic(summary["periodic"], say, comm)
    prior = summary.get("coupling", {}).get("jacobian_prior")
    if prior is not None:
        say(f"coupling prior: {prior}")


def _time_words(block: dict) -> str:
    """The line that says the scheme, the step control and the milestones' estimated errors."""
    control = block["step_control"]
    steps = (f"fixed dt = {control['dt']:.4e} (tau_c/{1 / control['dt_over_tau_c']:.4g})"
             if control["kind"] == "fixed" else f"adaptive dt (time_tol {control['time_tol']:.1e})")
    if control.get("start"):
        steps += " after " + ", ".join(f"{f:g} dt" for f in control["start"]) + " from rest"
    if block["scheme"] == "bdf2":
        steps += " (the first step backward Euler)"
    error = block["estimated_error"]
    words = ("not estimated (no milestones of a step start)" if error is None else
             "/".join(f"{error[q]:+.2%}" for q in ("t50", "t90", "t99")) + " of t50/t90/t99 (> 0: late)")
    return f"time discretisation: {block['scheme_words']}, {steps}; estimated error {words}"


def _say_periodic(block: dict, say, comm: MPI.Comm) -> None:
    """The periodic block's headline: cycles, the last change, the last cycle's ranges and the lag."""
    change = "n/a" if block["change"] is None else f"{block['change']:.2e}"
    if not block["converged"] and comm.rank == 0:
        print(f"gelcell: warning: the response is not periodic after {block['cycles']} cycles (time.max_cycles): "
              f"cycle-to-cycle change {change} >= periodic_tol {block['tolerance']:.1e}",
              file=sys.stderr, flush=True)
    last = block["per_cycle"][-1]
    ranges = "; ".join(f"{name} {last[name]['min']:.4e}/{last[name]['mean']:.4e}/{last[name]['max']:.4e}"
                       for name in ("cell_strain", "cell_stress", "network_displacement") if name in last)
    lag = block["phase_lag"]
    lag_words = "n/a" if lag is None else (f"{lag['quantity']} {lag['time']:.4e} ({lag['time_s']:.3e} s, "
                                           f"{lag['degrees']:.1f} degrees)")
    say(f"periodic: {'converged' if block['converged'] else 'NOT converged'} after {block['cycles']} cycles of "
        f"{block['period']:.4e} (change {change}); last cycle min/mean/max: {ranges} (paper units); "
        f"phase lag behind the inflow: {lag_words}")


def _write_fields(work_dir: str, backend, state: dict, comm: MPI.Comm) -> list[str]:
    """The XDMF series of every frame, read back from ``DIR.partial/frames``."""
    derived = DerivedFields(backend.fields)
    series = FieldSeries(work_dir, derived)
    for index, t_frame in state["frames"]:
        read_frame(os.path.join(work_dir, FRAMES_DIR), int(index), backend.fields, comm)
        derived.update()
        series.write(float(t_frame))
    return series.names


def _write_results(work_dir: str, backend, state: dict, summary: dict, config: RunConfig, comm: MPI.Comm,
                   worker: FigureWorker | None, fields: bool) -> None:
    """Every file of the finished run into ``work_dir`` (summary.json last); the checkpoint is then removed."""
    written = ["summary.json", "case.toml", "timeseries.csv", "timeseries.h5"]
    write_timeseries(work_dir, state["rows"], config.case, comm)
    # the final state's profiles and figure data first: the worker draws while the frames are written
    profiles = write_profiles(work_dir, backend.fields, comm)
    data = figure_data(backend.fields, profiles, summary) if config.output.figures else None
    if worker is not None and data is not None:
        worker.submit(work_dir, data)
    if fields:
        written += _write_fields(work_dir, backend, state, comm)
    written += [f"{k.lower()}_profiles.{ext}" for k in profiles for ext in ("h5", "csv")]
    backend.write_records(os.path.join(work_dir, "coupling"))
    if backend.method == "partitioned":
        written.append("coupling/")
    if data is not None:
        from gelcell.output.drawing import draw_transient_figures      # imports matplotlib
        written += collect_figures(work_dir, data, worker)
        written += draw_transient_figures(work_dir, state["rows"], summary, config.case, comm)
        if "periodic" in summary:
            from gelcell.output.drawing import draw_periodic_figure
            written += draw_periodic_figure(work_dir, state["rows"], summary["periodic"], config.case, comm)
    summary["files"] = written
    write_json(os.path.join(work_dir, "summary.json"), summary, comm)
    if comm.rank == 0:
        os.remove(os.path.join(work_dir, CHECKPOINT))
        shutil.rmtree(os.path.join(work_dir, FRAMES_DIR), ignore_errors=True)
    comm.Barrier()


def run_transient_case(config: RunConfig, out: str | None, *, comm: MPI.Comm = MPI.COMM_WORLD,
                       fields: bool = True, resume: bool = False, stream=None) -> dict:
    """Run the case of ``config`` in time from rest (or resume it) and write its outputs into ``out``."""
    stream = stream or sys.stdout
    say = (lambda msg: print(msg, file=stream, flush=True)) if comm.rank == 0 else (lambda msg: None)
    config = config.replace(case=described(config.case))
    coupling = None if config.solver.monolithic else partitioned_config(
        config.case, config.coupling, transient=True, gamma2=config.solver.gamma2)
    plan = config.time.resolved(config.case)
    for line in _header(config, coupling, plan):
        say(line)
    t0 = time.perf_counter()
    backend = _backend(config, coupling, comm)
    setup_time = time.perf_counter() - t0
    if coupling is not None:
        say(f"coupling prior: {_prior_words(backend)}")

    def solve_and_write(work_dir: str | None, worker: FigureWorker | None = None) -> dict:
        run = TransientRun(backend, config.case, config.time, comm, work_dir, say)
        if resume:
            run.resume()
            say(f"resumed from {run.checkpoint_path}: window {run.state['windows']}, t = {run.state['t']:.6e}")
        elif work_dir is not None:
            write_case_file(work_dir, config.to_tables(coupling=coupling), comm)
        state = run.run()
        summary = _summary(run, backend, state, config, setup_time)
        _say_summary(summary, say, comm)
        if work_dir is not None:
            _write_results(work_dir, backend, state, summary, config, comm, worker, fields)
        return summary

    if out is None:
        return solve_and_write(None)
    # a serial run's device figures are drawn by a second process, which imports matplotlib meanwhile
    with figure_worker(config.output.figures, comm) as worker:
        with atomic_directory(out, comm, partial=True) as work_dir:
            try:
                summary = solve_and_write(work_dir, worker)
            finally:
                if worker is not None:
                    worker.close()          # before the directory is promoted or left as DIR.partial
    say(f"wrote {os.path.abspath(out)}: " + ", ".join(summary["files"]))
    return summary
