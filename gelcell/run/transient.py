"""Time-dependent device runs: the flow switched on from rest (model.md section 8).

Every time window [t, t + dt] is one implicit coupling of the three solvers
(serial IQN-ILS reusing past windows by default; Aitken, IQN-IMVJ, or an
explicit scheme for comparison), or one Newton solve of the monolithic
reference with the same time discretisation.  :class:`TransientRun` steps the
windows with a fixed or an adaptive dt, records one row of quantities per
window, keeps a checkpoint after every window and writes frames of the fields.

Adaptive dt.  The local error of the step is estimated from the gel's
displacement (its only time-differentiated unknown) by comparing the
solution with an explicit extrapolation of the past ones (Milne's device):
linear for backward Euler, LTE ~ dt/(2 dt + dt_prev) |u - u_pred|, quadratic
for BDF2, LTE ~ (2/11) |u - u_pred| (its constant-step factor).  Normalised
by the largest |u| seen so far it must stay below ``time_tol``; a larger one
rejects the window (everything, including the quasi-Newton state, is restored)
and retries with dt (0.9 (tol/err)^(1/(p+1))), at least 0.2 dt.  An accepted
step keeps dt unless that factor allows twice the step, which it then takes:
a piecewise-constant dt lets the windows share one interface operator, so
the quasi-Newton columns of past windows stay valid and each field keeps
its factorisation (docs/transient.md measures the alternative).

Steady state: the relative change of the gel's displacement per consolidation
time, max|u^{n+1} - u^n| / max|u^{n+1}| * tau_c / dt, below ``steady_tol``.

Until periodic: fixed dt = P / N, stopped at the end of the first cycle whose
response differs from the previous one's by less than ``periodic_tol``, or
after ``max_cycles`` cycles (:class:`gelcell.post.periodic.PeriodicMonitor`,
which reads only the rows, so a resumed run continues the same count).
"""

from __future__ import annotations

import math
import os
import time
import zipfile

import numpy as np

from mpi4py import MPI

from femtools.canonical import CanonicalOrder
from gelcell.case import CaseParameters, TimeSettings
from gelcell.errors import ModelLimitError, ParameterError
from gelcell.post.periodic import PeriodicMonitor
from gelcell.post.quantities import DeviceQuantities
from gelcell.run.backends import WindowOutcome
from gelcell.run.frames import FRAMES_DIR, write_frame
from gelcell.run.resume import CHECKPOINT

__all__ = ["TransientRun", "BDF2_START"]

#: the first fixed steps of a BDF2 run from rest, in units of dt: backward Euler at dt/4, then
#: variable-step BDF2 (omega = 2, zero-stable below 1 + sqrt 2); the start's first-order error
#: (3/4) h_1^2 x'' is 1/16 of that of a first step of dt (docs/transient.md, "Accuracy")
BDF2_START = (0.25, 0.5)


# ----------------------------------------------------------------------------- the run
def _max_abs(values: np.ndarray) -> float:
    """max |values| of a replicated array (canonical order: the same number on every rank)."""
    return float(np.max(np.abs(values))) if values.size else 0.0


