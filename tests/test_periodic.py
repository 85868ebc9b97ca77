"""``--until-periodic``: the cycle statistics, the stop rule, a device run, and bad input.

The statistics and the stop rule are those of ``gelcell.post.periodic.PeriodicMonitor``, checked on
a toy participant with a closed form: the first-order system y' = (f(t) - y)/tau, f = m + a sin(w t),
stepped by backward Euler, y_{n+1} = (y_n + h f_{n+1}) / (1 + h), h = dt/tau.  Its exact discrete
solution from y_0 is

    y_n = m + a Im(H e^{i w t_n}) + e_0 (1 + h)^{-n},   H = h / (1 + h - e^{-i w dt}),
    e_0 = y_0 - m - a Im(H),

whose periodic part lags f by -arg(H)/w, and tends, as dt -> 0, to the continuous periodic
response: amplitude a / sqrt(1 + (w tau)^2), lag atan(w tau) / w, with a first-order error.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from mpi4py import MPI

from gelcell import cli
from gelcell.case import TimeSettings
from gelcell.case.inflow import parse_inflow
from gelcell.errors import ParameterError
from gelcell.post.periodic import PeriodicMonitor
from gelcell.run.solve import solve_partitioned
from transient_cases import case, tau

COMM = MPI.COMM_WORLD
MEAN, AMP, TAU = 1.0, 0.5, 0.3
#: the toy's centroid moves as (y, -Y_GAIN y): a component that moves against the inflow
Y_GAIN = 0.25


# ----------------------------------------------------------------------------- the toy
def discrete_h(period: float, steps: int) -> complex:
    """H = h / (1 + h - e^{-i w dt}): backward Euler's periodic response to e^{i w t} (module docstring)."""
    dt, w = period / steps, 2 * np.pi / period
    h = dt / TAU
    return h / (1 + h - np.exp(-1j * w * dt))


def discrete_response(n: np.ndarray, period: float, steps: int, y0: float) -> np.ndarray:
    """The exact backward-Euler solution y_n of the toy from y_0 (module docstring)."""
    dt, w = period / steps, 2 * np.pi / period
    h = dt / TAU
    H = discrete_h(period, steps)
    periodic = MEAN + AMP * np.imag(H * np.exp(1j * w * n * dt))
    e0 = y0 - MEAN - AMP * np.imag(H)
    return periodic + e0 * (1 + h) ** (-n.astype(float))


def discrete_lag(period: float, steps: int) -> float:
    return -np.angle(discrete_h(period, steps)) / (2 * np.pi / period)


def toy_row(t: float, f: float, y: float) -> dict:
    """A time-series row of the toy as the device's rows name the cell's quantities."""
    return {"t": t, "inflow": f, "centroid_x": y, "centroid_y": -Y_GAIN * y, "cell_strain_max": 2e-6 * y,
            "cell_stress_max": 3e-8 * y}


def run_toy(period: float, steps: int, tol: float, y0: float = 0.0, max_cycles: int = 50):
    """Step the toy by backward Euler until the monitor stops it; returns (rows, monitor)."""
    f = parse_inflow(f"sine:{MEAN},{AMP},{period!r}")
    monitor = PeriodicMonitor(period, steps, tol, max_cycles, with_cell=True)
    dt, y = period / steps, y0
    rows = [toy_row(0.0, f(0.0), y)]
    while not monitor.done(rows):
        t = len(rows) * dt
        y = (y + dt / TAU * f(t)) / (1 + dt / TAU)
        rows.append(toy_row(t, f(t), y))
    return rows, monitor


class _Params:
    """The unit conversions the summary asks of a case (the identity)."""

    def to_si(self, value, kind):
        return value

    def to_report(self, value, kind):
        return value


