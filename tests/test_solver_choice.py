"""The fields' linear solvers of a run: ``--solver direct|iterative|auto`` and the ``[solver]`` table.

References: the direct (MUMPS) run of the same device, to 1e-8 relative on
every summary quantity (the Krylov solves stop at 1e-11 relative to their
right-hand side, the coupling at a 1e-10 residual: both far below 1e-8, far
above round-off); the global size of the function spaces the solvers build
(the unknowns ``auto`` counts before building them); the precedence and the
errors of tests/test_config.py.  Meshes are coarse (every element size x3):
the iterative device solve is 10-20x slower than the direct one in 2D.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib

import numpy as np
import pytest

from mpi4py import MPI

import ufl
from dolfinx import fem, mesh as dmesh

from gelcell.case import CaseParameters, TimeSettings
from gelcell.cli.commands import run_config
from gelcell.cli.parser import build_parser
from gelcell.coupled import solverchoice
from gelcell.coupled.defaults import coupling_config
from gelcell.coupled.device import Device
from gelcell.errors import ParameterError
from gelcell.output.timeseries import COLUMNS
from gelcell.post.quantities import DeviceQuantities
from gelcell.run.backends import PartitionedBackend
from gelcell.run.solve import solve_monolithic, solve_partitioned
from gelcell.run.steady import run_case
from gelcell.run.transient import TransientRun
from agreement import assert_quantities_agree
from transient_cases import tau

MESH = 3.0          # test-sized: every element size x3
#: the time-dependent comparison on a coarser mesh: ~30 Krylov-solved coupling iterations in two windows
#: (the comparison is of one discrete system on two solver paths: no resolution is needed)
TRANSIENT_MESH = 6.0
RTOL = 1e-8


def _params(case: str, mesh_size: float = MESH) -> CaseParameters:
    return CaseParameters.default(case, True).with_mesh_size(mesh_size)


# --------------------------------------------------------------------------- iterative = direct
@pytest.mark.parametrize("case", ["shear", "normal"])
def test_iterative_equals_direct_on_the_steady_device(case):
    p = _params(case)
    direct = solve_partitioned(p, verbose=False, checks=False, solver="direct")
    iterative = solve_partitioned(p, verbose=False, checks=False, solver="iterative")
    assert direct.summary["coupling"]["converged"] and iterative.summary["coupling"]["converged"]
    solver = iterative.summary["solver"]
    assert (solver["kind"], solver["fields"]) == ("iterative", dict.fromkeys(solverchoice.FIELDS, "iterative"))
    # every field's Krylov solves are counted, each converged in at least one iteration
    assert set(solver["krylov"]) == {"fluid", "mesh_motion", "gel", "cell"}
    for field, krylov in solver["krylov"].items():
        assert krylov["solves"] > 0 and krylov["iterations"] >= krylov["solves"], field
    assert direct.summary["solver"] == {"kind": "direct", "fields": dict.fromkeys(solverchoice.FIELDS, "direct")}
    assert_quantities_agree(iterative.summary, direct.summary, case, RTOL)


def _series(solver: str, windows: int) -> dict:
    """The time series of the shear device with its cell over ``windows`` backward-Euler windows from rest
    (each window's coupling converged to its 1e-10 residual)."""
    p = _params("shear", TRANSIENT_MESH)
    settings = TimeSettings(transient=True, dt=tau(p) / 40, t_end=windows * tau(p) / 40, scheme="be")
    device = Device(p, MPI.COMM_WORLD, transient=True, time_scheme=settings.scheme, inflow=settings.waveform,
                    solver=solver)
    config = {**coupling_config(with_cell=True, transient=True), "verbose": False}
    state = TransientRun(PartitionedBackend(device, config, MPI.COMM_WORLD), p, settings, MPI.COMM_WORLD).run()
    return {c: np.array([r[c] for r in state["rows"]], dtype=float) for c in COLUMNS}


def test_iterative_equals_direct_in_a_time_dependent_run():
    """Two windows from rest (the undrained start and a step on its history): every quantity of every window
    to 1e-8."""
    direct, iterative = _series("direct", 2), _series("iterative", 2)
    assert len(direct["t"]) == len(iterative["t"]) == 3          # t = 0 and the two windows
    assert np.array_equal(direct["t"], iterative["t"])
    for column in DeviceQuantities.TIMESERIES:
        scale = np.abs(direct[column]).max()
        assert np.all(np.abs(iterative[column] - direct[column]) <= RTOL * scale), column


# --------------------------------------------------------------------------- auto
def test_auto_counts_the_unknowns_of_the_spaces_the_solvers_build():
    msh = dmesh.create_box(MPI.COMM_WORLD, [[0, 0, 0], [1, 1, 1]], [2, 3, 2], dmesh.CellType.tetrahedron)
    P2, P1 = ufl.VectorElement("Lagrange", msh.ufl_cell(), 2), ufl.FiniteElement("Lagrange", msh.ufl_cell(), 1)
    for field, element in (("fluid", ufl.MixedElement([P2, P1])), ("gel", ufl.MixedElement([P2, P2, P1])),
                           ("cell", P2)):
        W = fem.FunctionSpace(msh, element)
        assert solverchoice.field_unknowns(msh, field) == W.dofmap.index_map.size_global * W.dofmap.index_map_bs


def test_auto_is_direct_in_2d_and_switches_at_the_threshold_in_3d(monkeypatch):
    square = dmesh.create_unit_square(MPI.COMM_WORLD, 4, 4)
    box = dmesh.create_unit_cube(MPI.COMM_WORLD, 2, 2, 2, dmesh.CellType.tetrahedron)
    n = solverchoice.field_unknowns(box, "gel")
    assert n <= solverchoice.AUTO_ITERATIVE_MIN_UNKNOWNS
    assert solverchoice.choose("auto", box, "gel") == "direct"
    monkeypatch.setattr(solverchoice, "AUTO_ITERATIVE_MIN_UNKNOWNS", n - 1)
    assert solverchoice.choose("auto", box, "gel") == "iterative"
    assert solverchoice.choose("auto", square, "gel") == "direct"
    for kind in ("direct", "iterative"):
        assert solverchoice.choose(kind, box, "cell") == kind


def test_a_device_says_what_auto_picked():
    device = Device(_params("shear"), solver="auto")
    assert device.solver_kinds == dict.fromkeys(solverchoice.FIELDS, "direct")
    with pytest.raises(ValueError, match="solver = 'krylov'"):
        Device(_params("shear"), solver="krylov")


# --------------------------------------------------------------------------- configuration
def config_of(argv: list[str], tmp_path=None, file_text: str | None = None):
    """The RunConfig of ``gelcell run ARGV`` (with ``--config`` of ``file_text`` if given)."""
    if file_text is not None:
        path = tmp_path / "case.toml"
        path.write_text(file_text)
        argv = argv + ["--config", str(path)]
    return run_config(build_parser().parse_args(["run", *argv, "--out", "unused"]))


def test_the_command_line_beats_the_file_and_the_file_beats_the_default(tmp_path):
    text = '[case]\nname = "shear"\n[solver]\nkind = "iterative"\n[solver.petsc.gel]\nksp_rtol = 1e-12\n'
    assert config_of(["shear"]).solver.kind == "direct"
    from_file = config_of([], tmp_path, text)
    assert from_file.solver.kind == "iterative" and from_file.solver.petsc == {"gel": {"ksp_rtol": 1e-12}}
    both = config_of(["--solver", "auto"], tmp_path, text)
    assert both.solver.kind == "auto" and both.solver.petsc == {"gel": {"ksp_rtol": 1e-12}}
    sweep = build_parser().parse_args(["sweep", "shear", "--solver", "iterative", "--param", "ca", "--values", "1",
                                       "--out", "unused"])
    assert run_config(sweep).solver.kind == "iterative"


@pytest.mark.parametrize("text, words", [
    ('[solver]\nkind = "krylov"\n', ["solver.kind", "'krylov'", "direct", "iterative", "auto"]),
    ('[solver.petsc.fluids]\nksp_rtol = 1e-9\n', ["solver.petsc.fluids", "fluid", "gel", "cell"]),
    ('[solver.petsc]\ngel = 3\n', ["solver.petsc.gel", "table of PETSc options"]),
    ('[solver]\npetsc = 3\n', ["solver.petsc", "table"]),
    ('[solver]\nmethod = "monolithic"\n[solver.petsc.gel]\nksp_rtol = 1e-9\n', ["solver.petsc.gel", "monolithic"]),
], ids=["kind", "petsc-field", "petsc-options", "petsc-table", "petsc-monolithic"])
def test_a_bad_solver_table_is_refused_naming_the_key(tmp_path, text, words):
    with pytest.raises(ParameterError) as info:
        config_of([], tmp_path, '[case]\nname = "shear"\n' + text)
    for word in words:
        assert word in str(info.value), (word, str(info.value))


def test_the_monolithic_flag_takes_every_solver_kind():
    for kind in ("direct", "iterative", "auto"):
        config = config_of(["shear", "--monolithic", "--solver", kind])
        assert config.solver.monolithic and config.solver.kind == kind


@pytest.mark.skip_in_parallel
def test_a_bad_solver_on_the_command_line_is_refused_before_meshing(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "gelcell.cli", "run", "shear", "--solver", "krylov", "--out", "o"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2 and "--solver" in proc.stderr and "auto" in proc.stderr
    assert not (tmp_path / "o").exists()


def test_the_run_prints_and_writes_what_it_picked(tmp_path, shared_tmp_path, capsys):
    text = '[case]\nname = "shear"\n[mesh]\nsize_factor = 3.0\n[solver]\nkind = "auto"\n' \
           '[solver.petsc.gel]\nmat_mumps_icntl_14 = 80\n[output]\nfigures = false\n'
    config = config_of(["--quiet"], tmp_path, text)
    out = shared_tmp_path / "run"
    run_case(config, str(out), fields=False)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["solver"] == {"kind": "auto", "fields": dict.fromkeys(solverchoice.FIELDS, "direct")}
    if MPI.COMM_WORLD.rank == 0:                     # rank 0 prints
        assert "linear solvers: auto -> fluid direct, gel direct, cell direct" in capsys.readouterr().out
    written = tomllib.loads((out / "case.toml").read_text())["solver"]
    assert written["kind"] == "auto" and written["petsc"] == {"gel": {"mat_mumps_icntl_14": 80}}


def test_petsc_options_reach_their_field_only():
    """Direct: the gel's MUMPS ordering from [solver.petsc.gel], the others keep the steady default (AMF, 2);
    iterative: the cell's Krylov iteration limit from [solver.petsc.cell], the others keep the default."""
    device = Device(_params("shear"), petsc_options={"gel": {"mat_mumps_icntl_7": 0}})
    assert device.gel.newton.solver.ordering == 0
    for solver in (device.fluid.newton.solver, device.fluid.motion.solver.solver, device.cell._newton.solver):
        assert solver.ordering == 2
    device = Device(_params("shear"), solver="iterative", petsc_options={"cell": {"ksp_max_it": 77}})
    assert device.cell._newton.solver.max_it == 77
    for solver in (device.fluid.newton.solver, device.fluid.motion.solver.solver, device.gel.newton.solver):
        assert solver.max_it == 1000, solver.name


def test_a_monolithic_summary_says_direct():
    run = solve_monolithic(_params("shear"), checks=False, solver="auto")
    assert run.summary["solver"] == {"kind": "auto", "fields": {"monolithic": "direct"}}
