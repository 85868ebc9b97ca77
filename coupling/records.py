"""Records of coupling runs: per-iteration and per-window logs, results, recordings.

Files written by :func:`write_records` (rank 0 only):

* ``coupling-iterations.csv`` / ``.json``: one row per time window (window,
  time, dt, iterations, converged, reason, quasi-Newton columns, solve time
  per participant);
* ``coupling-convergence.csv`` / ``.json``: one row per coupling iteration
  (window, iteration, per data the convergence measure and the residual
  norm, relaxation, quasi-Newton columns used / filtered / dropped, solve time
  per participant).
"""

from __future__ import annotations

import csv
import json
import math
import os
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np

from coupling.convergence import MeasureValue
from coupling.serialization import load_npz, save_npz, to_jsonable

__all__ = ["IterationRecord", "WindowRecord", "CouplingResult", "RecordedSolve", "Recording",
           "write_records", "format_progress"]


@dataclass
class IterationRecord:
    """Everything measured in one coupling iteration.

    Attributes:
        window: Window index (0-based, counted since the scheme was created
            or restored).
        iteration: Iteration within the window (1-based).
        time: Window start time (``None`` for steady solves).
        dt: Window length (``None`` for steady solves).
        residual_norms: Data name -> ``‖r‖``.
        value_norms: Data name -> ``‖x̃‖``.
        measure_values: Data name -> the convergence measure (the first one
            configured for the data; the relative residual if none is).
        measures: All measure evaluations.
        relaxation: Relaxation factor applied after this iteration (``None``
            for a quasi-Newton step or when the iteration converged).
        columns_used: Quasi-Newton columns in the least-squares system.
        columns_filtered: Columns deleted by the filter (or zero) in this iteration.
        columns_dropped: Columns dropped (``max_used_iterations``) in this iteration.
        solve_time: Participant -> wall time of its solve in this iteration [s].
        converged: Whether the convergence test passed in this iteration.
    """

    window: int
    iteration: int
    time: float | None
    dt: float | None
    residual_norms: dict[str, float]
    value_norms: dict[str, float]
    measure_values: dict[str, float]
    measures: list[MeasureValue]
    relaxation: float | None = None
    columns_used: int = 0
    columns_filtered: int = 0
    columns_dropped: int = 0
    solve_time: dict[str, float] = field(default_factory=dict)
    converged: bool = False

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "IterationRecord":
        """The record whose :func:`dataclasses.asdict` is ``d`` (as a checkpoint holds it)."""
        return cls(**{**d, "measures": [MeasureValue(**m) for m in d["measures"]]})

    def as_dict(self) -> dict[str, Any]:
        """JSON-compatible dictionary."""
        d = asdict(self)
        d["measures"] = [asdict(m) for m in self.measures]
        return to_jsonable(d)


@dataclass
class WindowRecord:
    """Summary of one time window (or of one steady solve).

    Attributes:
        window: Window index.
        time: Start time (``None`` for steady solves).
        dt: Window length (``None`` for steady solves).
        iterations: Number of coupling iterations.
        converged: Whether the convergence measures were met.
        reason: ``"converged"``, ``"explicit"``, ``"max_iterations"`` or ``"diverged: ..."``.
        records: The iteration records.
        columns_kept: Quasi-Newton columns kept at the end of the window.
        columns_dropped_at_end: Columns dropped when the window closed
            (older than ``time_windows_reused``).
    """

    window: int
    time: float | None
    dt: float | None
    iterations: int = 0
    converged: bool = False
    reason: str = ""
    records: list[IterationRecord] = field(default_factory=list)
    columns_kept: int = 0
    columns_dropped_at_end: int = 0

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "WindowRecord":
        """The record whose :func:`dataclasses.asdict` is ``d`` (as a checkpoint holds it)."""
        return cls(**{**d, "records": [IterationRecord.from_dict(r) for r in d["records"]]})

    @property
    def solve_time(self) -> dict[str, float]:
        """Participant -> total solve time in this window [s]."""
        total: dict[str, float] = {}
        for rec in self.records:
            for name, t in rec.solve_time.items():
                total[name] = total.get(name, 0.0) + t
        return total

    def as_dict(self, with_iterations: bool = False) -> dict[str, Any]:
        """JSON-compatible dictionary (optionally with the iteration records)."""
        d = {"window": self.window, "time": self.time, "dt": self.dt, "iterations": self.iterations,
             "converged": self.converged, "reason": self.reason,
             "columns_used_last": self.records[-1].columns_used if self.records else 0,
             "columns_filtered": sum(r.columns_filtered for r in self.records),
             "columns_dropped": sum(r.columns_dropped for r in self.records) + self.columns_dropped_at_end,
             "columns_kept": self.columns_kept, "solve_time": self.solve_time}
        if with_iterations:
            d["records"] = [r.as_dict() for r in self.records]
        return to_jsonable(d)


