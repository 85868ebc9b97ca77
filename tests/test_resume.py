"""Exact resume of a time-dependent run (issue 31, target 4).

A run stopped by SIGINT, SIGTERM or a crash and resumed with ``--resume``
must repeat the uninterrupted run: in serial bit for bit, the coupling
iterations of every window included (every piece of state the next window
depends on is in the checkpoint: the quasi-Newton columns and weights, the
extrapolation history, the participants' unknowns and displacement history,
the step controller, whether each Newton solver's unknowns are still its
last solution, where the next solve takes its linear path, and the coupling's
window records, so that its logs cover the whole run); on 2 ranks to
1e-10 (MUMPS schedules its parallel factorisation dynamically, so two
uninterrupted runs differ in round-off, which the coupling tolerance 1e-10
bounds: measured up to 8e-11 of a quantity's largest value, and by one
iteration in some windows, so on several ranks the counts are not compared).

The interruptions land in different places: early (before window 2),
inside a coupling iteration (SIGINT), a crash of a participant's solve,
while a frame is written, while the checkpoint is written, in the window
retaken after a rejected adaptive step, and in the second cycle of an
``--until-periodic`` run (whose cycle statistics must come out the same).  The
signal is sent by the process to itself where the test patches in a hook, so
that it lands exactly there.
"""

from __future__ import annotations

import json
import os
import signal
import time

import h5py
import numpy as np
import pytest

from mpi4py import MPI

import coupling.schemes
from coupling.errors import CouplingDivergedError
from coupling.serialization import load_npz
import gelcell.run.transient
from gelcell.case import OutputSettings, RunConfig, TimeSettings
from gelcell.coupled.participants import CellParticipant, GelParticipant
from gelcell.errors import Interrupted, install_signal_handlers
from gelcell.output.timeseries import COLUMNS
from gelcell.run.backends import PartitionedBackend
from gelcell.run.transient import TransientRun
from gelcell.run.transient_case import run_transient_case
from transient_cases import case, tau

COMM = MPI.COMM_WORLD
NO_FIGURES = OutputSettings(figures=False)
#: the issue's step on the coarse mesh; 8 windows, a frame every 3
FIXED = TimeSettings(transient=True, dt=5e-8, t_end=4e-7, output_every=3)


def adaptive_settings() -> TimeSettings:
    """Adaptive BDF2 whose 4th attempt is rejected (the step doubles, then the error is too large)."""
    p = case("shear")
    return TimeSettings(transient=True, dt=tau(p) / 10, t_end=tau(p) / 2, scheme="bdf2", adaptive=True,
                        time_tol=1e-2, output_every=2)


def periodic_settings() -> TimeSettings:
    """Until periodic under a sine of period 2 tau_c, 6 steps per period: 3 cycles, 18 windows."""
    p = case("shear")
    return TimeSettings(transient=True, until_periodic=True, inflow=f"sine:1,0.5,{2 * tau(p)!r}",
                        steps_per_period=6, periodic_tol=1e-2, output_every=2)


SETTINGS = {"fixed": lambda: FIXED, "adaptive": adaptive_settings, "periodic": periodic_settings}


def read_series(directory) -> dict:
    with h5py.File(os.path.join(directory, "timeseries.h5"), "r") as h5:
        return {c: h5[c][()] for c in COLUMNS}


def coupling_log(directory, name: str) -> list[dict]:
    """A coupling log of the run (coupling-NAME.json) without the wall times."""
    with open(os.path.join(directory, "coupling", f"coupling-{name}.json")) as fh:
        return [{k: v for k, v in row.items() if k != "solve_time"} for row in json.load(fh)]


def shared(tmp_path_factory, name: str) -> str:
    path = COMM.bcast(str(tmp_path_factory.mktemp(name)) if COMM.rank == 0 else None, root=0)
    return os.path.join(path, "run")


def run(settings: TimeSettings, out: str, resume: bool = False) -> dict:
    with install_signal_handlers():            # as the command line: SIGINT/SIGTERM raise Interrupted
        return run_transient_case(RunConfig(case("shear"), time=settings, output=NO_FIGURES), out, comm=COMM,
                                  fields=False, resume=resume)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """The uninterrupted runs of every entry of SETTINGS: its name -> (series, summary, directory)."""
    out = {}
    for name, settings in SETTINGS.items():
        directory = shared(tmp_path_factory, name)
        summary = run(settings(), directory)
        out[name] = (read_series(directory) if COMM.rank == 0 else None, summary, directory)
    return out


def signal_self(signum: int) -> None:
    """Send ``signum`` to this process and let its handler (Interrupted) run here."""
    os.kill(os.getpid(), signum)
    time.sleep(5)                               # the handler raises before this returns


def on_call(monkeypatch, owner, name: str, call: int, action) -> None:
    """Run ``action()`` at the ``call``-th call of ``owner.name`` (before the original)."""
    original = getattr(owner, name)
    calls = [0]

    def hooked(*args, **kwargs):
        calls[0] += 1
        if calls[0] == call:
            action()
        return original(*args, **kwargs)
    monkeypatch.setattr(owner, name, hooked)


def after_rejection(monkeypatch, signum: int) -> None:
    """Signal at the start of the window retaken after the first rejected step."""
    rejected, window = TransientRun._rejected, PartitionedBackend.window
    armed = [False]

    def judge(self, *args):
        out = rejected(self, *args)
        armed[0] = armed[0] or out
        return out

    def hooked_window(self, t, dt):
        if armed[0]:
            signal_self(signum)
        return window(self, t, dt)
    monkeypatch.setattr(TransientRun, "_rejected", judge)
    monkeypatch.setattr(PartitionedBackend, "window", hooked_window)


