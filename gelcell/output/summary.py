"""The layout of summary.json and the short table a run prints.

Every quantity appears as a top-level dotted key (``gel.max_interstitial_speed``,
``cell.centroid_displacement``, ...) in the paper's dimensionless units, and in
the ``si`` block in µm/s, µm and mPa.
"""

from __future__ import annotations

import typing

from gelcell.case import CaseParameters
from gelcell.post.validity import model_warnings

__all__ = ["report", "format_summary"]


_ROWS = [
    ("max |v_f| in the gel", ("gel", "max_interstitial_speed"), "velocity"),
    ("max |u_s| in the gel", ("gel", "max_network_displacement"), "length"),
    ("max von Mises of sigma_s", ("gel", "max_network_von_mises"), "stress"),
    ("volume change below Gamma1", ("gel", "volume_change_below_gamma1"), "measure"),
    ("  share due to the cell", ("gel", "volume_change_share_of_cell"), None),
    ("cell centroid displacement x", ("cell", "centroid_displacement", 0), "length"),
    ("cell centroid displacement y", ("cell", "centroid_displacement", 1), "length"),
    ("cell centroid displacement z", ("cell", "centroid_displacement", 2), "length"),       # 3D
    ("max |u_c| in the cell", ("cell", "max_displacement"), "length"),
    ("cell von Mises strain min", ("cell", "von_mises_strain", 0), None),
    ("cell von Mises strain max", ("cell", "von_mises_strain", 1), None),
    ("cell von Mises stress min", ("cell", "von_mises_stress", 0), "stress"),
    ("cell von Mises stress max", ("cell", "von_mises_stress", 1), "stress"),
    ("traction near cell: pressure", ("cell", "max_traction_von_mises", "pressure"), "stress"),
    ("traction near cell: Brinkman", ("cell", "max_traction_von_mises", "brinkman"), "stress"),
    ("traction near cell: network", ("cell", "max_traction_von_mises", "network"), "stress"),
    ("traction near cell: total", ("cell", "max_traction_von_mises", "total"), "stress"),
]


_UNITS = {"velocity": "µm/s", "length": "µm", "stress": "mPa", None: "-"}
#: the unit of a volume change: an area in 2D, a volume in 3D
_MEASURE_UNITS = {2: "µm²", 3: "µm³"}


def _get(d, path):
    for k in path:
        if d is None or (isinstance(k, int) and k >= len(d)):
            return None
        d = d[k]
    return d


def _flat(block: dict | None, prefix: str, names: typing.Iterable[str]) -> dict:
    return {f"{prefix}.{k}": (None if block is None else block[k]) for k in names}


_GEL_KEYS = ("max_interstitial_speed", "max_network_displacement", "max_network_von_mises",
             "max_network_von_mises_location", "volume_change_below_gamma1", "local_volume_change_magnitude",
             "relative_volume_change_below_gamma1", "volume_change_share_of_cell")


_CELL_KEYS = ("centroid_displacement", "max_displacement", "von_mises_strain", "von_mises_stress",
              "max_traction_von_mises")


def report(summary: dict, params: CaseParameters) -> dict:
    """The layout of summary.json: ``case``, ``cell`` (bool), quantities as dotted keys.

    Every quantity appears as a top-level dotted key (``gel.max_interstitial_speed``,
    ``cell.centroid_displacement``, ... ; ``null`` for cell quantities without a
    cell), in the paper's dimensionless units; the ``si`` block repeats them in
    µm/s, µm and mPa.  ``gel_quantities``/``cell_quantities`` hold the same
    values nested.
    """
    gel, cell = summary.pop("gel"), summary.pop("cell")
    si = summary.pop("si")
    out = {"case": params.case, "cell": bool(params.with_cell), "method": summary.pop("method")}
    out.update(_flat(gel, "gel", _GEL_KEYS))
    out.update(_flat(cell, "cell", _CELL_KEYS))
    out["si"] = {"units": si["units"], **_flat(si["gel"], "gel", _GEL_KEYS), **_flat(si["cell"], "cell", _CELL_KEYS)}
    if "cells" in si:
        out["si"]["cells"] = si["cells"]
    out["parameters"] = params.to_dict()
    out["cell_moduli_note"] = (f"cell moduli mu_c = {params.cell.mu_c:g} Pa, lambda_c = {params.cell.lambda_c:g} Pa "
                               f"= {params.cell_moduli_multiple:g} x the gel's drained modulus phi_s0 mu_s")
    out.update(summary)
    out["gel_quantities"], out["cell_quantities"] = gel, cell
    model = out["model"] = dict(out.get("model") or {})
    model["max_cell_strain"] = None if cell is None else cell["von_mises_strain"][1]
    model["warnings"] = model_warnings(model)
    return out


