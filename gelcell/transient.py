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
its factorisation (a dt that changed in every window cost 2.4x the
iterations per window and a refactorisation each; docs/transient.md).

Steady state: the relative change of the gel's displacement per consolidation
time, max|u^{n+1} - u^n| / max|u^{n+1}| * tau_c / dt, below ``steady_tol``.
"""

from __future__ import annotations

import math
import os
import time
import typing

import numpy as np

from mpi4py import MPI

import coupling as cp
from coupling.serialization import load_npz, save_npz
from femtools.serialize import CanonicalOrder, MixedCanonical
from femtools.timestepping import WindowClock
from femtools.transfer import NodalTransfer
from gelcell.device import Device
from gelcell.geometry import build_device
from gelcell.monolithic import MonolithicSolver
from gelcell.parameters import DEFAULT_GAMMA2, CaseParameters, ParameterError
from gelcell.results import DeviceFields, DeviceQuantities, fields_from_device
from gelcell.timesettings import TimeSettings

__all__ = ["TransientRun", "PartitionedBackend", "MonolithicBackend", "COLUMNS", "transient_summary"]

#: the columns of timeseries.csv / timeseries.h5
COLUMNS = ("t", "inflow") + DeviceQuantities.TIMESERIES + ("iterations", "residual")

_CHECKPOINT = "checkpoint.npz"
_FRAMES = "frames"


class WindowOutcome(typing.NamedTuple):
    iterations: int
    residual: float


# ----------------------------------------------------------------------------- backends
class PartitionedBackend:
    """The three coupled field solvers of a :class:`Device`, one coupling per window."""

    method = "partitioned"

    def __init__(self, device: Device, config: typing.Mapping, comm: MPI.Comm):
        self.device, self.comm = device, comm
        self.config = dict(config)
        self.scheme = cp.build_scheme(self.config, device.participants, device.data, comm=comm)
        self.fields = fields_from_device(device)

    def window(self, t: float, dt: float) -> WindowOutcome:
        if abs(self.scheme.time - t) > 1e-12 * max(abs(t), dt):
            raise RuntimeError(f"coupling time {self.scheme.time} differs from the run's time {t}")
        rec = self.scheme.advance_window(dt)
        last = rec.records[-1].measure_values if rec.records else {}
        residual = max(last.values()) if last else 0.0
        return WindowOutcome(rec.iterations, residual)

    def update_fields(self) -> None:
        gel, f = self.device.gel, self.fields
        gel.interstitial_velocity(out=f.interstitial_velocity)
        gel.displacement(out=f.displacement)
        gel.pore_pressure(out=f.pore_pressure)

    def snapshot(self):
        return self.scheme.snapshot()

    def restore(self, snapshot) -> None:
        self.scheme.restore(snapshot)

    def save(self, path: str, extra) -> None:
        self.scheme.save_checkpoint(path, extra=extra)

    def load(self, path: str):
        return self.scheme.load_checkpoint(path)

    def write_records(self, directory: str) -> None:
        self.scheme.write_records(directory)

    def describe(self) -> dict:
        acc = self.config["acceleration"]
        return {"scheme": self.config["scheme"], "acceleration": acc["type"],
                "time_windows_reused": acc.get("time_windows_reused"),
                "robin_coefficient": self.device.alpha_n, "gamma2": self.device.gamma2}


class MonolithicBackend:
    """The monolithic reference with the same time discretisation, one Newton solve per window."""

    method = "monolithic"

    def __init__(self, params: CaseParameters, comm: MPI.Comm, time_scheme: str, inflow):
        from gelcell.runner import monolithic_coefficients
        self.params, self.comm, self.inflow = params, comm, inflow
        self.mesh = build_device(params, comm, whole=True)
        msh, ct, ft = self.mesh.whole
        layout = self.mesh.layout
        self.solver = MonolithicSolver(msh, ct, ft, layout.boundaries, monolithic_coefficients(params), transient=True,
                                       cell_region_tags=layout.cell_region_tags or None)
        self.clock = WindowClock(time_scheme)
        self._transfers: dict = {}
        self.fields = self._region_fields()
        self.update_fields()

    def _region_fields(self) -> DeviceFields:
        from dolfinx import fem
        out = {}
        fluid = ("V", "P", "fluid_motion") if self.params.kinematics == "finite" else ("V", "P")
        regions = [("fluid", fluid), ("gel", ("v_f", "u", "p"))]
        if self.params.with_cell:
            regions.append(("cell", ("u",)))
        tags = {}
        for region, names in regions:
            msh, tags[region] = self.mesh.region(region)
            for name in names:
                src = self.solver.field(name)
                degree_space = (fem.FunctionSpace(msh, ("Lagrange", 1)) if name in ("P", "p")
                                else fem.VectorFunctionSpace(msh, ("Lagrange", 2)))
                key = f"{region}/{name}"
                out[key] = fem.Function(degree_space, name=name)
                self._transfers[key] = NodalTransfer(src.function_space, degree_space)
        return DeviceFields(params=self.params, fluid_velocity=out["fluid/V"], fluid_pressure=out["fluid/P"],
                            interstitial_velocity=out["gel/v_f"], displacement=out["gel/u"],
                            pore_pressure=out["gel/p"], cell_displacement=out.get("cell/u"),
                            fluid_tags=tags["fluid"], gel_tags=tags["gel"], cell_tags=tags.get("cell"),
                            fluid_mesh_displacement=out.get("fluid/fluid_motion"), layout=self.mesh.layout,
                            cell_regions=self.mesh.cell_tags)

    def update_fields(self) -> None:
        f = self.fields
        targets = {"fluid/V": f.fluid_velocity, "fluid/P": f.fluid_pressure, "gel/v_f": f.interstitial_velocity,
                   "gel/u": f.displacement, "gel/p": f.pore_pressure}
        if f.cell_displacement is not None:
            targets["cell/u"] = f.cell_displacement
        if f.fluid_mesh_displacement is not None:
            targets["fluid/fluid_motion"] = f.fluid_mesh_displacement
        cache = {}
        for key, dst in targets.items():
            name = key.split("/")[1]
            if name not in cache:
                cache[name] = self.solver.field(name)
            self._transfers[key].apply(cache[name], dst)

    def window(self, t: float, dt: float) -> WindowOutcome:
        scheme, dt_previous = self.clock.enter(t, dt, self.solver.push_history)
        self.solver.set_time_step(dt, scheme, dt_previous)
        self.solver.scale_boundary_velocity(self.inflow(t + dt))
        iterations = self.solver.solve()
        return WindowOutcome(iterations, self.solver.newton.history[-1] if self.solver.newton.history else 0.0)

    def snapshot(self):
        return {"state": self.solver.get_state(), "times": self.clock.state()}

    def restore(self, snapshot) -> None:
        self.solver.set_state(snapshot["state"])
        self.clock.load(snapshot["times"])

    def _canonical(self):
        if not hasattr(self, "_orders"):
            self._orders = (MixedCanonical(self.solver.W, self.solver.field_names),
                            CanonicalOrder(self.solver.history.past[0].function_space))
        return self._orders

    def save(self, path: str, extra) -> None:
        """Partition-independent arrays (``femtools.serialize``) and the run's own state (rank 0's)."""
        mixed, order_u = self._canonical()
        history = self.solver.history
        state = {"format": "gelcell-monolithic-checkpoint", "fields": mixed.gather(self.solver.w.x.array),
                 "past": [order_u.gather(f.x.array) for f in history.past], "length": history.length,
                 "times": self.clock.state(), "extra": extra}
        if self.comm.rank == 0:
            save_npz(f"{path}.tmp", state)
            os.replace(f"{path}.tmp", path)
        self.comm.Barrier()

    def load(self, path: str):
        state = load_npz(path)
        if state.get("format") != "gelcell-monolithic-checkpoint":
            raise ParameterError(f"{path}: not a checkpoint of a monolithic time-dependent run")
        mixed, order_u = self._canonical()
        mixed.scatter(state["fields"], self.solver.w.x.array)
        self.solver.history.load({"past_0": order_u.scatter(state["past"][0]),
                                  "past_1": order_u.scatter(state["past"][1]), "length": state["length"]})
        self.clock.load(state["times"])
        return state["extra"]

    def write_records(self, directory: str) -> None:
        pass

    def describe(self) -> dict:
        return {"newton": "exact Jacobian, kept while it contracts (refactorised when dt changes)"}


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
        self.state = {"t": 0.0, "windows": 0, "dt_next": self.plan["dt"], "rows": [], "frames": [],
                      "past": [], "past_times": [], "u_scale": 0.0, "rejected": 0, "wall_time": 0.0,
                      "steady": False}

    # -- checkpoint --------------------------------------------------------------
    @property
    def checkpoint_path(self) -> str | None:
        return None if self.work_dir is None else os.path.join(self.work_dir, _CHECKPOINT)

    def _save(self) -> None:
        if self.work_dir is not None:
            self.backend.save(self.checkpoint_path, self.state)

    def resume(self) -> None:
        """Continue from the checkpoint in ``work_dir`` (same case, settings and rank count)."""
        extra = self.backend.load(self.checkpoint_path)
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
        write_frame(os.path.join(self.work_dir, _FRAMES), index, self.backend.fields, self.comm)
        st["frames"].append([index, st["t"]])

    # -- the loop --------------------------------------------------------------------
    def _next_dt(self) -> float:
        st, plan = self.state, self.plan
        dt = st["dt_next"] if self.settings.adaptive else plan["dt"]
        t = st["t"]
        if plan["t_end"] is not None and t + dt > plan["t_end"] * (1 - 1e-12):
            dt = plan["t_end"] - t
        if self.settings.adaptive:
            # land on the waveform's kinks and jumps
            breaks = self.waveform.breakpoints(t + 1e-9 * dt, t + dt)
            if breaks:
                dt = breaks[0] - t
        return dt

    def _done(self) -> bool:
        st, plan = self.state, self.plan
        if plan["t_end"] is not None and st["t"] >= plan["t_end"] * (1 - 1e-12):
            return True
        return plan["until_steady"] and st["steady"]

    def run(self) -> dict:
        """Step until done; returns the state (rows, windows, ...)."""
        st, settings = self.state, self.settings
        started = time.perf_counter()
        if st["windows"] == 0 and not st["rows"]:
            self.backend.update_fields()
            st["rows"].append(self._row(0.0, 0, 0.0))
            st["past"], st["past_times"] = [self._u()], [0.0]
            self._frame(force=True)
            self._save()
        order = 2 if settings.scheme == "bdf2" else 1
        while not self._done():
            if st["windows"] >= settings.max_windows:
                raise RuntimeError(f"time-dependent run: {settings.max_windows} windows (time.max_windows) "
                                   f"reached at t = {st['t']:.6g} before "
                                   f"{'steady state' if self.plan['t_end'] is None else 't_end'}")
            dt = self._next_dt()
            t = st["t"]
            snapshot = self.backend.snapshot() if settings.adaptive else None
            outcome = self.backend.window(t, dt)
            self.backend.update_fields()
            u = self._u()
            if settings.adaptive:
                err = self._error(u, dt)
                p = order if (order == 2 and len(st["past"]) >= 3) else 1
                if err is not None and err > settings.time_tol and dt > self.plan["dt_min"]:
                    factor = max(0.2, 0.9 * (settings.time_tol / err) ** (1.0 / (p + 1)))
                    st["dt_next"] = max(dt * factor, self.plan["dt_min"])
                    st["rejected"] += 1
                    self.backend.restore(snapshot)
                    self.backend.update_fields()
                    self.say(f"window {st['windows'] + 1:4d}  t = {t:.4e}  dt = {dt:.3e} rejected: error "
                             f"{err:.2e} > time_tol {settings.time_tol:.1e}")
                    continue
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


# ----------------------------------------------------------------------------- frames
def _frame_functions(fields: DeviceFields) -> dict:
    out = {"fluid_velocity": fields.fluid_velocity, "fluid_pressure": fields.fluid_pressure,
           "interstitial_velocity": fields.interstitial_velocity, "displacement": fields.displacement,
           "pore_pressure": fields.pore_pressure}
    if fields.cell_displacement is not None:
        out["cell_displacement"] = fields.cell_displacement
    if fields.fluid_mesh_displacement is not None:
        out["fluid_mesh_displacement"] = fields.fluid_mesh_displacement
    return out


_ORDERS: dict = {}


def _order(f) -> CanonicalOrder:
    key = id(f.function_space)
    if key not in _ORDERS:
        _ORDERS[key] = (f.function_space, CanonicalOrder(f.function_space))
    return _ORDERS[key][1]


def write_frame(directory: str, index: int, fields: DeviceFields, comm: MPI.Comm) -> None:
    """Every field in the partition-independent order, ``frame_{index:05d}.npz`` (rank 0, written whole)."""
    arrays = {k: _order(f).gather(f.x.array) for k, f in _frame_functions(fields).items()}
    if comm.rank == 0:
        os.makedirs(directory, exist_ok=True)
        path = os.path.join(directory, f"frame_{index:05d}.npz")
        with open(path + ".tmp", "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(path + ".tmp", path)
    comm.Barrier()


def read_frame(directory: str, index: int, fields: DeviceFields, comm: MPI.Comm) -> None:
    """Load a frame written by :func:`write_frame` into ``fields`` (any partition)."""
    with np.load(os.path.join(directory, f"frame_{index:05d}.npz")) as data:
        for key, f in _frame_functions(fields).items():
            f.x.array[:] = _order(f).scatter(data[key])


# ----------------------------------------------------------------------------- summary
def _crossing(t: np.ndarray, x: np.ndarray, level: float) -> float | None:
    """First time the series x reaches ``level`` (linear interpolation; x rises from 0)."""
    above = np.nonzero(x >= level)[0]
    if above.size == 0:
        return None
    k = int(above[0])
    if k == 0:
        return float(t[0])
    return float(t[k - 1] + (level - x[k - 1]) * (t[k] - t[k - 1]) / (x[k] - x[k - 1]))


def transient_summary(state: dict, params: CaseParameters, settings: TimeSettings, plan: dict) -> dict:
    """The ``transient`` block of summary.json (see the README)."""
    rows = state["rows"]
    t = np.array([r["t"] for r in rows])
    key = "centroid_x" if params.with_cell else "max_network_displacement"
    x = np.array([r[key] for r in rows])
    iterations = [r["iterations"] for r in rows[1:]]
    out = {"quantity": key, "t50": None, "t90": None, "t99": None, "relaxation_time": None,
           "windows_to_t99": None}
    final = x[-1]
    constant = settings.waveform.constant_after
    if final != 0 and np.isfinite(final) and constant is not None:
        ratio = x / final
        for q in (50, 90, 99):
            out[f"t{q}"] = _crossing(t, ratio, q / 100)
        if out["t99"] is not None:
            out["windows_to_t99"] = int(np.searchsorted(t, out["t99"] * (1 - 1e-12)))
        fit = (ratio >= 0.5) & (ratio <= 0.99) & (t >= constant)
        if fit.sum() >= 3:
            slope = np.polyfit(t[fit], np.log(1 - ratio[fit]), 1)[0]
            out["relaxation_time"] = float(-1 / slope) if slope < 0 else None
    scales = plan["scales"]
    out.update({
        "t_end": float(t[-1]), "t_end_s": params.to_si(float(t[-1]), "time"),
        "steady": bool(state["steady"]), "windows": int(state["windows"]),
        "rejected_windows": int(state["rejected"]),
        "iterations_total": int(sum(iterations)),
        "iterations_mean": float(np.mean(iterations)) if iterations else 0.0,
        "iterations_mean_after_5": float(np.mean(iterations[5:])) if len(iterations) > 5 else None,
        "iterations_max": int(max(iterations)) if iterations else 0,
        "wall_time": float(state["wall_time"]),
        "time_unit_s": params.scale("time"),
        "time_scales": {"consolidation": scales["consolidation"], "kelvin_voigt": scales["kelvin_voigt"],
                        "drainage_length": scales["drainage_length"],
                        "consolidation_s": params.to_si(scales["consolidation"], "time"),
                        "kelvin_voigt_s": params.to_si(scales["kelvin_voigt"], "time")},
        "settings": {**settings.to_dict(), "dt_used": plan["dt"]},
    })
    for q in ("t50", "t90", "t99", "relaxation_time"):
        out[f"{q}_s"] = None if out[q] is None else params.to_si(out[q], "time")
    return out


# ----------------------------------------------------------------------------- a whole run
_RUN_FILE = "run.json"


def run_record(params: CaseParameters, settings: TimeSettings, method: dict) -> dict:
    """What identifies a run for ``--resume``: the case, the time settings and the method."""
    return {"format": "gelcell-transient-run", "case": params.to_input_dict(), "time": settings.to_dict(),
            "method": dict(method)}


def read_run_record(out: str) -> dict:
    """The run record of the interrupted run whose ``--out`` was ``out``; ParameterError if none."""
    import json
    partial = os.path.abspath(out) + ".partial"
    path = os.path.join(partial, _RUN_FILE)
    if not os.path.isfile(os.path.join(partial, _CHECKPOINT)) or not os.path.isfile(path):
        raise ParameterError(f"--resume {out}: nothing to resume, {partial}/ holds no checkpoint of an "
                             f"interrupted time-dependent run")
    try:
        with open(path) as fh:
            record = json.load(fh)
    except (OSError, ValueError) as exc:
        raise ParameterError(f"--resume {out}: cannot read {path} ({exc})") from None
    if not isinstance(record, dict) or record.get("format") != "gelcell-transient-run":
        raise ParameterError(f"--resume {out}: {path} is not the record of a time-dependent run")
    return record


def check_resume(record: dict, params: CaseParameters | None, settings: TimeSettings | None,
                 method: dict | None, out: str) -> None:
    """Raise ParameterError if the command line asks for another case, settings or method."""
    given = [("case", None if params is None else params.to_input_dict()),
             ("time settings", None if settings is None else settings.to_dict()),
             ("method", method)]
    stored = {"case": record["case"], "time settings": record["time"], "method": record["method"]}
    import json
    for what, value in given:
        if value is None:
            continue
        a = json.loads(json.dumps(value, default=str))
        b = stored[what]
        if a != b:
            keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k)) if isinstance(a, dict) else []
            raise ParameterError(f"--resume {out}: the checkpoint belongs to another run: its {what} "
                                 f"differ{'s' if what == 'method' else ''} from the command line's"
                                 f"{' (' + ', '.join(keys) + ')' if keys else ''}; resume with the "
                                 f"interrupted run's options, or only '--resume {out}'")


def _write_timeseries(directory: str, rows: list[dict], params: CaseParameters, comm: MPI.Comm) -> None:
    if comm.rank != 0:
        return
    import csv

    import h5py
    # several cells: each cell's columns after the common ones
    columns = COLUMNS + tuple(c for c in rows[-1] if c not in COLUMNS and c.startswith("cell_"))
    data = {c: np.array([r.get(c, np.nan) for r in rows], dtype=float) for c in columns}
    with open(os.path.join(directory, "timeseries.csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for k in range(len(rows)):
            w.writerow([f"{data[c][k]:.12e}" if c not in ("iterations",) else int(data[c][k]) for c in columns])
    with h5py.File(os.path.join(directory, "timeseries.h5"), "w") as h5:
        h5.attrs["units"] = ("paper's dimensionless units: t in L0/V0, lengths in L0, velocities in V0, "
                             "stresses in mu_s; strains dimensionless")
        h5.attrs["time_unit_s"] = params.scale("time")
        h5.attrs["case"] = params.case
        for c in columns:
            h5.create_dataset(c, data=data[c])


def _fmt(value) -> str:
    """A time for the progress line: 4 digits, or 'n/a' when undefined (e.g. no motion)."""
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.4e}"


def run_transient_case(params: CaseParameters, settings: TimeSettings, out: str | None, *,
                       monolithic: bool = False, scheme: str = "serial", acceleration: str = "iqn-ils",
                       coupling: typing.Mapping | None = None, comm: MPI.Comm = MPI.COMM_WORLD,
                       figures: bool = True, fields: bool = True, gamma2: str = DEFAULT_GAMMA2,
                       resume: bool = False, stream=None) -> dict:
    """Run a case in time from rest (or resume it) and write its outputs into ``out``.

    ``out``/``DIR.partial/`` holds the checkpoint while the run goes on; it
    becomes ``out`` when every file has been written (femtools.io).
    """
    import json
    import sys

    from femtools.io import atomic_directory
    from gelcell.output import DerivedFields, FieldSeries, write_json_file, write_profiles
    from gelcell.plots import FigureWorker, figure_data, figure_worker
    from gelcell.runner import collect_figures, format_summary, partitioned_config, report
    from gelcell.validity import model_warnings

    stream = stream or sys.stdout
    say = (lambda msg: print(msg, file=stream, flush=True)) if comm.rank == 0 else (lambda msg: None)
    method = {"monolithic": bool(monolithic), "scheme": scheme, "acceleration": acceleration,
              "gamma2": gamma2, "coupling": dict(coupling or params.coupling or {})}
    plan = settings.resolved(params)
    scales = plan["scales"]
    say(f"gelcell: {params.label}, {'with' if params.with_cell else 'without'} cell, time-dependent "
        f"({settings.scheme}, {'adaptive' if settings.adaptive else 'fixed'} dt), "
        f"{'monolithic' if monolithic else f'partitioned ({scheme}, {acceleration})'}, inflow {settings.inflow}")
    say(f"time scales: consolidation {scales['consolidation']:.3e} ({params.to_si(scales['consolidation'], 'time'):.3e} s), "
        f"Kelvin-Voigt {scales['kelvin_voigt']:.3e}; dt = {plan['dt']:.3e}, "
        f"until {'steady' if plan['t_end'] is None else ('t = %.4e' % plan['t_end'])}"
        f"{' or steady' if plan['t_end'] is not None and settings.until_steady else ''}")
    t0 = time.perf_counter()
    if monolithic:
        backend = MonolithicBackend(params, comm, settings.scheme, settings.waveform)
    else:
        overrides = dict(method["coupling"])
        config = partitioned_config(params, scheme, acceleration, overrides, transient=True)
        config["verbose"] = False
        device = Device(params, comm, gamma2=gamma2, transient=True, time_scheme=settings.scheme,
                        inflow=settings.waveform)
        backend = PartitionedBackend(device, config, comm)
    setup_time = time.perf_counter() - t0

    def solve_and_write(work_dir: str | None, worker: FigureWorker | None = None) -> dict:
        """Run and write into ``work_dir``; ``worker`` draws the device figures of a serial run."""
        run = TransientRun(backend, params, settings, comm, work_dir, say)
        if resume:
            run.resume()
            say(f"resumed from {run.checkpoint_path}: window {run.state['windows']}, t = {run.state['t']:.6e}")
        elif work_dir is not None and comm.rank == 0:
            with open(os.path.join(work_dir, _RUN_FILE), "w") as fh:
                json.dump(run_record(params, settings, method), fh, indent=2, default=str)
        state = run.run()
        raw = run.quantities.summary()
        raw["method"] = backend.method
        summary = report(raw, params)
        summary["coupling"] = backend.describe()
        summary["transient"] = transient_summary(state, params, settings, plan)
        if params.with_cell:
            # the model's limits over the whole run, not only at its end (e.g. the peaks of a pulsatile inflow)
            model = summary["model"]
            model["max_cell_strain"] = max(r["cell_strain_max"] for r in state["rows"])
            model["warnings"] = model_warnings(model)
        if comm.rank == 0:
            for warning in summary["model"]["warnings"]:
                print(f"gelcell: warning: {warning}", file=sys.stderr, flush=True)
        summary["timing"] = {"setup": setup_time, "time_stepping": state["wall_time"]}
        t = summary["transient"]
        say(format_summary(summary))
        say(f"time-dependent: {t['windows']} windows to t = {t['t_end']:.4e} ({t['t_end_s']:.3e} s), "
            f"{t['iterations_total']} iterations (mean {t['iterations_mean']:.2f}), "
            f"t50/t90/t99 = {_fmt(t['t50'])}/{_fmt(t['t90'])}/{_fmt(t['t99'])}, "
            f"relaxation time {_fmt(t['relaxation_time'])} (paper units)")
        if work_dir is None:
            return summary
        written = ["summary.json", "timeseries.csv", "timeseries.h5"]
        _write_timeseries(work_dir, state["rows"], params, comm)
        # the final state's profiles and figure data first: the worker draws while the frames are written
        profiles = write_profiles(work_dir, backend.fields, comm)
        data = figure_data(backend.fields, profiles, summary) if figures else None
        if worker is not None and data is not None:
            worker.submit(work_dir, data)
        if fields:
            derived = DerivedFields(backend.fields)
            series = FieldSeries(work_dir, derived)
            for index, t_frame in state["frames"]:
                read_frame(os.path.join(work_dir, _FRAMES), int(index), backend.fields, comm)
                derived.update()
                series.write(float(t_frame))
            written += series.names
        written += [f"{k.lower()}_profiles.{ext}" for k in profiles for ext in ("h5", "csv")]
        backend.write_records(os.path.join(work_dir, "coupling"))
        if not monolithic:
            written.append("coupling/")
        if figures:
            from gelcell.figures import draw_transient_figures
            if data is not None:
                written += collect_figures(work_dir, data, worker)
            written += draw_transient_figures(work_dir, state["rows"], summary, params, comm)
        summary["files"] = written
        write_json_file(os.path.join(work_dir, "summary.json"), summary, comm)
        if comm.rank == 0:
            import shutil
            os.remove(os.path.join(work_dir, _CHECKPOINT))
            shutil.rmtree(os.path.join(work_dir, _FRAMES), ignore_errors=True)
        comm.Barrier()
        return summary

    if out is None:
        return solve_and_write(None)
    # a serial run's device figures are drawn by a second process, which imports matplotlib meanwhile
    with figure_worker(figures, comm) as worker:
        with atomic_directory(out, comm, partial=True) as work_dir:
            try:
                summary = solve_and_write(work_dir, worker)
            finally:
                if worker is not None:
                    worker.close()          # before the directory is promoted or left as DIR.partial
    say(f"wrote {os.path.abspath(out)}: " + ", ".join(summary["files"]))
    return summary
