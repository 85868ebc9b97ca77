"""The ``gelcell`` command line.

Subcommands are built with :func:`add_case_arguments` (the options that
define a case) and :func:`case_parameters_from_args` (turn them into a
validated :class:`~gelcell.parameters.CaseParameters`), so every command
reads a case the same way: defaults < ``--config`` file < command-line
options.

Everything that can be checked is checked before anything is meshed or
solved: the parameters and the ``[coupling]`` table, the model's limits
(``gelcell.validity``) and the output directory (``femtools.io``).  Every
expected failure ends with one line on stderr and the exit code of
``gelcell.errors``; ``gelcell --debug`` adds the traceback and the form
compiler's log.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import traceback
import typing

# Started without mpirun, this process is an MPI singleton that talks to nobody, yet Open MPI's
# MPI_Init (0.4 s) would probe the high-speed network libraries (psm, psm2, libfabric) and start a
# helper daemon for MPI_Comm_spawn, which gelcell never calls: ob1 and no daemon make it 0.03 s.
# Only for this process's MPI_Init (a setting the user made is kept); its children do not inherit them.
# Not under a launcher (mpirun, srun, a PMI server): there the transport is the launcher's choice.
_LAUNCHED = ("OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE", "SLURM_PROCID")
_SINGLETON_MCA = {"OMPI_MCA_pml": "ob1", "OMPI_MCA_ess_singleton_isolated": "1"}
_SINGLETON_MCA = {} if any(k in os.environ for k in _LAUNCHED) else \
    {k: v for k, v in _SINGLETON_MCA.items() if k not in os.environ}
os.environ.update(_SINGLETON_MCA)
from mpi4py import MPI  # noqa: E402

for _key in _SINGLETON_MCA:
    del os.environ[_key]

from gelcell.parameters import CASES, DEFAULT_GAMMA2, GAMMA2, CaseParameters, ParameterError

__all__ = ["main", "build_parser", "add_case_arguments", "case_parameters_from_args"]

DESCRIPTION = """\
gelcell: finite-element model of a microfluidic device in which a perfusate
(Stokes flow) passes a poroelastic hydrogel with an embedded hyperelastic cell.
Three field solvers (fluid, gel, cell) are coupled on the interfaces
Gamma1 (fluid-gel), Gamma2 (gel-cell) and Gamma3 (second fluid-gel) for two
device geometries: "shear" (gel chamber below a channel) and "normal"
(flow through a gel layer between posts), or for your own device drawn in gmsh
(--geometry FILE.geo|FILE.msh, docs/geometry-files.md), with one or several
cells.  Results are reported in the paper's dimensionless units and in SI
units (µm, µm/s, mPa).

Runs in serial or under mpirun (e.g. mpirun -n 2 gelcell mesh normal --out m).
"""

EPILOG = """\
Case options (--geometry, --cells, --e, --ca, --cell-moduli, --gel-moduli, --mesh-size,
--cell/--no-cell, --kinematics)
override the values of a --config TOML file, which override the defaults of
model.md (see examples/case_baseline_shear.toml).  Run "gelcell COMMAND --help"
for the options of a command.

