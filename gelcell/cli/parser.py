"""The options of the ``gelcell`` commands, each with the case-file key it sets.

Every option that configures a run sets one key of the case-file tables
(:data:`OPTION_KEYS`); :func:`command_line_keys` turns the parsed options
into those keys, and :func:`gelcell.case.resolve` puts them on top of the
``--config`` file's tables.  Options not given are left out, so the file's
value (or the default) holds.  ``--out``, ``--config``, ``--resume`` and
``--debug`` say where gelcell reads and writes, not what a run computes.
"""

from __future__ import annotations

import argparse
import os
import typing

from gelcell.case import CASES, GAMMA2, SOLVER_KINDS, SWEEPS, WALLS
from gelcell.errors import ParameterError

__all__ = ["build_parser", "command_line_keys", "OPTION_KEYS", "SCHEMES", "ACCELERATIONS"]

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
Every option that configures a run has a case-file key (docs/configuration.md):
the defaults of model.md < the --config TOML file < the command line.  A run
writes the configuration it used as DIR/case.toml, and "gelcell run --config
DIR/case.toml --out DIR2" repeats it.  Run "gelcell COMMAND --help" for the
options of a command.

--out DIR is replaced as a whole, and only if gelcell wrote it (it holds the
marker file .gelcell-output) or it is empty.  Exit codes: 0 success, 1 internal
error, 2 bad parameters or configuration, 3 output directory refused, 4 model
limits, 5 coupling diverged, 6 coupling not converged, 7 singular system,
8 Newton failure, 9 some sweep values failed, 130 SIGINT, 143 SIGTERM.
"""

SCHEMES = ("serial", "parallel", "serial-explicit", "parallel-explicit")
ACCELERATIONS = ("none", "constant", "aitken", "iqn-ils", "iqn-imvj")


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def _cells(texts: list[str]) -> list[list[float]]:
    """X,Y,D (planar) or X,Y,Z,D (a 3D device) per cell."""
    cells = []
    for text in texts:
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) not in (3, 4):
            raise ParameterError(f"--cells {text!r}: each cell is X,Y,D, or X,Y,Z,D on a 3D device (centre and "
                                 f"diameter in units of L0), e.g. --cells 1.9,-0.2,0.06 2.1,-0.3,0.06")
        cells.append(values)
    return cells


def _inflow(text: str) -> str:
    """A ``table:FILE`` inflow with the file's path made absolute (relative to where gelcell runs)."""
    kind, sep, path = text.partition(":")
    if kind.strip() == "table" and sep and path.strip() and not os.path.isabs(path.strip()):
        return f"table:{os.path.abspath(path.strip())}"
    return text


#: option (argparse dest) -> (case-file key, the key's value from the option's)
OPTION_KEYS: dict[str, tuple[str, typing.Callable]] = {
    "case": ("case.name", str),
    "geometry": ("geometry.file", os.path.abspath),
    "cells": ("geometry.cells", _cells),
    "cell": ("case.cell", bool),
    "e": ("geometry.e", float),
    "height": ("geometry.chip_height", float),
    "walls": ("geometry.walls", str),
    "ca": ("physics.ca", float),
    "cell_moduli": ("case.cell_moduli", float),
    "gel_moduli": ("case.gel_moduli", float),
    "mesh_size": ("mesh.size_factor", float),
    "kinematics": ("case.kinematics", str),
    "monolithic": ("solver.method", lambda on: "monolithic" if on else "partitioned"),
    "gamma2": ("solver.gamma2", str),
    "solver": ("solver.kind", str),
    "scheme": ("coupling.scheme", lambda s: f"{s}-implicit" if s in ("serial", "parallel") else s),
    "acceleration": ("coupling.acceleration.type", str),
    "jacobian_prior": ("coupling.acceleration.jacobian_prior", str),
    "distribute": ("coupling.distribute", str),
    "quiet": ("output.progress", lambda on: not on),
    "no_figures": ("output.figures", lambda on: not on),
    "compare_no_cell": ("output.compare_no_cell", bool),
    "transient": ("time.transient", bool),
    "dt": ("time.dt", float),
    "t_end": ("time.t_end", float),
    "until_steady": ("time.until_steady", bool),
    "time_scheme": ("time.scheme", str),
    "adaptive": ("time.adaptive", bool),
    "time_tol": ("time.time_tol", float),
    "steady_tol": ("time.steady_tol", float),
    "inflow": ("time.inflow", _inflow),
    "output_every": ("time.output_every", int),
    "until_periodic": ("time.until_periodic", bool),
    "periodic_tol": ("time.periodic_tol", float),
    "steps_per_period": ("time.steps_per_period", int),
    "param": ("sweep.param", str),
    "values": ("sweep.values", list),
    "compare_kinematics": ("sweep.compare_kinematics", bool),
}


