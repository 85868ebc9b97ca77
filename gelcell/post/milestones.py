"""The milestones of a time-dependent run: when the response reaches 50, 90 and 99 % of its final value.

The ``transient`` block of summary.json: t50, t90, t99, the relaxation time
of the exponential approach to the steady state, and the run's bookkeeping
(windows, iterations, time scales, settings).  The ``time`` block: the scheme,
the step control and the milestones' estimated time-discretisation error
(:func:`global_errors`; derived and measured in docs/transient.md, "Accuracy of
the milestones").
"""

from __future__ import annotations

import numpy as np

from gelcell.case import CaseParameters, TimeSettings

__all__ = ["transient_summary", "time_summary", "estimated_errors", "global_errors"]

#: the schemes in words (summary.json's time block)
SCHEMES = {"be": "backward Euler", "bdf2": "BDF2 (variable step)"}


# ----------------------------------------------------------------------------- summary
def _crossing(t: np.ndarray, x: np.ndarray, level: float) -> float | None:
    """First time the series x reaches ``level`` (x rises from 0).

    The crossing in [t_{k-1}, t_k] is the root of the quadratic through three samples
    (k-1, k and k+1, or k-2 when k is the last): its error is O(dt^3), below the O(dt^2)
    of BDF2, where linear interpolation (error (dt^2/8) |x''/x'|) would cap the order.
    """
    above = np.nonzero(x >= level)[0]
    if above.size == 0:
        return None
    k = int(above[0])
    if k == 0:
        return float(t[0])
    linear = float(t[k - 1] + (level - x[k - 1]) * (t[k] - t[k - 1]) / (x[k] - x[k - 1]))
    if len(t) < 3:
        return linear
    j = k - 1 if k + 1 < len(t) else k - 2          # >= 0: k >= 1, and k = len - 1 >= 2 in the else
    return _quadratic_root(t[j:j + 3], x[j:j + 3] - level, t[k - 1], t[k], linear)


def _quadratic_root(t: np.ndarray, y: np.ndarray, lo: float, hi: float, fallback: float) -> float:
    """The root in [lo, hi] of the quadratic through (t_i, y_i), i = 0..2 (``fallback`` if none)."""
    scale = hi - lo
    s = (t - lo) / scale
    roots = np.roots(np.polyfit(s, y, 2))
    inside = [r.real for r in roots if abs(r.imag) < 1e-12 and -1e-9 <= r.real <= 1 + 1e-9]
    if len(inside) != 1:
        return fallback
    return float(lo + min(max(inside[0], 0.0), 1.0) * scale)


#: (q, C): the scheme's order and error constant; a step of size h turns a mode e^(lambda t) into
#: one with lambda (1 + C (lambda h)^q), to leading order
ERROR_CONSTANTS = {"be": (1, 0.5), "bdf2": (2, 1.0 / 3.0)}


def _derivatives(t: np.ndarray, x: np.ndarray, count: int) -> list[np.ndarray]:
    """x', x'', ... (``count`` of them) of a sampled series (second-order finite differences)."""
    out = [np.gradient(x, t, edge_order=2)]
    for _ in range(count - 1):
        out.append(np.gradient(out[-1], t, edge_order=2))
    return out


def global_errors(t: np.ndarray, x: np.ndarray, scheme: str) -> tuple[np.ndarray, np.ndarray]:
    """The estimated global error e_n = x_n - x(t_n) of a series stepped from rest, and x'.

    For a linear problem with a constant load after t = 0 the response is a sum of modes
    c_i e^(lambda_i t); the scheme replaces each lambda_i by lambda_i (1 + C (lambda_i h)^q),
    so every mode, and hence x, is off by C x^(q+1)(t) sum_k h_k^(q+1):

        e(t) = C x^(q+1)(t) sum_{t_k <= t} h_k^(q+1)   (+ (3/4) h_1^2 x''(t) for BDF2's
                                                        backward Euler start)

    (backward Euler q = 1, C = 1/2; BDF2 q = 2, C = 1/3), with the derivatives of the computed
    series (finite differences). Unresolved fast modes (|lambda h| > 1) are left out: they
    have decayed a few steps after the start.
    """
    order, constant = ERROR_CONSTANTS[scheme]
    if len(t) < 5:
        return np.zeros_like(x), np.gradient(x, t) if len(t) > 1 else np.zeros_like(x)
    d = _derivatives(t, x, order + 1)
    h = np.diff(t, prepend=t[0])
    error = constant * d[order] * np.cumsum(h**(order + 1))
    if scheme == "bdf2":
        # the start's error (h_1^2/2) x'' splits into the roots 1 and 1/3 of BDF2: 3/2 of it stays
        error += 0.75 * h[1]**2 * d[1]
    return error, d[0]


def estimated_errors(t: np.ndarray, ratio: np.ndarray, scheme: str, milestones: dict) -> dict:
    """Relative time-discretisation error of each milestone t_q: -e(t_q) / (x'(t_q) t_q) (> 0: late)."""
    error, slope = global_errors(t, ratio, scheme)
    out = {}
    for q, tq in milestones.items():
        s = None if tq is None or tq <= 0 else float(np.interp(tq, t, slope))
        out[q] = None if not s or s <= 0 else float(-np.interp(tq, t, error) / (s * tq))
    return out


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


def time_summary(state: dict, params: CaseParameters, settings: TimeSettings, plan: dict,
                 transient: dict, start: tuple = ()) -> dict:
    """The ``time`` block of summary.json: scheme, step control, the milestones' estimated errors.

    ``start``: the first steps of a run from rest in units of dt (BDF2's graded start), else ().

    ``estimated_error`` holds S_q = -e(t_q) / (x'(t_q) t_q) of each milestone
    (:func:`estimated_errors`, > 0: late) and their largest magnitude; None where the
    estimate does not apply (no milestones, or a load that is not a step).
    """
    control = ({"kind": "adaptive", "time_tol": settings.time_tol, "first_dt": plan["dt"]} if settings.adaptive
               else {"kind": "fixed", "dt": plan["dt"], "dt_over_tau_c": plan["dt"] / plan["scales"]["consolidation"],
                     "start": list(start)})
    out = {"scheme": settings.scheme, "scheme_words": SCHEMES[settings.scheme], "step_control": control,
           "estimated_error": None}
    found = {q: transient[q] for q in ("t50", "t90", "t99")}
    if settings.waveform.kind != "step" or any(v is None for v in found.values()):
        return out
    rows = state["rows"]
    t = np.array([r["t"] for r in rows])
    x = np.array([r[transient["quantity"]] for r in rows])
    errors = estimated_errors(t, x / x[-1], settings.scheme, found)
    if any(v is None for v in errors.values()):
        return out
    out["estimated_error"] = {**errors, "max": max(abs(v) for v in errors.values())}
    return out
