"""The ``gelcell`` commands: mesh, run (steady, time-dependent, resumed), sweep, study.

Each command resolves its configuration once (:func:`run_config`: defaults
< ``--config`` < options), checks everything that can be checked before
anything is meshed (the parameters and the ``[coupling]`` table, the model's
limits, the output directory), then runs.
"""

from __future__ import annotations

import argparse
import os

from mpi4py import MPI

from gelcell.case import CaseParameters, RunConfig, load_run_config, resolve
from gelcell.case.parameters import CASE_TABLES
from gelcell.cli.parser import command_line_keys
from gelcell.errors import ParameterError

__all__ = ["cmd_mesh", "cmd_run", "cmd_sweep", "cmd_study", "run_config"]


def run_config(args: argparse.Namespace) -> RunConfig:
    """The validated configuration of the options of ``args`` and its ``--config`` file (nothing meshed)."""
    keys = command_line_keys(args)
    if getattr(args, "geometry", None) is not None:
        if getattr(args, "case", None) is not None:
            raise ParameterError(f"give either the device name ({args.case}) or --geometry {args.geometry}, "
                                 f"not both")
        if "geometry.cells" in keys or "geometry.e" in keys:
            raise ParameterError(f"--{'cells' if 'geometry.cells' in keys else 'e'} places the cells of a built-in "
                                 f"device; the cells of --geometry {args.geometry} come from the file")
    if "geometry.cells" in keys and "geometry.e" in keys:
        raise ParameterError("give either --e (the one cell) or --cells, not both")
    if not args.config and "case.name" not in keys and "geometry.file" not in keys:
        raise ParameterError("give the device geometry (shear or normal), --geometry FILE or a --config file")
    if keys.get("solver.method") == "monolithic" and "coupling.acceleration.jacobian_prior" in keys:
        raise ParameterError("--jacobian-prior is an option of the partitioned coupling, not of --monolithic")
    return load_run_config(args.config, keys)


def _inputs(cases, config: RunConfig | None = None, config_file: str | None = None) -> list[tuple[str, str]]:
    """``(what, path)`` of every file the run reads: its ``--config``, geometry files and inflow table."""
    inputs = [("--config", config_file)] if config_file else []
    for params in cases:
        if params.case == "file":
            inputs.append(("--geometry", params.geometry.file))
    if config is not None and config.time.inflow.startswith("table:"):
        inputs.append(("--inflow table", config.time.inflow.partition(":")[2]))
    return inputs


def _check_before_meshing(cases, out: str, partial: bool = False, inputs=(), solver: str = "direct") -> None:
    """Model limits of every case, then the output directory (raise before anything is meshed).

    ``inputs`` (:func:`_inputs`): the files the run reads, none of which may lie in ``out``;
    ``solver``: the fields' solvers (``[solver] kind``), whose memory the mesh must fit.
    """
    from femtools.io import check_output_target
    from gelcell.post.validity import check_case
    cases = list(cases)
    for params in cases:
        check_case(params, solver)
    check_output_target(out, MPI.COMM_WORLD, partial, inputs)


def _check_coupling(config: RunConfig, transient: bool = False) -> None:
    """The resolved ``[coupling]`` table of a partitioned run is valid (ParameterError naming the key)."""
    if not config.solver.monolithic:
        from gelcell.coupled.defaults import partitioned_config
        partitioned_config(config.case, config.coupling, transient=transient, gamma2=config.solver.gamma2,
                           ranks=MPI.COMM_WORLD.size)