def test_toy_stops_at_the_cycle_the_closed_form_change_implies():
    """From rest the start-up decays by rho = (1 + h)^(-N) per cycle: change_k follows the closed form and
    the run stops at its first cycle below the tolerance."""
    period, steps, tol = 1.0, 20, 1e-4
    rows, monitor = run_toy(period, steps, tol)
    y = discrete_response(np.arange(40 * steps + 1), period, steps, 0.0)
    np.testing.assert_allclose([r["centroid_x"] for r in rows], y[:len(rows)], rtol=1e-13)
    expected = []
    for k in range(2, 40):
        last, previous = y[(k - 1) * steps + 1: k * steps + 1], y[(k - 2) * steps + 1: (k - 1) * steps + 1]
        # every tracked group is y times a constant: each group's relative change is y's
        expected.append(np.max(np.abs(last - previous)) / np.max(np.abs(last)))
    cycles = 2 + int(np.argmax(np.array(expected) < tol))
    assert monitor.cycles(rows) == cycles and len(rows) == cycles * steps + 1
    changes = [monitor.change(rows, k) for k in range(2, cycles + 1)]
    np.testing.assert_allclose(changes, expected[:cycles - 1], rtol=1e-10)
    assert changes[-1] < tol <= changes[-2]
    block = monitor.summary(rows, _Params())
    assert block["converged"] and block["cycles"] == cycles and block["change"] == changes[-1]
    # the geometric tail: the start-up decays by exactly rho per cycle (the ratio of changes differs from rho
    # by the change of the scale max|y_k| between cycles, ~ the start-up left: 1e-4 here)
    rho = (1 + period / steps / TAU) ** (-steps)
    assert block["estimated_distance"] == pytest.approx(changes[-1] * rho / (1 - rho), rel=1e-3)


def test_toy_cycle_statistics_equal_the_discrete_closed_form():
    """Started on its periodic state, the toy's cycles are periodic from the first: min, mean, max,
    excursion and lag of the sampled closed form, to round-off."""
    period, steps = 2.0, 16
    w = 2 * np.pi / period
    y0 = MEAN + AMP * np.imag(discrete_h(period, steps))
    rows, monitor = run_toy(period, steps, 1e-9, y0=y0)
    assert monitor.cycles(rows) == 2
    block = monitor.summary(rows, _Params())
    last = block["per_cycle"][-1]
    y = discrete_response(np.arange(steps + 1, 2 * steps + 1), period, steps, y0)
    assert last["cell_strain"]["min"] == pytest.approx(2e-6 * y.min(), rel=1e-12)
    assert last["cell_strain"]["max"] == pytest.approx(2e-6 * y.max(), rel=1e-12)
    # the mean of a sampled sinusoid over whole periods is its mean: the system's DC gain is 1
    assert last["cell_strain"]["mean"] == pytest.approx(2e-6 * MEAN, rel=1e-12)
    assert last["cell_stress"]["mean"] == pytest.approx(3e-8 * MEAN, rel=1e-12)
    assert last["centroid_mean"]["x"] == pytest.approx(MEAN, rel=1e-12)
    ptp = y.max() - y.min()
    excursion = last["centroid_excursion"]
    assert excursion["x"] == pytest.approx(ptp, rel=1e-12)
    assert excursion["y"] == pytest.approx(Y_GAIN * ptp, rel=1e-12)
    assert excursion["path"] == pytest.approx(math.hypot(1, Y_GAIN) * ptp, rel=1e-12)
    lag = discrete_lag(period, steps)
    gain = abs(discrete_h(period, steps))
    for q in ("centroid_x", "cell_strain_max", "cell_stress_max"):
        assert last["phase_lag"][q]["time"] == pytest.approx(lag, rel=1e-10), q
        assert last["phase_lag"][q]["degrees"] == pytest.approx(math.degrees(lag * w), rel=1e-10), q
    assert last["phase_lag"]["centroid_x"]["amplitude"] == pytest.approx(AMP * gain, rel=1e-10)
    assert last["phase_lag"]["centroid_x"]["gain"] == pytest.approx(gain, rel=1e-10)
    # moving against the inflow: half a period more lag, wrapped into (-P/2, P/2]
    assert last["phase_lag"]["centroid_y"]["time"] == pytest.approx(lag - period / 2, rel=1e-10)
    assert block["phase_lag"]["quantity"] == "centroid_x"