@dataclass
class CouplingResult:
    """Outcome and records of :meth:`CouplingScheme.solve` or :meth:`CouplingScheme.run`.

    Attributes:
        converged: True if every window converged.
        iterations: Total number of coupling iterations.
        iterations_per_window: Iterations of each window.
        residual_history: Data name -> the convergence measure per iteration
            (all windows concatenated).
        relaxation: Relaxation factor per iteration (``None``: quasi-Newton
            step or last iteration).
        reason: Why the run stopped (``"converged"``, ``"explicit"``,
            ``"max_iterations"`` or ``"diverged: ..."``).
        timing: Participant -> total solve time [s].
        windows: The window records.
    """

    converged: bool
    iterations: int
    iterations_per_window: list[int]
    residual_history: dict[str, list[float]]
    relaxation: list[float | None]
    reason: str
    timing: dict[str, float]
    windows: list[WindowRecord]

    @classmethod
    def from_windows(cls, windows: Sequence[WindowRecord], data_names: Sequence[str],
                     reason: str | None = None) -> "CouplingResult":
        """Assemble a result from window records."""
        history: dict[str, list[float]] = {d: [] for d in data_names}
        relaxation: list[float | None] = []
        timing: dict[str, float] = {}
        for w in windows:
            for rec in w.records:
                for d in data_names:
                    history[d].append(rec.measure_values.get(d, math.nan))
                relaxation.append(rec.relaxation)
            for name, t in w.solve_time.items():
                timing[name] = timing.get(name, 0.0) + t
        converged = bool(windows) and all(w.converged for w in windows)
        if reason is None:
            reason = windows[-1].reason if windows else "no window run"
            if not converged:
                failed = [w for w in windows if not w.converged]
                reason = failed[0].reason if failed else reason
        per_window = [w.iterations for w in windows]
        return cls(converged=converged, iterations=int(sum(per_window)),
                   iterations_per_window=per_window, residual_history=history,
                   relaxation=relaxation, reason=reason, timing=timing, windows=list(windows))

    def summary(self) -> str:
        """A short human-readable summary."""
        n = len(self.windows)
        lines = []
        status = "converged" if self.converged else "NOT converged"
        if n > 1:
            per = self.iterations_per_window
            lines.append(f"coupling {status}: {n} windows, {self.iterations} iterations "
                         f"(mean {np.mean(per):.2f}, max {max(per)} per window)")
        else:
            lines.append(f"coupling {status} in {self.iterations} iterations")
        lines.append(f"reason: {self.reason}")
        if self.windows and self.windows[-1].records:
            last = self.windows[-1].records[-1]
            parts = [f"{m.data} {m.kind} {m.value:.2e} (limit {m.limit:.0e})" for m in last.measures]
            if parts:
                lines.append("final measures: " + ", ".join(parts))
        if self.timing:
            lines.append("solve time: " + ", ".join(f"{k} {v:.3g} s" for k, v in self.timing.items()))
        return "\n".join(lines)


def format_progress(rec: IterationRecord, transient: bool) -> str:
    """One progress line, e.g. ``it   3  Gamma1/traction 2.1e-04  omega 0.41``."""
    head = f"win {rec.window:4d} t={rec.time:.4g}  " if transient and rec.time is not None else ""
    parts = [f"{head}it {rec.iteration:3d}"]
    for name, value in rec.measure_values.items():
        parts.append(f"{name} {value:.1e}")
    if rec.converged:
        parts.append("converged")
    elif rec.relaxation is not None:
        parts.append(f"omega {rec.relaxation:.3g}")
    else:
        parts.append(f"qn {rec.columns_used} cols")
    return "  ".join(parts)