def command_line_keys(args: argparse.Namespace) -> dict:
    """The case-file keys of the options given (``{"physics.ca": 1e-9, ...}``)."""
    keys = {}
    for dest, (key, convert) in OPTION_KEYS.items():
        value = getattr(args, dest, None)
        if value is not None:
            keys[key] = convert(value)
    return keys


def _flag(group, *names: str, help: str) -> None:
    group.add_argument(*names, action="store_true", default=None, help=help)


def add_case_arguments(parser: argparse.ArgumentParser) -> None:
    """The options that define a case (the tables [case] [physics] [cell] [geometry] [mesh])."""
    parser.add_argument("case", nargs="?", choices=CASES,
                        help="device geometry (case.name; default: [case] name of --config, else required)")
    g = parser.add_argument_group("case options")
    g.add_argument("--geometry", metavar="FILE.geo|FILE.msh",
                   help="your own device: a gmsh geometry file with named physical groups "
                        "(docs/geometry-files.md); replaces the positional device name (geometry.file)")
    g.add_argument("--cells", nargs="+", metavar="X,Y[,Z],D",
                   help="several cells in a built-in device: centre x, y (and z on a 3D device, which must be "
                        "--height/2) and diameter of each, in units of L0 (a cell of the normal device centred "
                        "on y = 0.5 is cut by the symmetry line) (geometry.cells)")
    g.add_argument("--height", type=_number, metavar="H",
                   help="a 3D device (model.md section 10): the planar device extruded to the chip's height H "
                        "in units of L0 (0.4 = 100 µm), computed on z in [0, H/2] with a symmetry plane at "
                        "mid-height and spherical cells there (geometry.chip_height; default: the planar device)")
    g.add_argument("--walls", choices=WALLS, default=None,
                   help="a 3D device's floor and lid: noslip (default: glass walls, the gel bonded) or "
                        "symmetric (symmetry planes: the slab, equal to the planar device) (geometry.walls)")
    g.add_argument("--config", metavar="CASE.toml",
                   help="TOML case file (tables [case] [physics] [dimensional] [cell] [geometry] [mesh] [solver] "
                        "[coupling] [time] [output] [sweep]); command-line options override it")
    g.add_argument("--cell", action=argparse.BooleanOptionalAction, default=None,
                   help="with or without the cell (case.cell; default: with)")
    g.add_argument("--e", type=_number, metavar="E",
                   help="cell position e in units of L0: centre (X, -e) in the shear device "
                        "(default 0.2), (e, 0.5) in the normal device (default 1.2) (geometry.e)")
    g.add_argument("--ca", type=_number, metavar="CA",
                   help="Ca = mu V0 / (L0 mu_s) (default 3e-10); changes the flow speed V0 "
                        "at fixed moduli (physics.ca)")
    g.add_argument("--cell-moduli", type=_number, metavar="M",
                   help="cell moduli as a multiple of the gel's drained modulus phi_s0 mu_s "
                        "(mu_c = M phi_s0 mu_s, Poisson ratio kept; default cell: E = 1 kPa, "
                        "nu = 0.25, i.e. M = 1) (case.cell_moduli)")
    g.add_argument("--gel-moduli", type=_number, metavar="X",
                   help="multiply mu_s and lambda_s by X at fixed flow speed V0 and fixed cell "
                        "moduli in Pa (so Ca -> Ca/X); applied after --cell-moduli (case.gel_moduli)")
    g.add_argument("--mesh-size", type=_number, metavar="F",
                   help="multiply every element size by F (2 = twice as coarse, 0.5 = twice as fine) "
                        "(mesh.size_factor)")
    g.add_argument("--kinematics", metavar="finite|small",
                   help="finite (default): the gel in total Lagrangian form and the fluid domain following "
                        "the gel's surface, right at any strain; small: every field on its undeformed "
                        "domain, exact to the size of the strains (~1e-6 at Table 1 loads) (case.kinematics)")