def format_summary(summary: dict) -> str:
    """A short table: quantity, paper's dimensionless value, SI value."""
    lines = [f"{'quantity':32s} {'dimensionless':>14s} {'SI':>14s}  unit", "-" * 70]
    units = {**_UNITS, "measure": _MEASURE_UNITS[(summary.get("geometry") or {}).get("dimension", 2)]}
    for label, path, kind in _ROWS:
        key, rest = f"{path[0]}.{path[1]}", path[2:]
        v = _get(summary.get(key), rest) if key in summary else None
        if v is None:
            continue
        si = _get(summary["si"][key], rest)
        lines.append(f"{label:32s} {v:14.6e} {si:14.6e}  {units[kind]}")
    cells = summary.get("cells") or []
    if len(cells) > 1:
        lines.append("per cell (dimensionless): centroid displacement x, y; von Mises strain max; stress max")
        for cl in cells:
            lines.append(f"  {cl['name']:8s} at ({cl['centre'][0]:.4g}, {cl['centre'][1]:.4g}) "
                         f"{cl['centroid_displacement'][0]:12.4e} {cl['centroid_displacement'][1]:12.4e} "
                         f"{cl['von_mises_strain'][1]:12.4e} {cl['von_mises_stress'][1]:12.4e}")
    c = summary.get("coupling")
    if c and "iterations" in c:
        prior = (f" (linearized prior: {c['prior_source']})" if c.get("jacobian_prior") == "linearized"
                 and c.get("prior_source") else f" (secant model alone: {c['prior_reason']})"
                 if c.get("prior_reason") else "")
        lines.append(f"coupling: {c['scheme']} / {c['acceleration']}{prior}, {c['iterations']} iterations, "
                     f"converged={c['converged']}")
    solver = summary.get("solver")
    if solver:
        lines.append(f"linear solvers: {solver['kind']} -> "
                     + ", ".join(f"{field} {kind}" for field, kind in solver["fields"].items()))
        if solver.get("krylov"):
            lines.append("Krylov iterations per solve: " + ", ".join(
                f"{field} {k['mean']:.1f} ({k['solves']} solves)" for field, k in solver["krylov"].items()))
    if summary.get("cost"):
        lines.append(_cost_line(summary["cost"]))
    t = summary.get("timing", {})
    if t:
        lines.append("timing [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in t.items()))
    return "\n".join(lines)


def _memory(mb: float) -> str:
    return f"{mb / 1024.0:.2f} GB" if mb >= 1024.0 else f"{mb:.0f} MB"


def _cost_line(cost: dict) -> str:
    """The unknowns per field and the peak memory (with several ranks, each rank's too)."""
    unknowns = ", ".join(f"{field} {n}" for field, n in cost["unknowns"].items())
    per_rank = cost["peak_memory_mb_per_rank"]
    ranks = (f" (max over {len(per_rank)} ranks; per rank " + ", ".join(_memory(m) for m in per_rank) + ")"
             if len(per_rank) > 1 else "")
    return f"cost: unknowns {unknowns}; peak memory {_memory(cost['peak_memory_mb'])}{ranks}"
