"""A steady run: solve one case (partitioned or monolithic) and write everything of it into one directory.

Used by ``gelcell run`` and ``gelcell sweep``; also importable::

    from gelcell.case import RunConfig
    from gelcell.run.steady import run_case
    summary = run_case(RunConfig(CaseParameters.default("shear")), out="results/shear")

The directory gets summary.json, the fields, the Gamma profiles, the
coupling records, the figures and ``case.toml``: the configuration the run
used, from which ``gelcell run --config DIR/case.toml`` repeats it.
"""

from __future__ import annotations

import os
import sys

from mpi4py import MPI

from femtools.io import atomic_directory, check_output_target, write_json
from gelcell.case import RunConfig
from gelcell.case.casefile import toml_text
from gelcell.coupled.defaults import partitioned_config
from gelcell.coupled.reuse import ReuseStore
from gelcell.geometry import described
from gelcell.output.fields import DerivedFields, write_fields
from gelcell.output.figures import FigureWorker, collect_figures, figure_data, figure_worker
from gelcell.output.profiles import write_profiles
from gelcell.output.summary import format_summary, report
from gelcell.post.quantities import gamma_profiles
from gelcell.post.residuals import format_residuals
from gelcell.run.solve import CaseRun, solve_monolithic, solve_partitioned

__all__ = ["run_case", "write_case_file", "run_header"]

#: the configuration a run used, in its output directory
CASE_FILE = "case.toml"


def write_case_file(directory: str, tables: dict, comm: MPI.Comm) -> str:
    """``directory/case.toml``: the configuration of the run (rank 0); returns its name."""
    if comm.rank == 0:
        with open(os.path.join(directory, CASE_FILE), "w", encoding="utf-8") as f:
            f.write(toml_text(tables, header="The configuration of this run: gelcell run --config case.toml "
                                             "--out DIR repeats it."))
    return CASE_FILE


def solver_arguments(config: RunConfig) -> dict:
    """The ``solver`` and ``petsc_options`` arguments of a partitioned device from ``[solver]``."""
    return {"solver": config.solver.kind, "petsc_options": config.solver.petsc or None}


def run_header(config: RunConfig, coupling: dict | None, extra: str = "") -> str:
    """The first line of a run: the device, its cells and what solves it (the resolved scheme)."""
    params = config.case
    n = len(params.geometry.cell_list()) if params.with_cell else 0
    cells = "without cell" if not n else "with cell" if n == 1 else f"{n} cells"
    method = ("monolithic" if coupling is None else
              f"partitioned ({coupling['scheme']}, {coupling['acceleration']['type']})")
    return f"gelcell: {params.label}, {cells}{extra}, {method}"


def _write_outputs(tmp: str, run: CaseRun, summary: dict, tables: dict, comm, *, monolithic: bool, figures: bool,
                   fields: bool, overlay_profiles: dict | None, extra_json: dict | None,
                   worker: FigureWorker | None) -> list[str]:
    """Write every file of a steady run into ``tmp`` (summary.json last); returns the names written.

    The figures' data is gathered first; a ``worker`` draws them while this
    process writes the fields, profiles and records (if it fails, they are
    drawn here).
    """
    written = ["summary.json", write_case_file(tmp, tables, comm)]
    derived = DerivedFields(run.fields) if fields or figures else None     # shared by XDMF and figures
    profiles = write_profiles(tmp, run.fields, comm)                      # the figures show them: first
    data = figure_data(run.fields, profiles, summary, overlay_profiles, derived) if figures else None
    if worker is not None and data is not None:
        worker.submit(tmp, data)
    if fields:
        written += write_fields(tmp, run.fields, derived)
    written += [f"{k.lower()}_profiles.{ext}" for k in profiles for ext in ("h5", "csv")]
    if not monolithic:
        run.solver.scheme.write_records(os.path.join(tmp, "coupling"))
        written.append("coupling/")
    if data is not None:
        written += collect_figures(tmp, data, worker)
    for name, value in (extra_json or {}).items():
        write_json(os.path.join(tmp, name), value, comm)
        written.append(name)
    summary["files"] = written
    write_json(os.path.join(tmp, "summary.json"), summary, comm)
    return written


def _without_cell(config: RunConfig, comm: MPI.Comm, say) -> tuple[dict, dict]:
    """The case without its cell, solved first (partitioned): its Gamma1 profiles (overlaid) and its summary."""
    say("gelcell: first the same case without the cell, for the profile comparison")
    params = config.case.replace(with_cell=False)
    # every field on every rank: the groups of [coupling] distribute name the cell
    coupling = {k: v for k, v in (config.coupling or {}).items() if k != "distribute"}
    ref = solve_partitioned(params, coupling, comm=comm, verbose=config.output.progress, checks=False,
                            gamma2=config.solver.gamma2, **solver_arguments(config))
    return gamma_profiles(ref.fields, "Gamma1"), {"summary_no_cell.json": report(ref.summary, params)}


def _say_results(summary: dict, say, comm: MPI.Comm) -> None:
    say(format_summary(summary))
    if "interface_residuals" in summary:
        say(format_residuals(summary["interface_residuals"]))
    if comm.rank == 0:
        for warning in summary["model"]["warnings"]:
            print(f"gelcell: warning: {warning}", file=sys.stderr, flush=True)


def run_case(config: RunConfig, out: str | None, *, comm: MPI.Comm = MPI.COMM_WORLD, stream=None,
             fields: bool = True, shown_path: str | None = None, reuse: ReuseStore | None = None) -> dict:
    """Solve the case of ``config`` and write its outputs into ``out`` (whole or not at all).

    ``out`` and the model's limits are checked before anything is meshed; the
    model's warnings go to stderr and to ``model.warnings`` in the summary.
    ``shown_path`` is the path printed for ``out`` (the final path of a run
    written inside a sweep's temporary directory).
    """
    stream = stream or sys.stdout
    say = (lambda msg: print(msg, file=stream, flush=True)) if comm.rank == 0 else (lambda msg: None)
    config = config.replace(case=described(config.case))
    params, monolithic, figures = config.case, config.solver.monolithic, config.output.figures
    if out is not None:
        check_output_target(out, comm)
    coupling = None if monolithic else partitioned_config(params, config.coupling, gamma2=config.solver.gamma2)
    overlay, extra = None, {}
    if config.output.compare_no_cell and params.with_cell:
        overlay, extra = _without_cell(config, comm, say)
    say(run_header(config, coupling))
    # a serial run draws its figures in a second process, which imports matplotlib while this one solves
    with figure_worker(out is not None and figures, comm) as worker:
        if monolithic:
            run = solve_monolithic(params, comm, solver=config.solver.kind)
        else:
            run = solve_partitioned(params, coupling, comm, config.output.progress, gamma2=config.solver.gamma2,
                                    reuse=reuse, **solver_arguments(config))
        summary = report(run.summary, params)
        _say_results(summary, say, comm)
        if out is None:
            return summary
        with atomic_directory(out, comm) as tmp:
            try:
                written = _write_outputs(tmp, run, summary, config.to_tables(coupling=coupling), comm,
                                         monolithic=monolithic, figures=figures, fields=fields,
                                         overlay_profiles=overlay, extra_json=extra, worker=worker)
            finally:
                if worker is not None:
                    worker.close()          # before the directory is promoted or removed
    say(f"wrote {shown_path or os.path.abspath(out)}: " + ", ".join(written))
    return summary