def _add_solver_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("solver options")
    g.add_argument("--scheme", choices=SCHEMES, default=None,
                   help="coupling scheme: serial (Gauss-Seidel: fluid, gel, cell; default) or parallel (Jacobi), "
                        "implicit; serial-explicit / parallel-explicit: one exchange per time window "
                        "(time-dependent runs, for comparison) (coupling.scheme)")
    g.add_argument("--acceleration", choices=ACCELERATIONS, default=None,
                   help="coupling acceleration (default iqn-ils; none for an explicit scheme) "
                        "(coupling.acceleration.type)")
    g.add_argument("--gamma2", choices=GAMMA2, default=None,
                   help="the split on Gamma2: schur (default): the cell takes the gel's displacement and the gel "
                        "carries the cell's interface stiffness (a Robin condition with the cell's Steklov-Poincare "
                        "operator); dirichlet: plain Dirichlet-Neumann; robin: the cell takes the gel's force plus "
                        "springs towards its displacement (Robin-Neumann) (solver.gamma2)")
    g.add_argument("--jacobian-prior", choices=("none", "linearized"), default=None,
                   help="IQN's prior: linearized = the Newton step on the coupled map linearised at rest from the "
                        "three solvers' interface Jacobians, computed once per machine and kept in a disk cache; "
                        "none = the secant model alone.  Default: linearized with at most 4000 interface unknowns "
                        "(mesh-size >= ~0.7), none otherwise (docs/coupling.md); time-dependent runs factorise it "
                        "per step size and scheme, not cached on disk (docs/transient.md) "
                        "(coupling.acceleration.jacobian_prior)")
    g.add_argument("--distribute", metavar="GROUPS", default=None,
                   help="participants in separate MPI process groups: 'name[+name...][:ranks],...', e.g. "
                        "'fluid:1,gel+cell:1' on 2 ranks (ranks omitted: the ranks left split evenly); "
                        "checked before meshing; the outputs are those of the run without it, each field "
                        "copied from its group for the post-processing (coupling.distribute)")
    g.add_argument("--solver", choices=SOLVER_KINDS, default=None,
                   help="the field solvers' linear solves: direct (MUMPS; default), iterative (Krylov with "
                        "multigrid, femtools.krylov) or auto (direct in 2D and for small 3D fields, iterative "
                        "above a number of unknowns per field; the run prints what it picked); with --monolithic "
                        "iterative is FGMRES over a gel-first block sweep, auto direct (solver.kind; "
                        "PETSc options per field: [solver.petsc.FIELD])")
    _flag(g, "--monolithic", help="solve the monolithic reference (all fields in one Newton system) instead "
                                  "(solver.method = \"monolithic\")")
    _flag(g, "--quiet", help="no per-iteration coupling progress (output.progress = false)")


def _add_time_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("time-dependent runs (model.md section 8; times in the paper's unit L0/V0; "
                             "the [time] table)")
    _flag(g, "--transient", help="integrate in time from rest instead of solving the steady state")
    g.add_argument("--dt", type=_number, metavar="DT",
                   help="time step (adaptive: the first one); default: consolidation time / 40 "
                        "(adaptive: Kelvin-Voigt time / 10)")
    g.add_argument("--t-end", type=_number, metavar="T", help="end time (default: until steady)")
    _flag(g, "--until-steady", help="stop when the relative change per consolidation time is below --steady-tol")
    g.add_argument("--time-scheme", choices=("be", "bdf2"), default=None,
                   help="BDF2 (default; from rest a backward Euler step of dt/4, then dt/2) or backward Euler "
                        "(time.scheme)")
    _flag(g, "--adaptive", help="adaptive dt from a local error estimate (tolerance --time-tol)")
    g.add_argument("--time-tol", type=_number, metavar="TOL", help="relative local error per step (default 1e-3)")
    g.add_argument("--steady-tol", type=_number, metavar="TOL",
                   help="steady when the relative change per consolidation time is below TOL (default 1e-4)")
    g.add_argument("--inflow", metavar="SPEC",
                   help="inflow V0 f(t): step (default), ramp:T, sine:MEAN,AMP,PERIOD, square:ON,OFF, "
                        "table:FILE.csv")
    g.add_argument("--output-every", type=int, metavar="N", help="an XDMF frame every N windows (default 5)")
    _flag(g, "--until-periodic", help="a periodic inflow (sine, square, a table whose first and last f are "
                                      "equal, repeated) until one period's response differs from the one before "
                                      "by less than --periodic-tol; the periodic block of summary.json")
    g.add_argument("--periodic-tol", type=_number, metavar="TOL",
                   help="periodic when the cycle-to-cycle change is below TOL (default 1e-3)")
    g.add_argument("--steps-per-period", type=int, metavar="N",
                   help="with --until-periodic: dt = period / N (default 40, or period / --dt)")
    g.add_argument("--resume", metavar="DIR",
                   help="continue the interrupted time-dependent run whose --out was DIR from DIR.partial/")


