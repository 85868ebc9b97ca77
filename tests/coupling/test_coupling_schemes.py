"""Steady coupling schemes on problems with analytic answers (no finite elements)."""

from __future__ import annotations

import io
import json
import csv

import numpy as np
import pytest

import coupling as cp
from coupling.toys import AffineParticipant, chain_problem, two_bar_problem

RELATIVE = [{"type": "relative", "limit": 1e-12}]


def build(problem, acceleration, scheme="serial-implicit", **options):
    participants, data = problem.build()
    config = {"scheme": scheme, "order": list(problem.order), "verbose": False,
              "convergence": RELATIVE, "acceleration": acceleration, **options}
    return cp.build_scheme(config, participants, data)


def assert_exact(scheme, problem, rtol=1e-10):
    for name, value in problem.exact.items():
        np.testing.assert_allclose(scheme.latest(name), value, rtol=rtol, err_msg=name)


@pytest.mark.parametrize("ratio", [10.0, 100.0])
def test_unrelaxed_dirichlet_neumann_diverges(ratio):
    problem = two_bar_problem(ratio)
    scheme = build(problem, {"type": "none"})
    assert scheme.accelerated == ("Gamma/displacement",)
    with pytest.raises(cp.CouplingDivergedError) as info:
        scheme.solve()
    message = str(info.value)
    assert "residual of data 'Gamma/" in message and "in iteration" in message
    assert "residual norms of 'Gamma/" in message
    result = info.value.result
    assert not result.converged and result.reason.startswith("diverged")
    # the iteration map is d -> -ratio d + c: every residual grows by the stiffness ratio
    norms = [r.residual_norms["Gamma/displacement"] for r in result.windows[0].records]
    np.testing.assert_allclose(np.array(norms[2:]) / np.array(norms[1:-1]), ratio, rtol=1e-9)


@pytest.mark.parametrize("ratio", [10.0, 100.0])
@pytest.mark.parametrize("scheme_name", ["serial-implicit", "parallel-implicit"])
@pytest.mark.parametrize("acceleration", [
    {"type": "aitken", "initial_relaxation": 0.5},
    {"type": "iqn-ils", "initial_relaxation": 0.5},
    {"type": "iqn-imvj", "initial_relaxation": 0.5},
])
def test_accelerated_dirichlet_neumann_matches_the_analytic_answer(ratio, scheme_name, acceleration):
    problem = two_bar_problem(ratio)
    if scheme_name == "parallel-implicit" and acceleration["type"] == "aitken":
        pytest.skip("Aitken does not converge on the Jacobi map (eigenvalues ±i√ratio)")
    scheme = build(problem, acceleration, scheme_name)
    result = scheme.solve()
    assert result.converged and result.reason == "converged"
    assert_exact(scheme, problem, rtol=1e-11)
    # secant / quasi-Newton on a linear map: exact after the first quasi-Newton step
    assert result.iterations <= (4 if scheme_name == "serial-implicit" else 5)


@pytest.mark.parametrize("ratio", [10.0, 100.0])
def test_constant_relaxation_contracts_at_the_predicted_rate(ratio):
    problem = two_bar_problem(ratio)
    omega = problem.relaxation  # 1.5 / (1 + ratio)
    scheme = build(problem, {"type": "constant", "relaxation": omega},
                   convergence=[{"type": "relative", "limit": 1e-10}])
    result = scheme.solve()
    assert result.converged
    norms = np.array([r.residual_norms["Gamma/displacement"] for r in result.windows[0].records])
    np.testing.assert_allclose(norms[1:6] / norms[:5], abs(1.0 - omega * (1.0 + ratio)), rtol=1e-9)
    assert_exact(scheme, problem, rtol=1e-8)


def test_relative_criteria_are_scale_invariant():
    counts = []
    for scale in (1.0, 1e-7, 1e5):
        problem = two_bar_problem(100.0, scale=scale)
        scheme = build(problem, {"type": "iqn-ils"}, "parallel-implicit",
                       convergence=[{"type": "residual-relative", "limit": 1e-10}])
        counts.append(scheme.solve().iterations)
        assert_exact(scheme, problem, rtol=1e-9)
    assert len(set(counts)) == 1, counts