def test_toy_lag_and_amplitude_converge_to_the_continuous_response_at_first_order():
    """Backward Euler: the lag and amplitude errors against atan(w tau)/w and a/sqrt(1+(w tau)^2) halve
    with dt."""
    period = 1.0
    w = 2 * np.pi / period
    lag_exact, amp_exact = math.atan(w * TAU) / w, AMP / math.sqrt(1 + (w * TAU) ** 2)
    errors = []
    for steps in (40, 80, 160):
        rows, monitor = run_toy(period, steps, 1e-10)
        lag = monitor.summary(rows, _Params())["per_cycle"][-1]["phase_lag"]["centroid_x"]
        errors.append((abs(lag["time"] - lag_exact), abs(lag["amplitude"] - amp_exact)))
    errors = np.array(errors)
    rates = np.log2(errors[:-1] / errors[1:])
    assert np.all(np.abs(rates - 1.0) < 0.1), (errors, rates)
    assert errors[-1, 0] < period / 160 / 2          # backward Euler lags by about half a step more


# ----------------------------------------------------------------------------- waveforms
def test_periodic_waveforms(tmp_path):
    csv = tmp_path / "pump.csv"
    csv.write_text("t,f\n0,0.5\n1e-6,1\n3e-6,0\n4e-6,0.5\n")
    settings = TimeSettings(transient=True, until_periodic=True, inflow=f"table:{csv}")
    f = settings.waveform
    assert f.period == pytest.approx(4e-6) and f.constant_after is None
    t = np.linspace(0, 4e-6, 9)
    np.testing.assert_allclose(f(t + 4e-6), f(t), atol=1e-12)
    np.testing.assert_allclose(f(np.array([5e-6, 6e-6])), [1.0, 0.5])
    assert settings.resolved(case("shear"))["dt"] == pytest.approx(4e-6 / 40)
    # without until_periodic the same table is held at its last value
    assert TimeSettings(transient=True, inflow=f"table:{csv}", t_end=1e-5).waveform(5e-6) == 0.5
    # a square wave sampled on its edges gives the same f in every period despite round-off in t
    square = parse_inflow("square:1e-7,2e-7")
    dt = 3e-7 / 30
    samples = square(np.cumsum(np.full(300, dt)))          # t accumulated as the run does
    np.testing.assert_array_equal(samples.reshape(10, 30), np.tile(samples[:30], (10, 1)))


# ----------------------------------------------------------------------------- bad input
def _cli(*args) -> int:
    return cli.main(list(args))


BAD = [
    (["--inflow", "step"], "inflow"),
    (["--inflow", "ramp:1e-6"], "inflow"),
    (["--inflow", "table:{open_table}"], "inflow"),
    (["--inflow", "sine:1,0.5,3e-6", "--until-steady"], "time.until_steady"),
    (["--inflow", "sine:1,0.5,3e-6", "--t-end", "1e-5"], "time.t_end"),
    (["--inflow", "sine:1,0.5,3e-6", "--adaptive"], "time.adaptive"),
    (["--inflow", "sine:1,0.5,3e-6", "--periodic-tol", "0"], "time.periodic_tol"),
    (["--inflow", "sine:1,0.5,3e-6", "--periodic-tol=-1e-3"], "time.periodic_tol"),
    (["--inflow", "sine:1,0.5,3e-6", "--periodic-tol", "1"], "time.periodic_tol"),
    (["--inflow", "sine:1,0.5,3e-6", "--steps-per-period", "3"], "time.steps_per_period"),
    (["--inflow", "sine:1,0.5,3e-6", "--dt", "7e-7"], "time.dt"),
    (["--inflow", "sine:1,0.5,3e-6", "--dt", "3e-7", "--steps-per-period", "20"], "time.steps_per_period"),
]


