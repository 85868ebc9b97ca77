"""The periodic response of a run with a periodic inflow: when it repeats, and what one cycle holds.

A run with ``until_periodic`` steps N = ``steps_per_period`` equal windows
per period P of the inflow f(t), so the rows of its time series after the
row of t = 0 fall into cycles: cycle k (k = 1, 2, ...) is the N rows at
t_j = (k - 1) P + j dt, j = 1..N.  Samples with the same j are at the same
phase of the inflow.

Cycle-to-cycle change of cycle k >= 2, over the tracked groups G (the
centroid's components together; the cell's peak von Mises strain; its peak
von Mises stress; without a cell the gel's max |u_s|):

    change_k = max_G  max_{q in G, j} |q_k(t_j) - q_{k-1}(t_j)| / max_{q in G, j} |q_k(t_j)|

The components of the centroid share one scale, so a component that is zero
by symmetry (round-off only) does not stall the criterion.  The response is
periodic when change_k < ``periodic_tol``.  A start-up transient that decays
by a factor r per period leaves the cycle change_k r / (1 - r) from the
periodic limit, the ``estimated_distance`` reported with r = change_k /
change_{k-1}.

Per cycle: the minimum, mean and maximum over its N samples of the cell's
von Mises strain and stress (their maxima over the cell, the time series'
``cell_strain_max`` and ``cell_stress_max``; the mean of N equally spaced
samples of a periodic signal is its time average over the period by the
trapezoidal rule); the centroid's mean, its excursion max - min per
component and the diameter of its sampled path; and the phase lag of every
tracked quantity q behind the inflow, from the first Fourier harmonics

    Q = (2/N) sum_j q(t_j) exp(-i w t_j),   F = (2/N) sum_j f(t_j) exp(-i w t_j),   w = 2 pi / P,
    lag = -arg(Q / F) / w   in (-P/2, P/2],   amplitude |Q|,   gain |Q| / |F|.

A response that follows the inflow late has 0 < lag < P/2; one that moves
against it (a negative gain) has |lag| near P/2 (180 degrees).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PeriodicMonitor", "first_harmonic", "phase_lag", "cycle_change", "cycle_statistics"]


def first_harmonic(t: np.ndarray, q: np.ndarray, period: float) -> complex:
    """Q = (2/N) sum_j q(t_j) exp(-i 2 pi t_j / P) of N samples over one period."""
    return complex(2.0 / len(q) * np.sum(q * np.exp(-2j * np.pi * t / period)))


def phase_lag(t: np.ndarray, q: np.ndarray, f: np.ndarray, period: float) -> dict | None:
    """The lag of q behind f over one period, ``{time, degrees, amplitude, gain}`` (None if either has no
    first harmonic)."""
    Q, F = first_harmonic(t, q, period), first_harmonic(t, f, period)
    if abs(F) == 0.0 or abs(Q) == 0.0 or not np.isfinite(Q):
        return None
    angle = -float(np.angle(Q / F))               # in [-pi, pi)
    if angle <= -math.pi:
        angle += 2 * math.pi                      # a lag in (-P/2, P/2]
    return {"time": angle / (2 * math.pi) * period, "degrees": math.degrees(angle), "amplitude": abs(Q),
            "gain": abs(Q) / abs(F)}


def tracked_groups(columns, with_cell: bool) -> dict[str, tuple[str, ...]]:
    """The quantities the change criterion compares, in groups that share one scale."""
    if not with_cell:
        return {"network_displacement": ("max_network_displacement",)}
    centroid = tuple(c for c in ("centroid_x", "centroid_y", "centroid_z") if c in columns)
    return {"centroid": centroid, "cell_strain": ("cell_strain_max",), "cell_stress": ("cell_stress_max",)}


def cycle_change(previous: dict[str, np.ndarray], last: dict[str, np.ndarray],
                 groups: dict[str, tuple[str, ...]]) -> float:
    """max over the groups of max |q_k - q_{k-1}| / max |q_k| (module docstring); 0 for a response at rest."""
    change = 0.0
    for names in groups.values():
        scale = max(float(np.max(np.abs(last[q]))) for q in names)
        if scale > 0.0:
            change = max(change, max(float(np.max(np.abs(last[q] - previous[q]))) for q in names) / scale)
    return change


def _min_mean_max(q: np.ndarray) -> dict:
    return {"min": float(np.min(q)), "mean": float(np.mean(q)), "max": float(np.max(q))}


def _path_diameter(points: np.ndarray) -> float:
    """The largest distance between two of the points (rows)."""
    return float(np.max(np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)))


def cycle_statistics(samples: dict[str, np.ndarray], period: float, with_cell: bool) -> dict:
    """The statistics of one cycle's samples (``t``, ``inflow`` and the tracked columns), paper units."""
    t, f = samples["t"], samples["inflow"]
    groups = tracked_groups(samples, with_cell)
    out: dict = {"t_start": float(t[0] - (t[1] - t[0])), "t_end": float(t[-1])}
    if with_cell:
        out["cell_strain"] = _min_mean_max(samples["cell_strain_max"])
        out["cell_stress"] = _min_mean_max(samples["cell_stress_max"])
        axes = [c.rpartition("_")[2] for c in groups["centroid"]]
        centroid = np.column_stack([samples[c] for c in groups["centroid"]])
        out["centroid_mean"] = dict(zip(axes, map(float, centroid.mean(axis=0))))
        out["centroid_excursion"] = {**dict(zip(axes, map(float, np.ptp(centroid, axis=0)))),
                                     "path": _path_diameter(centroid)}
    else:
        out["network_displacement"] = _min_mean_max(samples["max_network_displacement"])
    out["phase_lag"] = {q: phase_lag(t, samples[q], f, period) for names in groups.values() for q in names}
    return out


