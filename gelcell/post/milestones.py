"""The milestones of a time-dependent run: when the response reaches 50, 90 and 99 % of its final value.

The ``transient`` block of summary.json: t50, t90, t99, the relaxation time
of the exponential approach to the steady state, and the run's bookkeeping
(windows, iterations, time scales, settings).
"""

from __future__ import annotations

import numpy as np

from gelcell.case import CaseParameters, TimeSettings

__all__ = ["transient_summary"]


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
    """The ``transient`` block of summary.json (docs/output.md)."""
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
