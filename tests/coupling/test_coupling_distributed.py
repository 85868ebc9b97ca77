"""Participants in separate process groups (coupling.distributed) give the one-process answer.

On 2 ranks (``scripts/pytest-2-ranks``) the comparisons run in this process;
in serial one test launches them under ``mpirun -n 2`` itself.
"""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
import pytest

import coupling as cp
from coupling.parallel import SerialComm
from coupling.toys import chain_problem
from mpi_run import run_mpi

HERE = pathlib.Path(__file__).resolve().parent
spec = importlib.util.spec_from_file_location("coupling_distributed_toy", HERE / "coupling_distributed_toy.py")
toy = importlib.util.module_from_spec(spec)
spec.loader.exec_module(toy)


def _check(record: dict) -> None:
    """Every case: the one-process iterations and values (to 1e-12), the same on every rank; a failure
    in one group reported on every rank with the same message naming the participant."""
    assert record["ranks"] >= 2
    assert len(record["cases"]) == 4
    for case in record["cases"]:
        assert case["converged"], case
        assert case["iterations"] == case["single_iterations"], case
        assert case["max_relative_difference"] <= 1e-12, case
        assert case["replicated"], case
    for scheme, messages in record["failures"].items():
        assert messages[0] is not None and len(set(messages)) == 1, (scheme, messages)
        assert "participant 'C' failed in iteration 2" in messages[0]
        assert "FloatingPointError: the bar's solver broke down" in messages[0]


def test_distributed_toys_match_one_process_here(comm):
    if comm.Get_size() < 2:
        pytest.skip("needs several ranks (the serial run launches mpirun itself)")
    _check(toy.check_all(comm))


def test_distributed_toys_match_one_process_on_two_ranks(comm):
    if comm.Get_size() > 1:
        pytest.skip("already running under mpirun")
    _check(run_mpi(str(HERE / "coupling_distributed_toy.py"), 2, timeout=300))


def test_one_group_in_one_process_is_the_plain_scheme():
    problem = chain_problem()
    grouped, result = toy.solve(problem, "parallel", SerialComm(), "A+B+C")
    plain, plain_result = toy.solve(problem, "parallel", SerialComm())
    assert result.iterations == plain_result.iterations
    for name in plain.data:
        np.testing.assert_array_equal(grouped.latest(name), plain.latest(name))


@pytest.mark.parametrize("spec, message", [
    ("", "expected 'name"),
    ("A:1,B+:1", "empty participant name"),
    ("A:0,B+C", "rank count '0', which must be a positive integer"),
    ("A:x,B+C", "rank count 'x'"),
    ("A,B+C,A", r"names \['A'\] more than once"),
    ("A,B", r"participants \['C'\] are in no group"),
    ("A,B+C+D", r"unknown participants \['D'\]"),
])
def test_bad_specs_are_refused_with_the_allowed_forms(spec, message):
    with pytest.raises(ValueError, match=message) as info:
        cp.parse_distribution(spec, names=("A", "B", "C"))
    assert "distribute = " in str(info.value)


def test_rank_counts_must_fit_the_run():
    with pytest.raises(ValueError, match="needs 3 ranks, but the run has 1"):
        cp.Distribution("A:1,B+C:2", SerialComm(), names=("A", "B", "C"))
    with pytest.raises(ValueError, match="a multiple of 2 for the groups without a count"):
        cp.Distribution("A,B+C", SerialComm(), names=("A", "B", "C"))


def test_a_rank_must_construct_exactly_its_groups_participants():
    participants, data = chain_problem().build()
    distribution = cp.Distribution("A+B+C", SerialComm())
    with pytest.raises(ValueError, match=r"must construct exactly its participants \['A', 'B', 'C'\]"):
        cp.build_scheme({"convergence": [{"type": "relative", "limit": 1e-8}], "verbose": False},
                        participants[:2], data, distribution=distribution)