@pytest.mark.parametrize("scheme_name, accelerated", [
    ("serial-implicit", ("Gamma1/force", "Gamma2/force")),
    ("parallel-implicit", ("Gamma1/displacement", "Gamma1/force", "Gamma2/displacement", "Gamma2/force")),
])
@pytest.mark.parametrize("kind", ["iqn-ils", "iqn-imvj", "aitken", "constant"])
def test_three_participants_in_a_chain(scheme_name, accelerated, kind):
    problem = chain_problem()
    if scheme_name == "parallel-implicit" and kind in ("aitken", "constant"):
        pytest.skip("relaxation does not converge on this Jacobi map in reasonable time")
    acceleration = {"type": kind}
    if kind == "constant":
        acceleration["relaxation"] = problem.relaxation
    scheme = build(problem, acceleration, scheme_name, max_iterations=200,
                   convergence=[{"type": "relative", "limit": 1e-11}])
    assert scheme.accelerated == accelerated
    result = scheme.solve()
    assert result.converged
    assert_exact(scheme, problem, rtol=1e-9)
    if kind.startswith("iqn"):
        assert result.iterations <= 2 + len(accelerated) + 1


def test_serial_forward_readers_use_fresh_data():
    """A data read before and after its writer: later readers see the fresh value."""
    n = 3
    ones = np.eye(n)
    b = AffineParticipant("B", "m", n, {("y", "x"): 0.5 * ones}, {"y": np.ones(n)})
    a = AffineParticipant("A", "m", n, {("x", "y"): -0.5 * ones}, {"x": np.full(n, 2.0)})
    c = AffineParticipant("C", "m", n, {("z", "x"): 3.0 * ones}, {"z": np.zeros(n)})
    data = [cp.Data("x", "m", 1, "A", ("B", "C")), cp.Data("y", "m", 1, "B", ("A",)),
            cp.Data("z", "m", 1, "C", ("B",))]
    b.matrices[("y", "z")] = 0.0 * ones
    scheme = cp.build_scheme({"order": ["B", "A", "C"], "verbose": False, "record_data": True,
                              "convergence": RELATIVE, "acceleration": {"type": "iqn-ils"}},
                             [a, b, c], data)
    assert scheme.accelerated == ("x", "z")
    result = scheme.solve()
    assert result.converged
    # fixed point: y = 0.5 x + 1, x = -0.5 y + 2  ->  x = 1.2, y = 1.6, z = 3.6
    np.testing.assert_allclose(scheme.latest("x"), 1.2, rtol=1e-12)
    np.testing.assert_allclose(scheme.latest("y"), 1.6, rtol=1e-12)
    np.testing.assert_allclose(scheme.latest("z"), 3.6, rtol=1e-12)
    for k in range(1, result.iterations + 1):
        fresh = scheme.recording.find("A", k).outputs["x"]
        np.testing.assert_array_equal(scheme.recording.find("C", k).inputs["x"], fresh)


def test_max_iterations_policies():
    problem = two_bar_problem(10.0)
    acceleration = {"type": "constant", "relaxation": problem.relaxation}
    with pytest.raises(cp.CouplingNotConvergedError) as info:
        build(problem, acceleration, max_iterations=3).solve()
    message = str(info.value)
    assert "did not converge in 3 iterations" in message
    assert "worst data 'Gamma/" in message and "relative measure" in message and "history" in message
    assert info.value.result.iterations == 3
    result = build(problem, acceleration, max_iterations=3, on_max_iterations="return").solve()
    assert not result.converged and result.reason == "max_iterations"
    assert len(result.residual_history["Gamma/force"]) == 3


def test_min_iterations_and_suffices():
    problem = two_bar_problem(10.0)
    result = build(problem, {"type": "iqn-ils"}, min_iterations=7).solve()
    assert result.converged and result.iterations == 7
    # an unreachable measure plus a sufficient one
    convergence = [{"type": "absolute", "limit": 1e-300, "data": "Gamma/force"},
                   {"type": "relative", "limit": 1e-10, "data": "Gamma/displacement", "suffices": True}]
    result = build(problem, {"type": "iqn-ils"}, convergence=convergence).solve()
    assert result.converged


