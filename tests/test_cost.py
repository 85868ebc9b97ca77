"""What a run prints and writes about its cost: the unknowns per field and the peak memory (summary ``cost``).

Reference for the unknowns: the meshes' topology, counted independently of
any function space.  A Lagrange P1 space has one dof per vertex, P2 one per
vertex and one per edge, a d-vector P2 space d times that; the global
vertex and edge counts (owned, summed over ranks) make the reference equal
on 1 and 2 ranks.  The fields: fluid P2^d x P1, the fluid mesh's motion
P2^d (finite kinematics), gel P2^d x P2^d x P1, cell P2^d; the monolithic
system P2, P1, P2, P2, P1, P2 (+ P2 motion) of vectors and scalars on the
whole mesh.  Peak memory: positive and below the machine's memory.
"""

from __future__ import annotations

import io

import pytest

from mpi4py import MPI

from gelcell.case import CaseParameters
from gelcell.cli.commands import run_config
from gelcell.cli.parser import build_parser
from gelcell.coupled.device import Device
from gelcell.geometry.meshes import build_meshes
from gelcell.machine import machine_memory
from gelcell.run.solve import solve_monolithic, solve_partitioned
from gelcell.run.steady import run_case
from gelcell.run.transient_case import run_transient_case

MESH = 6.0          # coarse: the counts are exact at any resolution


def _lagrange_counts(msh) -> tuple[int, int, int]:
    """(d, global vertices, global edges) of a mesh."""
    msh.topology.create_entities(1)
    return (msh.geometry.dim, msh.topology.index_map(0).size_global, msh.topology.index_map(1).size_global)


def _p2_vector(msh) -> int:
    d, vertices, edges = _lagrange_counts(msh)
    return d * (vertices + edges)


def _p1(msh) -> int:
    return _lagrange_counts(msh)[1]


def _expected_partitioned(device) -> dict[str, int]:
    meshes = {f: device.meshes.region(f)[0] for f in ("fluid", "gel", "cell") if f != "cell" or device.cell}
    out = {"fluid": _p2_vector(meshes["fluid"]) + _p1(meshes["fluid"])}
    if device.kinematics == "finite":
        out["mesh_motion"] = _p2_vector(meshes["fluid"])
    out["gel"] = 2 * _p2_vector(meshes["gel"]) + _p1(meshes["gel"])
    if "cell" in meshes:
        out["cell"] = _p2_vector(meshes["cell"])
    return out


def _expected_monolithic(msh, kinematics: str) -> dict[str, int]:
    vectors = 5 if kinematics == "finite" else 4          # P2 vector fields; two scalar P1 pressures
    return {"monolithic": vectors * _p2_vector(msh) + 2 * _p1(msh)}


def _assert_memory(cost: dict) -> None:
    per_rank = cost["peak_memory_mb_per_rank"]
    assert len(per_rank) == MPI.COMM_WORLD.size and cost["peak_memory_mb"] == max(per_rank)
    assert all(0 < m < machine_memory() / 2**20 for m in per_rank), per_rank


@pytest.mark.parametrize("case, kinematics", [("shear", "finite"), ("normal", "small")])
def test_partitioned_unknowns_are_the_fields_spaces(case, kinematics):
    p = CaseParameters.default(case, True).with_mesh_size(MESH).replace(kinematics=kinematics)
    run = solve_partitioned(p, verbose=False, checks=False)
    cost = run.summary["cost"]
    assert cost["unknowns"] == _expected_partitioned(run.solver)
    assert ("mesh_motion" in cost["unknowns"]) == (kinematics == "finite")
    _assert_memory(cost)


def test_monolithic_unknowns_are_its_mixed_system():
    p = CaseParameters.default("shear", True).with_mesh_size(MESH)
    run = solve_monolithic(p, checks=False)
    assert run.summary["cost"]["unknowns"] == _expected_monolithic(run.solver.mesh, p.kinematics)
    _assert_memory(run.summary["cost"])


def _config(argv: list[str]):
    return run_config(build_parser().parse_args(["run", *argv, "--mesh-size", str(MESH), "--quiet",
                                                 "--no-figures", "--out", "unused"]))


def _printed(stream: io.StringIO, cost: dict) -> None:
    """Rank 0 printed the cost line with these unknowns."""
    if MPI.COMM_WORLD.rank == 0:
        unknowns = ", ".join(f"{k} {n}" for k, n in cost["unknowns"].items())
        assert f"cost: unknowns {unknowns}; peak memory " in stream.getvalue()


def test_a_steady_run_prints_its_cost():
    stream = io.StringIO()
    summary = run_case(_config(["shear"]), None, stream=stream)
    _printed(stream, summary["cost"])
    _assert_memory(summary["cost"])


@pytest.mark.parametrize("monolithic", [False, True], ids=["partitioned", "monolithic"])
def test_a_time_dependent_run_prints_and_reports_its_cost(monolithic):
    """One window of the shear device (the count does not depend on time)."""
    config = _config(["shear", "--transient", "--dt", "1e-3", "--t-end", "1e-3"]
                     + (["--monolithic"] if monolithic else []))
    stream = io.StringIO()
    summary = run_transient_case(config, None, stream=stream)
    cost = summary["cost"]
    if monolithic:
        msh = build_meshes(config.case, MPI.COMM_WORLD, whole=True).whole[0]
        assert cost["unknowns"] == _expected_monolithic(msh, config.case.kinematics)
    else:
        assert cost["unknowns"] == _expected_partitioned(Device(config.case, transient=True))
    _printed(stream, cost)
    _assert_memory(cost)
