"""The flexible-tube example (examples/flexible_tube): its coupled answer and its iteration counts.

References: a monolithic Newton solve of the same discrete equations (every
window: flow and wall together), the ordering of the literature's coupling
iteration counts (IQN-ILS fewer than Aitken in every time step, Degroote et
al., Computers & Structures 2009 and 2010), and preCICE's own run of its
elastic-tube-1d tutorial (its iterations per window and its outlet watch
point, ``run.PRECICE_*``; docs/couple-your-own-code.md).
"""

from __future__ import annotations

import importlib.util
import pathlib
import sys

import numpy as np
import pytest

HERE = pathlib.Path(__file__).resolve().parents[2] / "examples" / "flexible_tube"


def _load(name):
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


tube = _load("tube")
run = _load("run")

DT, WINDOWS = 1e-3, 5
PARAMS = tube.TubeParameters(cells=20, period=0.01)


@pytest.fixture(scope="module")
def reference():
    return run.monolithic(PARAMS, DT, WINDOWS)


def _difference(scheme, reference):
    """Radius error relative to r0, pressure error relative to max |p| (both over all cells)."""
    dr = np.max(np.abs(scheme.latest("radius")[:, 0] - reference["r"])) / PARAMS.r0
    dp = np.max(np.abs(scheme.latest("pressure")[:, 0] - reference["p"])) / np.max(np.abs(reference["p"]))
    return dr, dp


@pytest.mark.parametrize("acceleration", ["aitken", "iqn-ils"])
def test_the_coupled_answer_converges_to_the_monolithic_one(reference, acceleration):
    """The distance to the monolithic solution falls with the coupling limit: a limit 1000 times smaller
    leaves at least 100 times less (an observed rate of at least 2/3 of the proportional one)."""
    errors = {}
    for limit in (1e-8, 1e-11):
        _, scheme = run.coupled(PARAMS, run.ACCELERATIONS[acceleration], DT, WINDOWS, limit=limit)
        errors[limit] = _difference(scheme, reference)
    for k in range(2):
        assert errors[1e-11][k] < errors[1e-8][k] / 100, (acceleration, errors)


def test_iqn_ils_takes_fewer_iterations_than_aitken_in_every_window():
    aitken, _ = run.coupled(PARAMS, run.ACCELERATIONS["aitken"], DT, WINDOWS)
    iqn, _ = run.coupled(PARAMS, run.ACCELERATIONS["iqn-ils"], DT, WINDOWS)
    reused, _ = run.coupled(PARAMS, run.ACCELERATIONS["iqn-ils, 8 windows reused"], DT, WINDOWS)
    assert all(i < a for i, a in zip(iqn, aitken)), (iqn, aitken)
    # reuse of past windows: the first window is the same, every later one at most as many
    assert reused[0] == iqn[0] and all(r <= i for r, i in zip(reused[1:], iqn[1:])), (reused, iqn)


PRECICE_WINDOWS = 30


@pytest.fixture(scope="module")
def precice_run():
    """preCICE's elastic-tube-1d with its configuration (IQN-ILS, 8 windows reused), 30 of its 100 windows."""
    result, flow, _ = run.precice_coupled(run.PRECICE_ACCELERATIONS["iqn-ils, 8 windows reused"], PRECICE_WINDOWS)
    return result, np.array([(a, p) for _, a, p in flow.outlet])


def test_precice_tube_takes_the_iterations_of_precices_run(precice_run):
    """Mean iterations per window within 0.5 of preCICE's over the same windows, each window within 2.

    The case and the configuration are the same; what differs is rounding: the
    quasi-Newton columns kept, and what the QR2 filter deletes, depend on
    round-off once a window ends one iteration earlier or later, so single
    windows differ (over all 100: equal in 63, by 1 in 35, by 2 in 2; the first
    10 all equal), while the mean does not (8.56 against 8.57 over 100 windows,
    9.00 against 8.80 over these 30).  Without the reuse of 8 windows (which
    preCICE's configuration has) the mean is 20.7, with Aitken or without the
    pressure measure it is 40 (the limit) or 6.
    """
    result, _ = precice_run
    ours = np.array(result.iterations_per_window)
    published = np.array(run.PRECICE_ITERATIONS[:PRECICE_WINDOWS])
    assert result.converged
    assert abs(ours.mean() - published.mean()) <= 0.5, (ours, published)
    assert np.max(np.abs(ours - published)) <= 2, (ours, published)


def test_precice_tube_answer_is_precices_and_the_monolithic_one(precice_run):
    """The outlet area and pressure after every window: against the monolithic solve of the same equations
    and against preCICE's watch point (windows 10, 20, 30).  Both coupled runs stop at a relative change of
    1e-5; measured over 100 windows: area within 1.2e-7 of either (|a - a0| up to 2e-2), pressure within
    5.5e-6 max |p|."""
    _, outlet = precice_run
    reference = run.monolithic(tube.precice_tube(), run.PRECICE_DT, PRECICE_WINDOWS)["outlet"]
    p_max = np.max(np.abs(reference[:, 1]))
    assert np.max(np.abs(outlet[:, 0] - reference[:, 0])) < 1e-6
    assert np.max(np.abs(outlet[:, 1] - reference[:, 1])) < 5e-5 * p_max
    for k in (10, 20, 30):
        a_pub, p_pub = run.PRECICE_OUTLET[k]
        assert abs(outlet[k - 1, 0] - a_pub) < 1e-6, (k, outlet[k - 1], (a_pub, p_pub))
        assert abs(outlet[k - 1, 1] - p_pub) < 5e-5 * p_max, (k, outlet[k - 1], (a_pub, p_pub))
        # and preCICE's own answer is the monolithic one
        assert abs(reference[k - 1, 0] - a_pub) < 1e-6 and abs(reference[k - 1, 1] - p_pub) < 5e-5 * p_max