# --------------------------------------------------------------------------- mesh
def _counts_table(counts: dict) -> str:
    from gelcell.geometry import tag_value
    columns = [c for c in ("fluid", "gel", "cell", "whole") if c in counts]
    rows: list[tuple[str, str, list]] = [("cells", "-", [counts[c]["cells"] for c in columns])]
    per_tag = counts.get("whole", {}).get("cells_per_tag", {})
    for name, n in per_tag.items():
        region = "cell" if name.startswith("CELL") else name.lower()
        single = region != "cell" or sum(k.startswith("CELL") for k in per_tag) == 1
        rows.append((f"  {name}", str(tag_value(name)),
                     [n if c == "whole" else counts[c]["cells"] if c == region and single else None
                      for c in columns]))
    rows.append(("nodes(P2)", "-", [counts[c]["nodes"] for c in columns]))
    for name in sorted({k for c in columns for k in counts[c]["facets"]}, key=tag_value):
        rows.append((name, str(tag_value(name)), [counts[c]["facets"].get(name) for c in columns]))
    width = max(10, max(len(r[0]) for r in rows) + 2)
    lines = [f"{'':<{width}}{'tag':>5}" + "".join(f"{c:>9}" for c in columns)]
    for label, tag, vals in rows:
        lines.append(f"{label:<{width}}{tag:>5}" + "".join(f"{'-' if v is None else v:>9}" for v in vals))
    return "\n".join(lines)


def _mesh_line(params: CaseParameters, meshes, comm) -> str:
    h = params.element_sizes()
    n = len(meshes.cells)
    cells = "without cell" if not n else "with cell" if n == 1 else f"with {n} cells"
    if params.case == "file":
        return (f"gelcell mesh: device {os.path.basename(params.geometry.file)} {cells}, the file's element "
                f"sizes x {params.mesh.size_factor:g}, {comm.size} rank(s), built in {meshes.build_time:.2f} s")
    return (f"gelcell mesh: {params.case} device {cells}, size factor {params.mesh.size_factor:g} "
            f"(h_cell {h['h_cell']:.4g}, h_layer {h['h_layer']:.4g}, h_fluid {h['h_fluid']:.4g}, "
            f"h_gel {h['h_gel']:.4g}), {comm.size} rank(s), built in {meshes.build_time:.2f} s")


def cmd_mesh(args: argparse.Namespace) -> int:
    params = run_config(args).case                     # validated before any meshing
    _check_before_meshing([params], args.out, inputs=_inputs([params], config_file=args.config))
    from femtools.io import atomic_directory, write_json
    from gelcell.geometry.meshes import build_meshes
    comm = MPI.COMM_WORLD
    meshes = build_meshes(params, comm)
    counts = meshes.counts()
    out = os.path.abspath(args.out)
    with atomic_directory(out, comm) as tmp:
        if comm.rank == 0:
            os.chmod(tmp, 0o755)                      # mkdtemp makes it private
        meshes.write_xdmf(tmp)
        write_json(os.path.join(tmp, "counts.json"), counts, comm)
        write_json(os.path.join(tmp, "parameters.json"), meshes.params.to_dict(), comm)
        if comm.rank == 0:
            for name in ("counts.json", "parameters.json"):
                os.chmod(os.path.join(tmp, name), 0o644)      # mkstemp makes them private
    if comm.rank == 0:
        print(_mesh_line(meshes.params, meshes, comm))
        print(_counts_table(counts))
        print(f"wrote {', '.join(sorted(f for f in os.listdir(out) if f.endswith('.xdmf')))} "
              f"(+ .h5), counts.json, parameters.json to {out}")
    return 0


# --------------------------------------------------------------------------- run
def _time_keys_need_transient(keys: dict, config: RunConfig) -> None:
    given = [k for k in keys if k.startswith("time.") and k != "time.transient"]
    if given and not config.time.transient:
        option = given[0].partition(".")[2].replace("_", "-")
        option = "time-scheme" if option == "scheme" else option
        raise ParameterError(f"--{option} is an option of time-dependent runs: add --transient")


def cmd_run(args: argparse.Namespace) -> int:
    if args.resume is not None:
        return cmd_resume(args)
    if args.out is None:
        raise ParameterError("give the output directory: --out DIR")
    config = run_config(args)
    _time_keys_need_transient(command_line_keys(args), config)
    transient = config.time.transient
    _check_coupling(config, transient)
    _check_before_meshing([config.case], args.out, partial=transient,
                          inputs=_inputs([config.case], config, args.config), solver=config.solver.kind)
    if transient:
        from gelcell.run.transient_case import run_transient_case
        run_transient_case(config, args.out, comm=MPI.COMM_WORLD)
    else:
        from gelcell.run.steady import run_case
        run_case(config, args.out, comm=MPI.COMM_WORLD)
    return 0