class BrokenParticipant(cp.Participant):
    def __init__(self, name, output):
        self.name = name
        self.output = output

    def interface_points(self, mesh_name):
        return np.zeros((2, 1)) + np.arange(2)[:, None]

    def solve(self, inputs):
        return self.output(inputs)


def broken_scheme(output):
    good = AffineParticipant("good", "m", 2, {("b", "a"): np.eye(2)}, {"b": np.ones(2)})
    bad = BrokenParticipant("bad", output)
    data = [cp.Data("a", "m", 1, "bad", ("good",)), cp.Data("b", "m", 1, "good", ("bad",))]
    return cp.build_scheme({"verbose": False, "convergence": RELATIVE, "order": ["good", "bad"]},
                           [good, bad], data)


def test_participant_output_errors_name_the_participant():
    with pytest.raises(ValueError, match=r"participant 'bad': solve\(\) returned data \['c'\] but must "
                                         r"return exactly the data it writes: \['a'\]"):
        broken_scheme(lambda inputs: {"c": np.zeros((2, 1))}).solve()
    with pytest.raises(ValueError, match=r"data 'a' must have shape \(2, 1\)"):
        broken_scheme(lambda inputs: {"a": np.zeros((3, 1))}).solve()
    with pytest.raises(cp.CouplingDivergedError, match=r"data 'a' is not finite \(NaN/Inf\) in iteration 1"):
        broken_scheme(lambda inputs: {"a": np.full((2, 1), np.nan)}).solve()
    with pytest.raises(ValueError, match="two participants are named"):
        cp.build_scheme({"convergence": RELATIVE},
                        [BrokenParticipant("x", None), BrokenParticipant("x", None)],
                        [cp.Data("a", "m", 1, "x", ("y",))])


def test_explicit_scheme_does_one_sweep():
    problem = two_bar_problem(10.0)
    serial = build(problem, {"type": "none"}, "serial-explicit")
    result = serial.solve()
    assert result.converged and result.iterations == 1 and result.reason == "explicit"
    # one Gauss–Seidel sweep from d = 0: force = -f1 L / 2, then the Neumann bar's displacement
    np.testing.assert_allclose(serial.latest("Gamma/force"), -0.5)
    np.testing.assert_allclose(serial.latest("Gamma/displacement"), 1.0 + 0.5)
    parallel = build(problem, {"type": "none"}, "parallel-explicit")
    parallel.solve()
    np.testing.assert_allclose(parallel.latest("Gamma/displacement"), 1.0)  # read force = 0


def test_progress_lines_and_silence(capsys, comm):
    problem = two_bar_problem(10.0)
    stream = io.StringIO()
    participants, data = problem.build()
    scheme = cp.build_scheme({"order": list(problem.order), "convergence": RELATIVE,
                              "acceleration": {"type": "iqn-ils", "initial_relaxation": 0.25}},
                             participants, data, stream=stream)
    result = scheme.solve()
    lines = stream.getvalue().splitlines()
    if comm.Get_rank() > 0:
        assert lines == []  # only rank 0 prints
    else:
        assert len(lines) == result.iterations
        assert lines[0].startswith("it   1  Gamma/force ") and "Gamma/displacement" in lines[0]
        assert lines[0].endswith("omega 0.25")
        assert lines[1].endswith("qn 1 cols")
        assert lines[-1].endswith("converged")
    build(problem, {"type": "iqn-ils"}).solve()  # verbose=False
    assert capsys.readouterr().out == ""
    assert "converged in" in result.summary() and "solve time" in result.summary()