def _headline(lags: dict, with_cell: bool) -> str:
    """The quantity whose lag the run reports first: the centroid's component that oscillates most."""
    if not with_cell:
        return "max_network_displacement"
    components = [q for q in lags if q.startswith("centroid_") and lags[q] is not None]
    return max(components, key=lambda q: lags[q]["amplitude"]) if components else "centroid_x"


class PeriodicMonitor:
    """Cycles of an until-periodic run's rows: the stop rule and the ``periodic`` block of summary.json.

    Args:
        period: the inflow's period P (paper units).
        steps: windows per period N.
        tol: ``periodic_tol``.
        max_cycles: the run ends after this many cycles, converged or not.
        with_cell: track the cell (else the gel's max |u_s|).
    """

    def __init__(self, period: float, steps: int, tol: float, max_cycles: int, with_cell: bool):
        self.period, self.steps, self.tol, self.max_cycles = period, steps, tol, max_cycles
        self.with_cell = with_cell

    def cycles(self, rows: list[dict]) -> int:
        """Complete cycles in rows (rows[0] is t = 0)."""
        return (len(rows) - 1) // self.steps

    def samples(self, rows: list[dict], k: int) -> dict[str, np.ndarray]:
        """The columns of cycle k (1-based) as arrays."""
        block = rows[(k - 1) * self.steps + 1: k * self.steps + 1]
        return {c: np.array([r[c] for r in block], dtype=float) for c in block[0]}

    def change(self, rows: list[dict], k: int) -> float | None:
        """change_k of the module docstring (None for the first cycle)."""
        if k < 2:
            return None
        last = self.samples(rows, k)
        return cycle_change(self.samples(rows, k - 1), last, tracked_groups(last, self.with_cell))

    def done(self, rows: list[dict]) -> bool:
        """At the end of a cycle: periodic (change below tol), or max_cycles reached."""
        k = self.cycles(rows)
        if k == 0 or (len(rows) - 1) % self.steps:
            return False
        return k >= self.max_cycles or (k >= 2 and self.change(rows, k) < self.tol)

    def summary(self, rows: list[dict], params) -> dict:
        """The ``periodic`` block of summary.json (docs/output.md): paper units, and the last cycle in SI."""
        count = self.cycles(rows)
        per_cycle = [{"cycle": k, "change": self.change(rows, k),
                      **cycle_statistics(self.samples(rows, k), self.period, self.with_cell)}
                     for k in range(1, count + 1)]
        changes = [c["change"] for c in per_cycle if c["change"] is not None]
        final = changes[-1] if changes else None
        out = {"period": self.period, "period_s": params.to_si(self.period, "time"),
               "steps_per_period": self.steps, "dt": self.period / self.steps, "tolerance": self.tol,
               "max_cycles": self.max_cycles, "cycles": count,
               "converged": final is not None and final < self.tol, "change": final,
               "estimated_distance": _distance(changes), "phase_lag": None, "per_cycle": per_cycle}
        if per_cycle:
            lags = per_cycle[-1]["phase_lag"]
            q = _headline(lags, self.with_cell)
            if lags.get(q) is not None:
                out["phase_lag"] = {"quantity": q, **lags[q], "time_s": params.to_si(lags[q]["time"], "time")}
            out["last_cycle_si"] = _si(per_cycle[-1], params)
        return out


def _distance(changes: list[float]) -> float | None:
    """change_k r / (1 - r), r = change_k / change_{k-1}: the geometric tail of a decaying start-up."""
    if len(changes) < 2 or changes[-2] == 0.0:
        return None
    r = changes[-1] / changes[-2]
    return changes[-1] * r / (1.0 - r) if r < 1.0 else None


def _si(cycle: dict, params) -> dict:
    """The last cycle's stress (mPa), centroid (µm) and lags (s) in reporting units."""
    out = {}
    if "cell_stress" in cycle:
        out["cell_stress_mPa"] = {k: params.to_report(v, "stress") for k, v in cycle["cell_stress"].items()}
        out["centroid_mean_um"] = {k: params.to_report(v, "length") for k, v in cycle["centroid_mean"].items()}
        out["centroid_excursion_um"] = {k: params.to_report(v, "length")
                                        for k, v in cycle["centroid_excursion"].items()}
    else:
        out["network_displacement_um"] = {k: params.to_report(v, "length")
                                          for k, v in cycle["network_displacement"].items()}
    out["phase_lag_s"] = {q: None if lag is None else params.to_si(lag["time"], "time")
                          for q, lag in cycle["phase_lag"].items()}
    return out