class TransientRun:
    """Step a backend from rest (or from a checkpoint) to t_end or to steady state.

    Args:
        backend: :class:`PartitionedBackend` or :class:`MonolithicBackend`.
        settings: the validated :class:`TimeSettings`.
        work_dir: where the checkpoint and the frames go (the ``DIR.partial/`` of the run),
            or None for neither.
        say: a function printing one line (rank 0 only).
    """

    def __init__(self, backend, params: CaseParameters, settings: TimeSettings, comm: MPI.Comm,
                 work_dir: str | None = None, say=None):
        self.backend, self.params, self.settings, self.comm = backend, params, settings, comm
        self.work_dir = work_dir
        self.say = say or (lambda msg: None)
        self.waveform = settings.waveform
        self.plan = settings.resolved(params)
        self.tau = self.plan["scales"]["consolidation"]
        self.quantities = DeviceQuantities(backend.fields)
        self.periodic = None if not settings.until_periodic else PeriodicMonitor(
            self.plan["period"], self.plan["steps_per_period"], settings.periodic_tol, settings.max_cycles,
            params.with_cell)
        self.state = {"t": 0.0, "windows": 0, "dt_next": self.plan["dt"], "rows": [], "frames": [],
                      "past": [], "past_times": [], "u_scale": 0.0, "rejected": 0, "wall_time": 0.0,
                      "steady": False}

    # -- checkpoint --------------------------------------------------------------
    @property
    def checkpoint_path(self) -> str | None:
        return None if self.work_dir is None else os.path.join(self.work_dir, CHECKPOINT)

    def _save(self) -> None:
        if self.work_dir is not None:
            self.backend.save(self.checkpoint_path, self.state)

    def resume(self) -> None:
        """Continue from the checkpoint in ``work_dir`` (same case, settings and rank count)."""
        try:
            extra = self.backend.load(self.checkpoint_path)
        except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            raise ParameterError(f"{self.checkpoint_path}: the checkpoint cannot be resumed "
                                 f"({type(exc).__name__}: {exc})") from None
        if not isinstance(extra, dict) or "rows" not in extra:
            raise ParameterError(f"{self.checkpoint_path}: no time-dependent run state in the checkpoint")
        self.state = extra
        self.backend.update_fields()

    # -- one accepted window -------------------------------------------------------
    def _row(self, t: float, iterations: int, residual: float) -> dict:
        row = {"t": t, "inflow": float(self.waveform(t))}
        row.update(self.quantities.timeseries_row())
        row.update(iterations=iterations, residual=residual)
        return row

    def _u(self) -> np.ndarray:
        """The gel's displacement in the partition-independent order (the same on every rank)."""
        if not hasattr(self, "_u_order"):
            self._u_order = CanonicalOrder(self.backend.fields.displacement.function_space)
        return self._u_order.gather(self.backend.fields.displacement.x.array).ravel()

    def _error(self, u: np.ndarray, dt: float) -> float | None:
        """The estimated relative local error of the step just taken (None if not enough history)."""
        past, times = self.state["past"], self.state["past_times"]
        t_new = self.state["t"] + dt
        if self.settings.scheme == "bdf2" and len(past) >= 3:
            # quadratic extrapolation through the last three states
            (u2, u1, u0), (t2, t1, t0) = past[-3:], times[-3:]
            l0 = (t_new - t1) * (t_new - t2) / ((t0 - t1) * (t0 - t2))
            l1 = (t_new - t0) * (t_new - t2) / ((t1 - t0) * (t1 - t2))
            l2 = (t_new - t0) * (t_new - t1) / ((t2 - t0) * (t2 - t1))
            factor = 2.0 / 11.0
            prediction = l0 * u0 + l1 * u1 + l2 * u2
        elif len(past) >= 2:
            (u1, u0), (t1, t0) = past[-2:], times[-2:]
            dt_prev = t0 - t1
            prediction = u0 + (u0 - u1) * dt / dt_prev
            factor = dt / (2 * dt + dt_prev)
        else:
            return None
        scale = max(self.state["u_scale"], _max_abs(u))
        if scale == 0.0:
            return 0.0
        return factor * _max_abs(u - prediction) / scale

    def _steady_measure(self, u: np.ndarray, dt: float) -> float:
        past = self.state["past"]
        scale = _max_abs(u)
        if not past or scale == 0.0:
            return math.inf
        return _max_abs(u - past[-1]) / scale * self.tau / dt

    def _accept(self, t_new: float, dt: float, outcome: WindowOutcome, u: np.ndarray) -> None:
        st = self.state
        keep = 3 if self.settings.scheme == "bdf2" else 2
        st["past"] = (st["past"] + [u])[-keep:]
        st["past_times"] = (st["past_times"] + [t_new])[-keep:]
        st["u_scale"] = max(st["u_scale"], _max_abs(u))
        st["t"] = t_new
        st["windows"] += 1
        st["rows"].append(self._row(t_new, outcome.iterations, outcome.residual))

    # -- frames ----------------------------------------------------------------------
    def _frame(self, force: bool = False) -> None:
        st = self.state
        if self.work_dir is None:
            return
        if not force and st["windows"] % self.settings.output_every != 0:
            return
        if st["frames"] and st["frames"][-1][1] == st["t"]:
            return
        index = len(st["frames"])
        write_frame(os.path.join(self.work_dir, FRAMES_DIR), index, self.backend.fields, self.comm)
        st["frames"].append([index, st["t"]])

    # -- the loop --------------------------------------------------------------------
    def _next_dt(self) -> float:
        st, plan = self.state, self.plan
        dt = st["dt_next"] if self.settings.adaptive else plan["dt"]
        if st["windows"] < len(self.start_steps):
            dt *= self.start_steps[st["windows"]]
        t = st["t"]
        if plan["t_end"] is not None and t + dt > plan["t_end"] * (1 - 1e-12):
            dt = plan["t_end"] - t
        if self.settings.adaptive:
            # land on the waveform's kinks and jumps
            breaks = self.waveform.breakpoints(t + 1e-9 * dt, t + dt)
            if breaks:
                dt = breaks[0] - t
        return dt

    @property
    def start_steps(self) -> tuple:
        """The first steps of this run from rest in units of dt: BDF2_START for fixed-step BDF2 (a periodic
        run keeps equal steps), else ()."""
        settings = self.settings
        graded = settings.scheme == "bdf2" and not settings.adaptive and not settings.until_periodic
        return BDF2_START if graded else ()

    def _done(self) -> bool:
        st, plan = self.state, self.plan
        if plan["t_end"] is not None and st["t"] >= plan["t_end"] * (1 - 1e-12):
            return True
        if self.periodic is not None:
            return self.periodic.done(st["rows"])
        return plan["until_steady"] and st["steady"]

    def _start(self) -> None:
        """The row, the history and the frame of t = 0 (a new run)."""
        st = self.state
        self.backend.update_fields()
        st["rows"].append(self._row(0.0, 0, 0.0))
        st["past"], st["past_times"] = [self._u()], [0.0]
        self._frame(force=True)
        self._save()

    def _rejected(self, t: float, dt: float, u: np.ndarray, snapshot) -> bool:
        """Adaptive dt: reject the window just solved (restored) if its error is too large, else set the next dt."""
        st, settings = self.state, self.settings
        err = self._error(u, dt)
        order = 2 if settings.scheme == "bdf2" else 1
        p = order if (order == 2 and len(st["past"]) >= 3) else 1
        if err is not None and err > settings.time_tol and dt > self.plan["dt_min"]:
            factor = max(0.2, 0.9 * (settings.time_tol / err) ** (1.0 / (p + 1)))
            st["dt_next"] = max(dt * factor, self.plan["dt_min"])
            st["rejected"] += 1
            self.backend.restore(snapshot)
            self.backend.update_fields()
            self.say(f"window {st['windows'] + 1:4d}  t = {t:.4e}  dt = {dt:.3e} rejected: error "
                     f"{err:.2e} > time_tol {settings.time_tol:.1e}")
            return True
        # dt changes in steps: it doubles when the error allows twice the step and is kept
        # otherwise, so that windows share one interface operator (quasi-Newton columns of
        # past windows stay valid) and one factorisation of each field's Jacobian
        factor = 2.0 if not err else 0.9 * (settings.time_tol / err) ** (1.0 / (p + 1))
        if dt >= st["dt_next"] * (1 - 1e-12):     # not a step shortened to land on t_end or a kink
            nominal = st["dt_next"]
            if factor >= 2.0:
                nominal *= 2.0
            elif factor < 1.0:
                nominal *= max(factor, 0.2)
            st["dt_next"] = min(nominal, self.plan["dt_max"])
        return False

    def run(self) -> dict:
        """Step until done; returns the state (rows, windows, ...)."""
        st, settings = self.state, self.settings
        started = time.perf_counter()
        if st["windows"] == 0 and not st["rows"]:
            self._start()
        while not self._done():
            if st["windows"] >= settings.max_windows:
                goal = "t_end" if self.plan["t_end"] is not None else (
                    "a periodic response" if self.periodic is not None else "steady state")
                raise ModelLimitError(f"time-dependent run: {settings.max_windows} windows (time.max_windows) "
                                      f"reached at t = {st['t']:.6g} before {goal}: raise max_windows in the "
                                      f"[time] table of a --config file, or give a larger --dt or a --t-end")
            dt, t = self._next_dt(), st["t"]
            snapshot = self.backend.snapshot() if settings.adaptive else None
            outcome = self.backend.window(t, dt)
            self.backend.update_fields()
            u = self._u()
            if settings.adaptive and self._rejected(t, dt, u, snapshot):
                continue
            steady = self._steady_measure(u, dt)
            self._accept(t + dt, dt, outcome, u)
            st["steady"] = bool(steady < settings.steady_tol and self._inflow_constant(st["t"]))
            self._frame()
            self._progress(dt, outcome, steady)
            st["wall_time"] += time.perf_counter() - started
            started = time.perf_counter()
            self._save()
        self._frame(force=True)
        st["wall_time"] += time.perf_counter() - started
        return st

    def _inflow_constant(self, t: float) -> bool:
        after = self.waveform.constant_after
        return after is not None and t >= after

    def _progress(self, dt: float, outcome: WindowOutcome, steady: float) -> None:
        st = self.state
        row = st["rows"][-1]
        seconds = self.params.to_si(st["t"], "time")
        if self.params.with_cell:
            where = f"centroid ({row['centroid_x']:.4e}, {row['centroid_y']:.3e})"
        else:
            where = f"max |u_s| {row['max_network_displacement']:.4e}"
        self.say(f"window {st['windows']:4d}  t = {st['t']:.4e} ({seconds:.3e} s)  dt = {dt:.3e}  "
                 f"iterations {outcome.iterations:3d}  {where}  change/tau {steady:.1e}")
        if self.periodic is not None and (len(st["rows"]) - 1) % self.periodic.steps == 0:
            k = self.periodic.cycles(st["rows"])
            change = self.periodic.change(st["rows"], k)
            self.say(f"cycle {k:3d} ends at t = {st['t']:.4e}: cycle-to-cycle change "
                     f"{'n/a (the first)' if change is None else f'{change:.2e}'} "
                     f"(periodic_tol {self.periodic.tol:.1e})")