@pytest.mark.parametrize("args,name", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_periodic_input_is_refused_before_meshing(tmp_path, cli_stderr, monkeypatch, args, name):
    import gelcell.geometry.meshes as meshes

    def no_mesh(params):
        raise AssertionError("meshed")
    monkeypatch.setattr(meshes, "_device_arrays", no_mesh)
    table = tmp_path / "open.csv"
    table.write_text("t,f\n0,0\n1e-6,1\n")                 # first and last f differ: not periodic
    out = tmp_path / "out"
    args = [a.format(open_table=table) for a in args]
    assert _cli("run", "shear", "--transient", "--until-periodic", *args, "--out", str(out)) == 2
    err = cli_stderr()
    assert name in err and "meshed" not in err, err
    assert not out.exists() and not (tmp_path / "out.partial").exists()


def test_max_cycles_below_two_is_refused():
    with pytest.raises(ParameterError, match="time.max_cycles"):
        TimeSettings(transient=True, until_periodic=True, inflow="sine:1,0.5,1e-6", max_cycles=1)


# ----------------------------------------------------------------------------- the device
def test_device_run_until_periodic(shared_tmp_path, cli_stderr):
    """The shear device at mesh size 3 under sine:1,0.5,2 tau_c, 10 steps per period: the start-up decays
    ~100x per period, so the run stops at the first cycle whose change is below 1e-3.

    Closed form: the response is linear in f to O(strain) ~ 1e-6, and the mean of a linear system's
    periodic response to m + a sin is its steady response to m (its DC gain times m; exact for the
    sampled response of a time-invariant discretisation); the last cycle's mean centroid is the steady
    centroid to the remaining start-up (``estimated_distance``) plus that nonlinearity (measured: 4e-8)."""
    p = case("shear")
    period = 2 * tau(p)
    out = os.path.join(shared_tmp_path, "periodic")
    assert _cli("run", "shear", "--mesh-size", "3", "--transient", "--until-periodic", "--inflow",
                f"sine:{MEAN},{AMP},{period!r}", "--steps-per-period", "10", "--no-figures", "--quiet",
                "--out", out) == 0
    with open(os.path.join(out, "summary.json")) as fh:
        block = json.load(fh)["periodic"]
    cycles = block["per_cycle"]
    changes = [c["change"] for c in cycles]
    assert block["converged"] and block["cycles"] == len(cycles) >= 3
    assert changes[0] is None and all(c >= block["tolerance"] for c in changes[1:-1])
    assert changes[-1] < block["tolerance"] == 1e-3
    assert block["period"] == pytest.approx(period) and block["steps_per_period"] == 10
    steady = solve_partitioned(p, verbose=False, checks=False).summary["cell"]["centroid_displacement"]
    last = cycles[-1]
    scale = abs(steady[0])
    assert abs(last["centroid_mean"]["x"] - MEAN * steady[0]) <= (block["estimated_distance"] + 1e-6) * scale
    assert abs(last["centroid_mean"]["y"] - MEAN * steady[1]) <= (block["estimated_distance"] + 1e-6) * scale
    # the gel consolidates behind the flow: the centroid lags it by less than a quarter period
    lag = block["phase_lag"]
    assert lag["quantity"] == "centroid_x" and 0 < lag["time"] < period / 4
    assert last["cell_strain"]["min"] < last["cell_strain"]["mean"] < last["cell_strain"]["max"]
    assert last["centroid_excursion"]["x"] > 0.1 * abs(steady[0])


def test_without_a_cell_the_gel_is_tracked():
    """No cell: the change, statistics and lag are those of the gel's max |u_s| (here the toy's y)."""
    period, steps = 1.0, 20
    rows, _ = run_toy(period, steps, 1e-6)
    gel_rows = [{"t": r["t"], "inflow": r["inflow"], "max_network_displacement": r["centroid_x"]} for r in rows]
    monitor = PeriodicMonitor(period, steps, 1e-6, 50, with_cell=False)
    assert monitor.done(gel_rows) and not monitor.done(gel_rows[:-steps])
    block = monitor.summary(gel_rows, _Params())
    last = block["per_cycle"][-1]
    assert block["phase_lag"]["quantity"] == "max_network_displacement"
    assert last["phase_lag"]["max_network_displacement"]["time"] == pytest.approx(discrete_lag(period, steps),
                                                                                   rel=1e-5)
    assert last["network_displacement"]["mean"] == pytest.approx(MEAN, rel=1e-5)
    assert "cell_strain" not in last and "network_displacement_um" in block["last_cycle_si"]