def test_records_are_written_as_csv_and_json(shared_tmp_path, comm):
    problem = chain_problem()
    scheme = build(problem, {"type": "iqn-ils"}, max_iterations=50)
    result = scheme.solve()
    paths = scheme.write_records(shared_tmp_path / "records")
    comm.Barrier()
    directory = shared_tmp_path / "records"
    with open(directory / "coupling-convergence.json") as fh:
        rows = json.load(fh)
    assert len(rows) == result.iterations
    assert rows[0]["relaxation"] == 0.5 and rows[1]["columns_used"] == 1
    assert set(rows[0]["measure_values"]) == set(scheme.data)
    with open(directory / "coupling-convergence.csv") as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == result.iterations
    assert float(table[-1]["measure[Gamma2/force]"]) < 1e-12
    assert "solve_time[B]" in table[0]
    with open(directory / "coupling-iterations.json") as fh:
        windows = json.load(fh)
    assert windows[0]["iterations"] == result.iterations and windows[0]["converged"]
    with open(directory / "coupling-iterations.csv") as fh:
        assert len(list(csv.DictReader(fh))) == 1
    if comm.Get_rank() == 0:
        assert set(paths) == {"iterations_csv", "iterations_json", "convergence_csv", "convergence_json"}


def test_replay_reproduces_a_participant_and_finds_a_changed_one(shared_tmp_path, comm):
    problem = two_bar_problem(10.0)
    scheme = build(problem, {"type": "aitken"}, record_data=True)
    scheme.solve()
    participants, _ = problem.build()
    neumann = participants[1]
    out = cp.replay(neumann, scheme.recording, iteration=2)
    assert out.max_abs_difference == {"Gamma/displacement": 0.0}
    path = shared_tmp_path / "recording.npz"
    if comm.Get_rank() == 0:
        scheme.recording.save(path)
    comm.Barrier()
    loaded = cp.Recording.load(path)
    neumann.k *= 1.01  # a participant that no longer behaves as recorded
    out = cp.replay(neumann, loaded, iteration=2)
    assert out.relative_difference["Gamma/displacement"] > 1e-3
    with pytest.raises(KeyError, match="no recorded solve of 'neumann_bar' at iteration 99"):
        cp.replay(neumann, loaded, iteration=99)


def test_latest_and_mapping_accessors():
    problem = two_bar_problem(10.0)
    scheme = build(problem, {"type": "iqn-ils"})
    scheme.solve()
    value = scheme.latest("Gamma/force")
    value[:] = 0.0
    assert scheme.latest("Gamma/force")[0, 0] != 0.0  # a copy
    np.testing.assert_array_equal(scheme.mapped("Gamma/force", "neumann_bar"), scheme.latest("Gamma/force"))
    with pytest.raises(KeyError, match="unknown data 'Gamma/forces'"):
        scheme.latest("Gamma/forces")


def test_participant_failure_stops_with_history():
    """A participant that raises (e.g. NaN in a field solve) ends the coupling with a
    CouplingDivergedError naming the participant and the iteration, with the records so far."""
    import numpy as np
    import coupling as cp

    class Blows(cp.Participant):
        name = "b"

        def __init__(self):
            self.calls = 0

        def interface_points(self, mesh_name):
            return np.zeros((1, 1))

        def solve(self, inputs):
            self.calls += 1
            if self.calls == 3:
                raise FloatingPointError("Newton iterate contains NaN")
            return {"y": 0.5 * inputs["x"] + 1.0}

    class Echo(cp.Participant):
        name = "a"

        def interface_points(self, mesh_name):
            return np.zeros((1, 1))

        def solve(self, inputs):
            return {"x": inputs["y"] + 0.0}

    data = [cp.Data("x", mesh="m", dim=1, writer="a", readers=("b",)),
            cp.Data("y", mesh="m", dim=1, writer="b", readers=("a",))]
    config = {"scheme": "serial-implicit", "order": ["a", "b"], "max_iterations": 20, "verbose": False,
              "convergence": [{"type": "relative", "limit": 1e-12}], "acceleration": {"type": "none"}}
    scheme = cp.build_scheme(config, [Echo(), Blows()], data)
    try:
        scheme.solve()
    except cp.CouplingDivergedError as err:
        assert "participant 'b' failed in iteration 3" in str(err)
        assert "FloatingPointError" in str(err)
        assert err.result.iterations == 2
    else:
        raise AssertionError("the failing participant did not stop the coupling")