def _csv_value(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    return v


def write_records(directory: str | os.PathLike, windows: Sequence[WindowRecord],
                  data_names: Sequence[str], participant_names: Sequence[str]) -> dict[str, str]:
    """Write the iterations log (per window) and convergence log (per iteration).

    Args:
        directory: Output directory (created if needed).
        windows: Window records.
        data_names: Data names (CSV columns).
        participant_names: Participant names (CSV columns).

    Returns:
        Mapping of log name to written path.
    """
    os.makedirs(directory, exist_ok=True)
    paths = {
        "iterations_csv": os.path.join(directory, "coupling-iterations.csv"),
        "iterations_json": os.path.join(directory, "coupling-iterations.json"),
        "convergence_csv": os.path.join(directory, "coupling-convergence.csv"),
        "convergence_json": os.path.join(directory, "coupling-convergence.json"),
    }
    window_rows = [w.as_dict() for w in windows]
    _write_json(paths["iterations_json"], window_rows)
    _write_iterations_csv(paths["iterations_csv"], window_rows, participant_names)
    iteration_rows = [r.as_dict() for w in windows for r in w.records]
    _write_json(paths["convergence_json"], iteration_rows)
    _write_convergence_csv(paths["convergence_csv"], iteration_rows, data_names, participant_names)
    return paths


def _write_json(path: str, rows: Any) -> None:
    """Strict JSON (non-finite numbers as ``null``), through :func:`coupling.serialization.to_jsonable`."""
    with open(path, "w") as fh:
        json.dump(to_jsonable(rows), fh, indent=1, allow_nan=False)


def _write_iterations_csv(path: str, window_rows: list[dict[str, Any]],
                          participant_names: Sequence[str]) -> None:
    header = ["window", "time", "dt", "iterations", "converged", "reason", "columns_used_last",
              "columns_filtered", "columns_dropped", "columns_kept"]
    header += [f"solve_time[{p}]" for p in participant_names]
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        for row in window_rows:
            writer.writerow([_csv_value(row[k]) for k in header[:10]]
                            + [_csv_value(row["solve_time"].get(p, 0.0)) for p in participant_names])


def _write_convergence_csv(path: str, iteration_rows: list[dict[str, Any]], data_names: Sequence[str],
                           participant_names: Sequence[str]) -> None:
    header = ["window", "iteration", "time", "dt"]
    header += [f"measure[{d}]" for d in data_names] + [f"residual_norm[{d}]" for d in data_names]
    header += ["relaxation", "columns_used", "columns_filtered", "columns_dropped", "converged"]
    header += [f"solve_time[{p}]" for p in participant_names]
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        for row in iteration_rows:
            values = [row["window"], row["iteration"], row["time"], row["dt"]]
            values += [row["measure_values"].get(d) for d in data_names]
            values += [row["residual_norms"].get(d) for d in data_names]
            values += [row["relaxation"], row["columns_used"], row["columns_filtered"],
                       row["columns_dropped"], row["converged"]]
            values += [row["solve_time"].get(p, 0.0) for p in participant_names]
            writer.writerow([_csv_value(v) for v in values])


# --------------------------------------------------------------------------- data recording
@dataclass
class RecordedSolve:
    """Inputs and outputs of one participant solve.

    Attributes:
        window: Window index.
        iteration: Iteration within the window (1-based).
        participant: Participant name.
        time: Window start time (``None`` for steady solves).
        dt: Window length (``None`` for steady solves).
        inputs: Data name -> mapped input array.
        outputs: Data name -> output array.
    """

    window: int
    iteration: int
    participant: str
    time: float | None
    dt: float | None
    inputs: dict[str, np.ndarray]
    outputs: dict[str, np.ndarray]


class Recording:
    """Interface data of every participant solve (``record_data = true``).

    ``checkpoints`` holds, per ``(window, participant)``, the state returned
    by ``save_state`` at the window start (kept in memory only; not saved).
    """

    def __init__(self) -> None:
        self.solves: list[RecordedSolve] = []
        self.checkpoints: dict[tuple[int, str], Any] = {}

    def add(self, solve: RecordedSolve) -> None:
        """Append one solve (arrays are copied)."""
        solve.inputs = {k: np.array(v, dtype=float) for k, v in solve.inputs.items()}
        solve.outputs = {k: np.array(v, dtype=float) for k, v in solve.outputs.items()}
        self.solves.append(solve)

    def find(self, participant: str, iteration: int, window: int | None = None) -> RecordedSolve:
        """The recorded solve of ``participant`` in ``iteration`` of ``window`` (default: last window)."""
        matches = [s for s in self.solves if s.participant == participant and s.iteration == iteration
                   and (window is None or s.window == window)]
        if not matches:
            have = sorted({(s.window, s.iteration) for s in self.solves if s.participant == participant})
            raise KeyError(f"no recorded solve of {participant!r} at iteration {iteration}"
                           f"{'' if window is None else f' of window {window}'}; recorded "
                           f"(window, iteration): {have[:20]}{' ...' if len(have) > 20 else ''}")
        return matches[-1]

    def save(self, path: str | os.PathLike) -> None:
        """Save the recorded solves (not the checkpoints) to an ``.npz`` file."""
        save_npz(path, {"format": "coupling-recording", "solves": [
            {"window": s.window, "iteration": s.iteration, "participant": s.participant,
             "time": s.time, "dt": s.dt, "inputs": s.inputs, "outputs": s.outputs}
            for s in self.solves]})

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Recording":
        """Load a recording written by :meth:`save`."""
        obj = load_npz(path)
        if not isinstance(obj, dict) or "format" not in obj or obj["format"] != "coupling-recording":
            raise ValueError(f"{path}: not a coupling recording")
        rec = cls()
        for s in obj["solves"]:
            rec.add(RecordedSolve(**s))
        return rec