--out DIR is replaced as a whole, and only if gelcell wrote it (it holds the
marker file .gelcell-output) or it is empty.  Exit codes: 0 success, 1 internal
error, 2 bad parameters or configuration, 3 output directory refused, 4 model
limits, 5 coupling diverged, 6 coupling not converged, 7 singular system,
8 Newton failure, 9 some sweep values failed, 130 SIGINT, 143 SIGTERM.
"""


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def add_case_arguments(parser: argparse.ArgumentParser, case_positional: bool = True) -> None:
    """Add the options that define a case to ``parser``.

    ``case`` (positional, ``shear``/``normal``, optional if ``--config`` names
    it), ``--config``, ``--cell/--no-cell``, ``--e``, ``--ca``,
    ``--cell-moduli``, ``--gel-moduli``, ``--mesh-size``, ``--kinematics``.
    """
    if case_positional:
        parser.add_argument("case", nargs="?", choices=CASES,
                            help="device geometry (default: [case] name of --config, else required)")
    g = parser.add_argument_group("case options")
    g.add_argument("--geometry", metavar="FILE.geo|FILE.msh",
                   help="your own device: a gmsh geometry file with named physical groups "
                        "(docs/geometry-files.md); replaces the positional device name")
    g.add_argument("--cells", nargs="+", metavar="X,Y,D",
                   help="several cells in a built-in device: centre x, y and diameter of each, in units of L0 "
                        "(a cell of the normal device centred on y = 0.5 is cut by the symmetry line)")
    g.add_argument("--config", metavar="CASE.toml",
                   help="TOML case file (tables [case] [physics] [dimensional] [cell] [geometry] "
                        "[mesh] [coupling]); command-line options override it")
    g.add_argument("--cell", action=argparse.BooleanOptionalAction, default=None,
                   help="with or without the cell (default: with)")
    g.add_argument("--e", type=_number, metavar="E",
                   help="cell position e in units of L0: centre (X, -e) in the shear device "
                        "(default 0.2), (e, 0.5) in the normal device (default 1.2)")
    g.add_argument("--ca", type=_number, metavar="CA",
                   help="Ca = mu V0 / (L0 mu_s) (default 3e-10); changes the flow speed V0 "
                        "at fixed moduli")
    g.add_argument("--cell-moduli", type=_number, metavar="M",
                   help="cell moduli as a multiple of the gel's drained modulus phi_s0 mu_s "
                        "(mu_c = M phi_s0 mu_s, Poisson ratio kept; default cell: E = 1 kPa, "
                        "nu = 0.25, i.e. M = 1)")
    g.add_argument("--gel-moduli", type=_number, metavar="X",
                   help="multiply mu_s and lambda_s by X at fixed flow speed V0 and fixed cell "
                        "moduli in Pa (so Ca -> Ca/X); applied after --cell-moduli")
    g.add_argument("--mesh-size", type=_number, metavar="F",
                   help="multiply every element size by F (2 = twice as coarse, 0.5 = twice as fine)")
    g.add_argument("--kinematics", metavar="finite|small",
                   help="finite (default): the gel in total Lagrangian form and the fluid domain following "
                        "the gel's surface, right at any strain; small: every field on its undeformed "
                        "domain, exact to the size of the strains (~1e-6 at Table 1 loads)")


def case_parameters_from_args(args: argparse.Namespace) -> CaseParameters:
    """Validated parameters from the options of :func:`add_case_arguments`.

    Order: defaults, then ``--config``, then ``case``, ``--cell``, ``--kinematics``,
    ``--ca``, ``--e``, ``--mesh-size`` (validated together), then ``--cell-moduli``,
    then ``--gel-moduli``.  Raises :class:`ParameterError`.
    """
    cells = None
    if getattr(args, "cells", None):
        cells = []
        for text in args.cells:
            try:
                x, y, dd = (float(v) for v in text.split(","))
            except ValueError:
                raise ParameterError(f"--cells {text!r}: each cell is X,Y,D (centre and diameter in units of L0), "
                                     f"e.g. --cells 1.9,-0.2,0.06 2.1,-0.3,0.06") from None
            cells.append([x, y, dd])
    geometry = getattr(args, "geometry", None)
    if geometry is not None:
        if getattr(args, "case", None) is not None:
            raise ParameterError(f"give either the device name ({args.case}) or --geometry {geometry}, not both")
        if cells is not None or args.e is not None:
            raise ParameterError(f"--{'cells' if cells is not None else 'e'} places the cells of a built-in device; "
                                 f"the cells of --geometry {geometry} come from the file")
        geometry = os.path.abspath(geometry)
    if cells is not None and args.e is not None:
        raise ParameterError("give either --e (the one cell) or --cells, not both")
    overrides = {"case.name": getattr(args, "case", None), "case.cell": args.cell,
                 "geometry.file": geometry, "geometry.cells": cells,
                 "case.kinematics": args.kinematics,
                 "physics.ca": args.ca, "geometry.e": args.e, "mesh.size_factor": args.mesh_size}
    if args.config:
        params = CaseParameters.from_toml(args.config, overrides)
    else:
        if overrides["case.name"] is None and geometry is None:
            raise ParameterError("give the device geometry (shear or normal), --geometry FILE or a --config file")
        params = CaseParameters.from_dict({}, overrides, source="the command line")
    if args.cell_moduli is not None:
        params = params.with_cell_moduli(args.cell_moduli)
    if args.gel_moduli is not None:
        params = params.with_gel_moduli(args.gel_moduli)
    return params


# --------------------------------------------------------------------------- mesh
def _counts_table(counts: dict) -> str:
    from gelcell.geometry import tag_value
    columns = [c for c in ("fluid", "gel", "cell", "whole") if c in counts]
    rows: list[tuple[str, str, list]] = [
        ("cells", "-", [counts[c]["cells"] for c in columns])]
    for name, n in counts.get("whole", {}).get("cells_per_tag", {}).items():
        region = "cell" if name.startswith("CELL") else name.lower()
        single = region != "cell" or sum(k.startswith("CELL") for k in counts["whole"]["cells_per_tag"]) == 1
        rows.append((f"  {name}", str(tag_value(name)),
                     [n if c == "whole" else counts[c]["cells"] if c == region and single else None
                      for c in columns]))
    rows.append(("nodes(P2)", "-", [counts[c]["nodes"] for c in columns]))
    names = sorted({k for c in columns for k in counts[c]["facets"]}, key=tag_value)
    for name in names:
        rows.append((name, str(tag_value(name)), [counts[c]["facets"].get(name) for c in columns]))
    width = max(10, max(len(r[0]) for r in rows) + 2)
    lines = [f"{'':<{width}}{'tag':>5}" + "".join(f"{c:>9}" for c in columns)]
    for label, tag, vals in rows:
        lines.append(f"{label:<{width}}{tag:>5}"
                     + "".join(f"{'-' if v is None else v:>9}" for v in vals))
    return "\n".join(lines)


def _check_before_meshing(cases: typing.Iterable[CaseParameters], out: str, partial: bool = False) -> None:
    """Model limits of every case, then the output directory (raise before anything is meshed)."""
    from femtools.io import check_output_target
    from gelcell.validity import check_case
    for params in cases:
        check_case(params)
    check_output_target(out, MPI.COMM_WORLD, partial)


def _with_solver_options(params: CaseParameters, args: argparse.Namespace) -> CaseParameters:
    """``--jacobian-prior`` into the case's ``[coupling.acceleration]`` table (it overrides the file's)."""
    prior = getattr(args, "jacobian_prior", None)
    if prior is None:
        return params
    if args.monolithic:
        raise ParameterError("--jacobian-prior is an option of the partitioned coupling, not of --monolithic")
    coupling = dict(params.coupling)
    coupling["acceleration"] = {**dict(coupling.get("acceleration", {})), "jacobian_prior": prior}
    return params.replace(coupling=coupling)


def cmd_mesh(args: argparse.Namespace) -> int:
    params = case_parameters_from_args(args)         # validated before any meshing
    _check_before_meshing([params], args.out)
    from femtools.io import atomic_directory, write_json
    from gelcell.geometry import build_device
    comm = MPI.COMM_WORLD
    dev = build_device(params, comm)
    counts = dev.counts()
    out = os.path.abspath(args.out)
    with atomic_directory(out, comm) as tmp:
        if comm.rank == 0:
            os.chmod(tmp, 0o755)                      # mkdtemp makes it private
        dev.write_xdmf(tmp)
        write_json(os.path.join(tmp, "counts.json"), counts, comm)
        write_json(os.path.join(tmp, "parameters.json"), params.to_dict(), comm)
        if comm.rank == 0:
            for name in ("counts.json", "parameters.json"):
                os.chmod(os.path.join(tmp, name), 0o644)      # mkstemp makes them private
    if comm.rank == 0:
        h = params.element_sizes()
        n = len(dev.cells)
        cells = "without cell" if not n else "with cell" if n == 1 else f"with {n} cells"
        if params.case == "file":
            print(f"gelcell mesh: device {os.path.basename(params.geometry.file)} {cells}, the file's element "
                  f"sizes x {params.mesh.size_factor:g}, {comm.size} rank(s), built in {dev.build_time:.2f} s")
        else:
            print(f"gelcell mesh: {params.case} device {cells}, "
                  f"size factor {params.mesh.size_factor:g} (h_cell {h['h_cell']:.4g}, "
                  f"h_layer {h['h_layer']:.4g}, h_fluid {h['h_fluid']:.4g}, h_gel {h['h_gel']:.4g}), "
                  f"{comm.size} rank(s), built in {dev.build_time:.2f} s")
        print(_counts_table(counts))
        print(f"wrote {', '.join(sorted(f for f in os.listdir(out) if f.endswith('.xdmf')))} "
              f"(+ .h5), counts.json, parameters.json to {out}")
    return 0


# --------------------------------------------------------------------------- run
SCHEMES = ("serial", "parallel", "serial-explicit", "parallel-explicit")
ACCELERATIONS = ("none", "constant", "aitken", "iqn-ils", "iqn-imvj")


def _add_solver_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("solver options")
    g.add_argument("--scheme", choices=SCHEMES, default="serial",
                   help="coupling scheme: serial (Gauss-Seidel: fluid, gel, cell) or parallel (Jacobi), implicit; "
                        "serial-explicit / parallel-explicit: one exchange per time window (time-dependent "
                        "runs, for comparison)")
    g.add_argument("--acceleration", choices=ACCELERATIONS, default=None,
                   help="coupling acceleration (default iqn-ils)")
    g.add_argument("--gamma2", choices=GAMMA2, default=DEFAULT_GAMMA2,
                   help="the split on Gamma2: schur (default): the cell takes the gel's displacement and the gel "
                        "carries the cell's interface stiffness (a Robin condition with the cell's Steklov-Poincare "
                        "operator); dirichlet: plain Dirichlet-Neumann; robin: the cell takes the gel's force plus "
                        "springs towards its displacement (Robin-Neumann)")
    g.add_argument("--jacobian-prior", choices=("none", "linearized"), default=None,
                   help="IQN's prior: linearized = the Newton step on the coupled map linearised at rest from the "
                        "three solvers' interface Jacobians (3-5 iterations instead of 14-39; ~1.3 s to compute "
                        "at the default mesh, then loaded from the disk cache in ~0.1 s); none = the secant "
                        "model alone.  Default: the case file's [coupling.acceleration] jacobian_prior, else "
                        "linearized for steady runs with at most 4000 interface "
                        "unknowns (mesh-size >= ~0.7), none otherwise (docs/coupling.md)")
    g.add_argument("--monolithic", action="store_true",
                   help="solve the monolithic reference (all fields in one Newton system) instead")
    g.add_argument("--quiet", action="store_true", help="no per-iteration coupling progress")


def _add_time_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("time-dependent runs (model.md section 8; times in the paper's unit L0/V0)")
    g.add_argument("--transient", action="store_true", default=None,
                   help="integrate in time from rest instead of solving the steady state")
    g.add_argument("--dt", type=_number, metavar="DT",
                   help="time step (adaptive: the first one); default: consolidation time / 40 "
                        "(adaptive: Kelvin-Voigt time / 10)")
    g.add_argument("--t-end", type=_number, metavar="T", help="end time (default: until steady)")
    g.add_argument("--until-steady", action="store_true", default=None,
                   help="stop when the relative change per consolidation time is below --steady-tol")
    g.add_argument("--time-scheme", choices=("be", "bdf2"), default=None,
                   help="backward Euler (default) or BDF2 (started by one backward Euler step)")
    g.add_argument("--adaptive", action="store_true", default=None,
                   help="adaptive dt from a local error estimate (tolerance --time-tol)")
    g.add_argument("--time-tol", type=_number, metavar="TOL", help="relative local error per step (default 1e-3)")
    g.add_argument("--steady-tol", type=_number, metavar="TOL",
                   help="steady when the relative change per consolidation time is below TOL (default 1e-4)")
    g.add_argument("--inflow", metavar="SPEC",
                   help="inflow V0 f(t): step (default), ramp:T, sine:MEAN,AMP,PERIOD, square:ON,OFF, "
                        "table:FILE.csv")
    g.add_argument("--output-every", type=int, metavar="N", help="an XDMF frame every N windows (default 5)")
    g.add_argument("--resume", metavar="DIR",
                   help="continue the interrupted time-dependent run whose --out was DIR from DIR.partial/")


def _time_overrides(args: argparse.Namespace) -> dict:
    return {"transient": args.transient, "dt": args.dt, "t_end": args.t_end, "until_steady": args.until_steady,
            "scheme": args.time_scheme, "adaptive": args.adaptive, "time_tol": args.time_tol,
            "steady_tol": args.steady_tol, "inflow": args.inflow, "output_every": args.output_every}


def time_settings_from_args(args: argparse.Namespace, params: CaseParameters):
    """The validated TimeSettings: ``[time]`` of the case file, then the command-line options."""
    from gelcell.timesettings import TimeSettings
    base = os.path.dirname(os.path.abspath(args.config)) if args.config else None
    return TimeSettings.from_dict(params.time, _time_overrides(args), source=args.config or "the command line",
                                  base_dir=base)


def cmd_run(args: argparse.Namespace) -> int:
    if args.resume is not None:
        return _cmd_resume(args)
    if args.out is None:
        raise ParameterError("give the output directory: --out DIR")
    params = _with_solver_options(case_parameters_from_args(args), args)   # validated before any meshing
    settings = time_settings_from_args(args, params)
    if settings.transient:
        if args.compare_no_cell:
            raise ParameterError("--compare-no-cell is for steady runs, not with --transient")
        from gelcell.runner import partitioned_config
        from gelcell.transient import run_transient_case
        if not args.monolithic:
            partitioned_config(params, args.scheme, args.acceleration, transient=True)
        _check_before_meshing([params], args.out, partial=True)
        run_transient_case(params, settings, args.out, monolithic=args.monolithic, scheme=args.scheme,
                           acceleration=args.acceleration, comm=MPI.COMM_WORLD, figures=not args.no_figures,
                           gamma2=args.gamma2)
        return 0
    given = [k for k, v in _time_overrides(args).items() if v is not None and k != "transient"]
    if given:
        raise ParameterError(f"--{given[0].replace('_', '-')} is an option of time-dependent runs: add --transient")
    if args.scheme.endswith("explicit"):
        raise ParameterError(f"--scheme {args.scheme} exchanges once per time window: add --transient")
    from gelcell.results import gamma_profiles
    from gelcell.runner import partitioned_config, report, run_case, solve_partitioned
    if not args.monolithic:
        partitioned_config(params, args.scheme, args.acceleration)
    _check_before_meshing([params], args.out)
    comm = MPI.COMM_WORLD
    overlay, extra = None, {}
    if args.compare_no_cell and params.case == "file" and params.with_cell:
        raise ParameterError("--compare-no-cell: the cells of a geometry file are part of its drawing; compare "
                             "with a copy of the file without them")
    if args.compare_no_cell and params.with_cell:
        if comm.rank == 0:
            print("gelcell: first the same case without the cell, for the profile comparison")
        ref = solve_partitioned(params.replace(with_cell=False), args.scheme, args.acceleration, comm=comm,
                                verbose=not args.quiet, checks=False)
        overlay = gamma_profiles(ref.fields, "Gamma1")
        extra["summary_no_cell.json"] = report(ref.summary, params.replace(with_cell=False))
    run_case(params, args.out, monolithic=args.monolithic, scheme=args.scheme, acceleration=args.acceleration,
             comm=comm, verbose=not args.quiet, figures=not args.no_figures, overlay_profiles=overlay,
             extra_json=extra, gamma2=args.gamma2)
    return 0


def _cmd_resume(args: argparse.Namespace) -> int:
    """``gelcell run [case options] --resume DIR``: the case and settings come from DIR.partial/."""
    from gelcell.timesettings import TimeSettings
    from gelcell.transient import check_resume, read_run_record, run_transient_case
    if args.out is not None and os.path.abspath(args.out) != os.path.abspath(args.resume):
        raise ParameterError(f"--resume {args.resume} continues the run whose --out was {args.resume}; "
                             f"do not give another --out ({args.out})")
    record = read_run_record(args.resume)
    given_params = case_parameters_from_args(args) if (args.case or args.config) else None
    overrides = _time_overrides(args)
    given_settings = None
    if any(v is not None for k, v in overrides.items() if k != "transient") or args.config:
        base = given_params.time if given_params is not None else {}
        given_settings = TimeSettings.from_dict(base, {**overrides, "transient": True})
    explicit = any(a.startswith(("--scheme", "--acceleration", "--gamma2", "--monolithic"))
                   for a in sys.argv[1:]) if args.argv is None else any(
                   a.startswith(("--scheme", "--acceleration", "--gamma2", "--monolithic")) for a in args.argv)
    method = ({"monolithic": bool(args.monolithic), "scheme": args.scheme, "acceleration": args.acceleration,
               "gamma2": args.gamma2, "coupling": record["method"].get("coupling", {})} if explicit else None)
    check_resume(record, given_params, given_settings, method, args.resume)
    params = CaseParameters.from_dict(record["case"], source=f"{args.resume}.partial/run.json")
    settings = TimeSettings.from_dict(record["time"], source=f"{args.resume}.partial/run.json")
    m = record["method"]
    _check_before_meshing([params], args.resume, partial=True)
    run_transient_case(params, settings, args.resume, monolithic=m["monolithic"], scheme=m["scheme"],
                       acceleration=m["acceleration"], coupling=m.get("coupling"), comm=MPI.COMM_WORLD,
                       figures=not args.no_figures, gamma2=m["gamma2"], resume=True)
    return 0


# --------------------------------------------------------------------------- sweep
SWEEPS = ("ca", "cell-moduli", "gel-moduli", "e")


def sweep_parameters(params: CaseParameters, name: str, value: float) -> CaseParameters:
    """The case with one swept parameter set (model.md section 5)."""
    if name == "ca":
        return params.with_ca(value)
    if name == "cell-moduli":
        return params.with_cell_moduli(value)
    if name == "gel-moduli":
        return params.with_gel_moduli(value)
    if name == "e":
        return params.with_e(value)
    raise ParameterError(f"--param must be one of {', '.join(SWEEPS)}, got {name!r}")


def cmd_sweep(args: argparse.Namespace) -> int:
    base = _with_solver_options(case_parameters_from_args(args), args)
    cases = [sweep_parameters(base, args.param, v) for v in args.values]   # validate all first
    from gelcell.runner import partitioned_config
    from gelcell.sweep import check_distinct, run_sweep
    check_distinct(args.param, args.values)
    if not args.monolithic:
        partitioned_config(base, args.scheme, args.acceleration)
    _check_before_meshing(cases, args.out)
    run_sweep(cases, args.param, args.values, args.out, monolithic=args.monolithic, scheme=args.scheme,
              acceleration=args.acceleration, verbose=not args.quiet, gamma2=args.gamma2, debug=args.debug,
              compare_kinematics=args.compare_kinematics)
    return 0


# --------------------------------------------------------------------------- study
def cmd_study(args: argparse.Namespace) -> int:
    if args.max_iterations < 1:
        raise ParameterError(f"--max-iterations = {args.max_iterations} must be at least 1")
    from gelcell.study import markdown_table, run_study, study_cases, study_mesh_size, update_readme
    mesh_size = study_mesh_size(args.quick, args.mesh_size)
    _check_before_meshing([c.parameters(mesh_size) for c in study_cases(args.quick)], args.out)
    study = run_study(args.out, quick=args.quick, mesh_size=mesh_size, max_iterations=args.max_iterations)
    if MPI.COMM_WORLD.rank == 0:
        print(study["table"])
        if args.update_readme:
            update_readme(args.update_readme, markdown_table(study["records"], study["monolithic"]))
            print(f"updated the coupling-study table in {args.update_readme}")
    return 0


# --------------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gelcell", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    from gelcell import __version__
    parser.add_argument("--version", action="version", version=f"gelcell {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="on an error also print the Python traceback; show debug logs (form compiler)")
    sub = parser.add_subparsers(dest="command", title="commands", metavar="COMMAND")
    p = sub.add_parser("mesh", help="build the meshes of a device and write them as XDMF",
                       description="Build the gmsh model of a device, the region meshes "
                                   "(fluid, gel, cell) and the whole-device mesh with their "
                                   "cell and facet tags; write them as XDMF (one file per region "
                                   "+ whole.xdmf, readable in ParaView) with counts.json and "
                                   "parameters.json into DIR (atomically), and print the number "
                                   "of cells and facets per tag.")
    add_case_arguments(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (replaced)")
    p.set_defaults(func=cmd_mesh)

    p = sub.add_parser("run", help="solve one case (partitioned or monolithic) and write its results",
                       description="Solve a device case: the partitioned fluid-gel-cell coupling (default) or "
                                   "the monolithic reference (--monolithic).  Prints the coupling progress "
                                   "and a table of results, and writes into DIR: summary.json (every "
                                   "quantity, dimensionless and SI), fluid.xdmf/gel.xdmf/cell.xdmf (fields "
                                   "for ParaView), gamma1_profiles.h5/.csv, coupling/ (iteration and "
                                   "convergence logs) and PNG figures.  DIR is replaced only when "
                                   "everything has been written.  With --transient the case is integrated "
                                   "in time from rest: one progress line per window, and DIR also gets "
                                   "timeseries.csv/.h5, trajectory.png, iterations.png and the fields at "
                                   "several times in the XDMF files; while it runs (and after an "
                                   "interruption) DIR.partial/ holds the last window's checkpoint, which "
                                   "--resume DIR continues.")
    add_case_arguments(p)
    _add_solver_arguments(p)
    _add_time_arguments(p)
    p.add_argument("--compare-no-cell", action="store_true",
                   help="also solve the case without the cell and overlay its Gamma1 profiles")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--out", metavar="DIR", help="output directory (replaced; required unless --resume)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("sweep", help="run a case for several values of one parameter",
                       description="Run one case per value of --param and write sweep.csv and sweep.json "
                                   "(the summary quantities per value), sweep.png (each quantity against "
                                   "the parameter) and one summary per run into DIR.  The gel-moduli sweep "
                                   "keeps the dimensional flow speed and the cell moduli in Pa fixed, so Ca "
                                   "and mu_c/mu_s change with it (model.md section 5).  --param ca also "
                                   "draws linearity.png: displacements, strains and stresses divided by Ca, "
                                   "which stay flat while the response is linear.")
    add_case_arguments(p)
    _add_solver_arguments(p)
    p.add_argument("--param", required=True, choices=SWEEPS, help="the swept parameter")
    p.add_argument("--values", required=True, nargs="+", type=_number, metavar="V",
                   help="values of the parameter (Ca; multiples of the cell or gel moduli; e in L0)")
    p.add_argument("--compare-kinematics", action="store_true",
                   help="also run every value on the other kinematics path (small vs finite) and record the "
                        "departure of the small-strain result from the finite-strain one (sweep.csv, "
                        "linearity.png)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (replaced)")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("study", help="compare coupling schemes and accelerations on the device cases",
                       description="Coupling-scheme comparison study: for both devices with the cell and the "
                                   "stiffness extremes (cell and gel moduli x0.1, x10), every scheme, "
                                   "acceleration and Robin coefficient; outcome, iterations, participant "
                                   "solves, wall time, error against the monolithic reference and final "
                                   "residual.  Writes study.csv, study.json, study.md and "
                                   "study_convergence.png into DIR.  --quick runs a representative subset "
                                   "in a few minutes.")
    p.add_argument("--quick", action="store_true", help="the representative subset (coarse mesh)")
    p.add_argument("--mesh-size", type=_number, default=None, metavar="F",
                   help="element size factor (default 3 with --quick, else 2)")
    p.add_argument("--max-iterations", type=int, default=150, metavar="N")
    p.add_argument("--update-readme", metavar="README.md", help="replace the study table in this README")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (replaced)")
    p.set_defaults(func=cmd_study)
    return parser


def configure_logging(debug: bool = False) -> None:
    """Warnings on stderr; debug records (incl. the C compiler lines of FFCx's JIT) only with ``debug``.

    FFCx calls ``logging.basicConfig()`` when imported and the compiler driver
    logs each command at INFO on the root logger; a handler of our own, at
    WARNING unless ``debug``, keeps those lines out of a normal run.
    """
    handler = logging.StreamHandler(sys.stderr)
    handler.setLevel(logging.DEBUG if debug else logging.WARNING)
    logging.basicConfig(handlers=[handler], format="%(levelname)s:%(name)s: %(message)s",
                        level=logging.DEBUG if debug else logging.WARNING, force=True)


def main(argv: typing.Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = None if argv is None else list(argv)
    if getattr(args, "scheme", None) is not None and getattr(args, "acceleration", "unset") is None:
        # explicit schemes exchange once per window: nothing to accelerate
        args.acceleration = "none" if args.scheme.endswith("explicit") else "iqn-ils"
    configure_logging(args.debug)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from gelcell.errors import exit_code, install_signal_handlers, message
    with install_signal_handlers():
        try:
            return int(args.func(args) or 0)
        except (Exception, KeyboardInterrupt) as exc:      # every failure: one line and its exit code
            if MPI.COMM_WORLD.rank == 0:
                if args.debug:
                    traceback.print_exc()
                print(f"gelcell {args.command}: error: {message(exc)}", file=sys.stderr, flush=True)
            return exit_code(exc)


if __name__ == "__main__":
    sys.exit(main())