def while_checkpointing(monkeypatch, call: int) -> None:
    """SIGTERM while the ``call``-th checkpoint is written (rank 0 writes it: on several ranks every
    rank is signalled as it enters the checkpoint's collective instead)."""
    if COMM.size == 1:
        on_call(monkeypatch, coupling.schemes, "save_npz", call, lambda: signal_self(signal.SIGTERM))
    else:
        on_call(monkeypatch, coupling.schemes.CouplingScheme, "_checkpoint_state", call,
                lambda: signal_self(signal.SIGTERM))


class Crash(RuntimeError):
    pass


def crash():
    raise Crash("simulated crash of a participant's solve")


def in_window(monkeypatch, window: int, owner, name: str, call: int, action) -> None:
    """Run ``action()`` at the ``call``-th call of ``owner.name`` within the ``window``-th window attempt."""
    calls = [0, 0]                              # window attempts, calls within the window
    original_window, original = PartitionedBackend.window, getattr(owner, name)

    def hooked_window(self, t, dt):
        calls[0] += 1
        return original_window(self, t, dt)

    def hooked(*args, **kwargs):
        if calls[0] == window:
            calls[1] += 1
            if calls[1] == call:
                action()
        return original(*args, **kwargs)
    monkeypatch.setattr(PartitionedBackend, "window", hooked_window)
    monkeypatch.setattr(owner, name, hooked)


#: (id, the windows the checkpoint holds, settings, where the interruption lands, the exception it raises)
CASES = [
    ("sigterm-before-window-2", 1, "fixed", lambda mp: on_call(mp, PartitionedBackend, "window", 2,
                                                            lambda: signal_self(signal.SIGTERM)), Interrupted),
    ("sigint-in-iteration-3-of-window-5", 4, "fixed", lambda mp: in_window(
        mp, 5, GelParticipant, "solve", 3, lambda: signal_self(signal.SIGINT)), Interrupted),
    ("crash-in-window-7", 6, "fixed", lambda mp: in_window(mp, 7, CellParticipant, "solve", 1, crash),
     CouplingDivergedError),
    # frames at t = 0 and after windows 3 and 6: the third is that of window 6
    ("sigterm-writing-frame-of-window-6", 5, "fixed", lambda mp: on_call(
        mp, gelcell.run.transient, "write_frame", 3, lambda: signal_self(signal.SIGTERM)), Interrupted),
    # checkpoints at t = 0 and after every window: the fifth is that of window 4
    ("sigterm-writing-checkpoint-of-window-4", 3, "fixed", lambda mp: while_checkpointing(mp, 5), Interrupted),
    ("sigterm-after-a-rejected-step", 1, "adaptive", lambda mp: after_rejection(mp, signal.SIGTERM), Interrupted),
    # the second window of the second cycle (6 windows per cycle)
    ("sigterm-in-cycle-2-until-periodic", 7, "periodic", lambda mp: on_call(
        mp, PartitionedBackend, "window", 8, lambda: signal_self(signal.SIGTERM)), Interrupted),
]


@pytest.mark.parametrize("name,done,kind,hook,error", CASES, ids=[c[0] for c in CASES])
def test_resumed_run_repeats_the_uninterrupted_one(tmp_path_factory, monkeypatch, uninterrupted, name, done, kind,
                                                   hook, error):
    settings = SETTINGS[kind]()
    reference, summary, reference_dir = uninterrupted[kind]
    out = shared(tmp_path_factory, name)
    with monkeypatch.context() as mp:
        hook(mp)
        with pytest.raises(error) as raised:
            run(settings, out)
    if error is CouplingDivergedError:         # the failed solve ends the coupling with its cause
        assert isinstance(raised.value.__cause__, Crash)
    assert os.path.isfile(out + ".partial/checkpoint.npz") and not os.path.exists(out)
    assert int(load_npz(out + ".partial/checkpoint.npz")["window"]) == done      # it landed where meant
    resumed = run(settings, out, resume=True)
    assert resumed["transient"]["rejected_windows"] == summary["transient"]["rejected_windows"]
    if kind == "periodic":                      # the cycles, their statistics and the lag: from the rows
        mine, theirs = resumed["periodic"], summary["periodic"]
        assert mine["converged"] and mine["cycles"] == theirs["cycles"] == 3
        if COMM.size == 1:
            assert mine == theirs
        else:
            assert mine["phase_lag"]["time"] == pytest.approx(theirs["phase_lag"]["time"], rel=1e-8)
    if COMM.rank != 0:
        return
    series = read_series(out)
    assert len(series["t"]) == len(reference["t"])
    logs = {name: (coupling_log(out, name), coupling_log(reference_dir, name)) for name in ("iterations",
                                                                                             "convergence")}
    if COMM.size == 1:
        for c in COLUMNS:                       # bit for bit, iteration counts and residuals included
            assert np.array_equal(series[c], reference[c]), (c, series[c], reference[c])
        for name, (mine, theirs) in logs.items():       # the coupling's logs cover the whole run
            assert mine == theirs, name
    else:
        # two uninterrupted runs on 2 ranks already differ by one iteration in some windows (measured):
        # the iteration counts are not compared, the quantities are
        mine, theirs = logs["iterations"]
        assert [r["window"] for r in mine] == [r["window"] for r in theirs]
        for c in COLUMNS:
            if c not in ("iterations", "residual"):
                scale = max(float(np.max(np.abs(reference[c]))), 1e-300)
                np.testing.assert_allclose(series[c], reference[c], rtol=0, atol=1e-10 * scale, err_msg=c)