def _resumed_groups(args: argparse.Namespace, keys: dict) -> list[str]:
    """What the command line of a resume says about the run: its case, time settings, method."""
    tables = {k.partition(".")[0] for k in keys}
    groups = []
    if args.config or tables & set(CASE_TABLES):
        groups.append("case")
    if args.config or any(k.startswith("time.") and k != "time.transient" for k in keys):
        groups.append("time settings")
    if args.config or tables & {"solver", "coupling"}:
        groups.append("method")
    return groups


def cmd_resume(args: argparse.Namespace) -> int:
    """``gelcell run [options] --resume DIR``: the configuration comes from DIR.partial/case.toml."""
    from gelcell.run.resume import check_checkpoint, check_resume, read_interrupted
    from gelcell.run.transient_case import run_transient_case
    if args.out is not None and os.path.abspath(args.out) != os.path.abspath(args.resume):
        raise ParameterError(f"--resume {args.resume} continues the run whose --out was {args.resume}; "
                             f"do not give another --out ({args.out})")
    tables = read_interrupted(args.resume)
    keys = command_line_keys(args)
    source = f"{args.resume}.partial/case.toml"
    stored = resolve(tables, source=source)
    groups = _resumed_groups(args, keys)
    if groups:
        keys = {"time.transient": True, **keys}
        if args.config:
            given = load_run_config(args.config, keys)
        elif "case.name" in keys or "geometry.file" in keys:
            given = resolve({}, keys)
        else:                               # the options change the stored case
            given = resolve({t: tables[t] for t in CASE_TABLES if t in tables}, keys, source=source)
        check_resume(stored, given, groups, args.resume)
    config = resolve(tables, {k: v for k, v in keys.items() if k.startswith("output.")}, source=source)
    check_checkpoint(args.resume, MPI.COMM_WORLD)
    _check_before_meshing([config.case], args.resume, partial=True,
                          inputs=_inputs([config.case], config, args.config), solver=config.solver.kind)
    run_transient_case(config, args.resume, comm=MPI.COMM_WORLD, resume=True)
    return 0


# --------------------------------------------------------------------------- sweep
def cmd_sweep(args: argparse.Namespace) -> int:
    config = run_config(args)
    from gelcell.run.sweep import run_sweep, sweep_cases
    cases = sweep_cases(config)                     # every value validated first
    _check_coupling(config)
    _check_before_meshing(cases, args.out, inputs=_inputs(cases, config, args.config), solver=config.solver.kind)
    run_sweep(config, args.out, comm=MPI.COMM_WORLD, debug=args.debug)
    return 0


# --------------------------------------------------------------------------- study
def cmd_study(args: argparse.Namespace) -> int:
    if args.max_iterations < 1:
        raise ParameterError(f"--max-iterations = {args.max_iterations} must be at least 1")
    from gelcell.run.study import (check_study_table, markdown_table, run_study, study_cases, study_mesh_size,
                                   update_study_table)
    if args.update_table:
        check_study_table(args.update_table)          # before the study runs, not after it
    mesh_size = study_mesh_size(args.quick, args.mesh_size)
    _check_before_meshing([c.parameters(mesh_size) for c in study_cases(args.quick)], args.out,
                          inputs=[("--update-table", args.update_table)] if args.update_table else [])
    study = run_study(args.out, quick=args.quick, mesh_size=mesh_size, max_iterations=args.max_iterations)
    if MPI.COMM_WORLD.rank == 0:
        print(study["table"])
        if args.update_table:
            update_study_table(args.update_table, markdown_table(study["records"], study["monolithic"]))
            print(f"updated the coupling-study table in {args.update_table}")
    return 0


COMMANDS = {"mesh": cmd_mesh, "run": cmd_run, "sweep": cmd_sweep, "study": cmd_study}