def _mesh_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("mesh", help="build the meshes of a device and write them as XDMF",
                       description="Build the gmsh model of a device, the region meshes "
                                   "(fluid, gel, cell) and the whole-device mesh with their "
                                   "cell and facet tags; write them as XDMF (one file per region "
                                   "+ whole.xdmf, readable in ParaView) with counts.json and "
                                   "parameters.json into DIR (atomically), and print the number "
                                   "of cells and facets per tag.")
    add_case_arguments(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (replaced)")
    return p


def _run_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("run", help="solve one case (partitioned or monolithic) and write its results",
                       description="Solve a device case: the partitioned fluid-gel-cell coupling (default) or "
                                   "the monolithic reference (--monolithic).  Prints the coupling progress "
                                   "and a table of results, and writes into DIR: summary.json (every "
                                   "quantity, dimensionless and SI), case.toml (the configuration used), "
                                   "fluid.xdmf/gel.xdmf/cell.xdmf (fields for ParaView), "
                                   "gamma1_profiles.h5/.csv, coupling/ (iteration and convergence logs) and "
                                   "PNG figures.  DIR is replaced only when everything has been written.  "
                                   "With --transient the case is integrated in time from rest: one progress "
                                   "line per window, and DIR also gets timeseries.csv/.h5, trajectory.png, "
                                   "iterations.png and the fields at several times in the XDMF files; while "
                                   "it runs (and after an interruption) DIR.partial/ holds the last window's "
                                   "checkpoint, which --resume DIR continues.")
    add_case_arguments(p)
    _add_solver_arguments(p)
    _add_time_arguments(p)
    o = p.add_argument_group("output options")
    _flag(o, "--compare-no-cell", help="also solve the case without the cell and overlay its Gamma1 profiles "
                                       "(output.compare_no_cell)")
    _flag(o, "--no-figures", help="skip the PNG figures (output.figures = false)")
    p.add_argument("--out", metavar="DIR", help="output directory (replaced; required unless --resume)")
    return p


def _sweep_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("sweep", help="run a case for several values of one parameter",
                       description="Run one case per value of --param and write sweep.csv and sweep.json "
                                   "(the summary quantities per value), sweep.png (each quantity against "
                                   "the parameter), case.toml and one summary per run into DIR.  The "
                                   "gel-moduli sweep keeps the dimensional flow speed and the cell moduli in "
                                   "Pa fixed, so Ca and mu_c/mu_s change with it (model.md section 5).  "
                                   "--param ca also draws linearity.png: displacements, strains and "
                                   "stresses divided by Ca, which stay flat while the response is linear.")
    add_case_arguments(p)
    _add_solver_arguments(p)
    p.add_argument("--param", choices=SWEEPS, help="the swept parameter (sweep.param)")
    p.add_argument("--values", nargs="+", type=_number, metavar="V",
                   help="values of the parameter (Ca; multiples of the cell or gel moduli; e in L0) (sweep.values)")
    _flag(p, "--compare-kinematics",
          help="also run every value on the other kinematics path (small vs finite) and record the departure "
               "of the small-strain result from the finite-strain one (sweep.csv, linearity.png) "
               "(sweep.compare_kinematics)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (replaced)")
    return p


def _study_parser(sub) -> argparse.ArgumentParser:
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
    p.add_argument("--update-table", "--update-readme", dest="update_table", metavar="FILE.md",
                   help="replace the study table between the coupling-study markers of this Markdown file "
                        "(docs/coupling-study.md; --update-readme is its earlier name)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (replaced)")
    return p


def build_parser() -> argparse.ArgumentParser:
    from gelcell import __version__
    parser = argparse.ArgumentParser(prog="gelcell", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"gelcell {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="on an error also print the Python traceback; show debug logs (form compiler)")
    sub = parser.add_subparsers(dest="command", title="commands", metavar="COMMAND")
    for make, name in ((_mesh_parser, "mesh"), (_run_parser, "run"), (_sweep_parser, "sweep"),
                       (_study_parser, "study")):
        make(sub).set_defaults(command_name=name)
    return parser
