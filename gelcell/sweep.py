"""``gelcell sweep``: one case per value of a parameter, tabulated and plotted.

A value whose run fails (the coupling diverges, a solver fails, ...) does not
discard the others: the sweep writes every completed run, lists the failed
values with their error in sweep.csv/sweep.json, and then raises
:class:`gelcell.errors.SweepError`.

Reuse (``--param ca``).  In the solver's units (stress Ca mu_s, displacement
Ca L0) every value of a Ca sweep is the same coupled problem up to the
strain-sized nonlinearity (gelcell.device.reuse_key).  Each value after the
first therefore starts from the previous values' interface data and field
states extrapolated in Ca (gelcell.runner.ReuseStore), with the linearized
prior's factorisation under the prior (the default) and the quasi-Newton
columns otherwise (gelcell.device.Device.solve); sweep.csv records
``iterations`` and ``reused``.
Other sweeps change the interface operator and start from rest.

Beyond linearity (``--param ca``).  At fixed moduli Ca sets the flow speed;
the flow is Ca-independent in the paper's units and every displacement,
strain and stress is proportional to Ca as long as the response is linear.
``linearity.png`` plots a few of them divided by Ca (normalised by their
value at the smallest Ca, so linear scaling is a flat line at 1) and shows
where that ends.  ``compare_kinematics`` also runs every value on the other
kinematics path (``runs/<param>=<value>-small`` or ``-finite``) and records
``departure``: the largest relative difference of those quantities between
the small-strain and the finite-strain result (relative to the latter).
"""

from __future__ import annotations

import csv
import os
import sys
import traceback

import numpy as np

from mpi4py import MPI

from femtools.io import atomic_directory
from gelcell.errors import SweepError, exit_code, message
from gelcell.output import write_json_file
from gelcell.parameters import DEFAULT_GAMMA2, CaseParameters, ParameterError
from gelcell.runner import ReuseStore, run_case

__all__ = ["run_sweep", "run_name", "check_distinct", "SWEEP_QUANTITIES"]

#: (column name, summary key, index or sub-key) of the tabulated quantities, paper units
SWEEP_QUANTITIES = [
    ("max_interstitial_speed", "gel.max_interstitial_speed", None),
    ("max_network_displacement", "gel.max_network_displacement", None),
    ("max_network_von_mises", "gel.max_network_von_mises", None),
    ("volume_change_below_gamma1", "gel.volume_change_below_gamma1", None),
    ("volume_change_share_of_cell", "gel.volume_change_share_of_cell", None),
    ("cell_centroid_x", "cell.centroid_displacement", 0),
    ("cell_centroid_y", "cell.centroid_displacement", 1),
    ("cell_max_displacement", "cell.max_displacement", None),
    ("cell_von_mises_strain_max", "cell.von_mises_strain", 1),
    ("cell_von_mises_stress_max", "cell.von_mises_stress", 1),
    ("traction_pressure", "cell.max_traction_von_mises", "pressure"),
    ("traction_brinkman", "cell.max_traction_von_mises", "brinkman"),
    ("traction_network", "cell.max_traction_von_mises", "network"),
    ("traction_total", "cell.max_traction_von_mises", "total"),
]


#: the quantities of the linearity figure and of the kinematics departure (if present)
LINEARITY_QUANTITIES = ("max_network_displacement", "max_network_von_mises", "cell_centroid_x",
                        "cell_von_mises_strain_max", "cell_von_mises_stress_max", "traction_total")


def departure(small: dict, finite: dict) -> float | None:
    """max over LINEARITY_QUANTITIES of |small - finite| / |finite| (None if none is present)."""
    values = [abs(small[k] - finite[k]) / abs(finite[k]) for k in LINEARITY_QUANTITIES
              if small.get(k) is not None and finite.get(k) not in (None, 0)]
    return max(values) if values else None


def _row(summary: dict) -> dict:
    row = {}
    for name, key, sub in SWEEP_QUANTITIES:
        v = summary.get(key)
        row[name] = None if v is None else (v if sub is None else v[sub])
    c = summary.get("coupling") or {}
    row["iterations"] = c.get("iterations")
    row["reused"] = c.get("reused")
    row["converged"] = c.get("converged", True)
    row["Ca"] = summary["parameters"]["dimensionless"]["Ca"] if "dimensionless" in summary["parameters"] else None
    row["model_warnings"] = "; ".join(summary["model"]["warnings"])
    return row


def run_name(param: str, value: float) -> str:
    """The directory of one run: ``runs/<param>=<value>`` (6 significant digits)."""
    return f"{param}={value:g}"


def check_distinct(param: str, values: list[float]) -> None:
    """Raise :class:`ParameterError` if two values would share a run (and its directory)."""
    names = [run_name(param, v) for v in values]
    repeated = sorted({n for n in names if names.count(n) > 1}, key=names.index)
    if repeated:
        raise ParameterError(f"--values gives {', '.join(repeated)} more than once (values equal to 6 "
                             f"significant digits are one run): give each value once")


def run_sweep(cases: list[CaseParameters], param: str, values: list[float], out: str, *,
              monolithic: bool = False, scheme: str = "serial", acceleration: str = "iqn-ils",
              verbose: bool = False, comm: MPI.Comm = MPI.COMM_WORLD, gamma2: str = DEFAULT_GAMMA2,
              debug: bool = False, compare_kinematics: bool = False) -> list[dict]:
    """Run every case; write sweep.csv/json, sweep.png and runs/<param>=<value>/summary.json.

    ``param == "ca"`` also draws linearity.png; ``compare_kinematics`` runs each value on the other
    kinematics path too (module docstring).

    Values must be distinct (:func:`check_distinct`).  A value that fails is
    recorded (``status`` "failed", ``error``) and the sweep goes on; if any
    failed, :class:`SweepError` is raised after the completed runs are written.
    An interruption (SIGINT, SIGTERM) discards the whole sweep.
    """
    check_distinct(param, values)
    final = os.path.abspath(out)
    rows, failures = [], []
    # one store per kinematics path: consecutive values of the same scaled problem (a Ca sweep) reuse the
    # previous values' interface data and the prior or the quasi-Newton columns (gelcell.runner.solve_partitioned)
    stores: dict[str, ReuseStore] = {}
    with atomic_directory(out, comm) as tmp:
        for value, params in zip(values, cases):
            name = run_name(param, value)
            other = ("small" if params.kinematics == "finite" else "finite") if compare_kinematics else None
            runs = [(name, params)] + ([(f"{name}-{other}", params.with_kinematics(other))] if other else [])
            try:
                summaries = [run_case(p, os.path.join(tmp, "runs", n), monolithic=monolithic, scheme=scheme,
                                      acceleration=acceleration, comm=comm, verbose=verbose, figures=False,
                                      fields=False, gamma2=gamma2, shown_path=os.path.join(final, "runs", n),
                                      reuse=stores.setdefault(p.kinematics, ReuseStore()))
                             for n, p in runs]
            except Exception as exc:  # noqa: BLE001  (one failed value must not discard the others)
                if comm.rank == 0:
                    if debug:
                        traceback.print_exc()
                    print(f"gelcell sweep: {name} failed: {message(exc)}", file=sys.stderr, flush=True)
                failures.append((value, message(exc), exit_code(exc)))
                rows.append({param: value, "status": "failed", "error": message(exc)})
                continue
            row = {param: value, "status": "ok", "error": "", "kinematics": params.kinematics,
                   **_row(summaries[0])}
            if other:
                names = {n for n, _, _ in SWEEP_QUANTITIES} | {"iterations"}
                row.update({f"{other}.{k}": v for k, v in _row(summaries[1]).items() if k in names})
                by_path = {params.kinematics: _row(summaries[0]), other: _row(summaries[1])}
                row["departure"] = departure(by_path["small"], by_path["finite"])
            rows.append(row)
        write_json_file(os.path.join(tmp, "sweep.json"), rows, comm)
        if comm.rank == 0:
            with open(os.path.join(tmp, "sweep.csv"), "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)), restval="")
                w.writeheader()
                w.writerows(rows)
            done = [r for r in rows if r["status"] == "ok"]
            if done:
                _plot(os.path.join(tmp, "sweep.png"), done, param, cases[0])
                if param == "ca":
                    _plot_linearity(os.path.join(tmp, "linearity.png"), done, cases[0])
    if comm.rank == 0:
        print(f"gelcell sweep: wrote {final}: sweep.csv, sweep.json"
              + (", sweep.png" if len(failures) < len(values) else "")
              + (", linearity.png" if len(failures) < len(values) and param == "ca" else "")
              + f", runs/ ({len(values) - len(failures)} of {len(values)} values)", flush=True)
    if failures:
        raise SweepError(f"{len(failures)} of {len(values)} values failed ("
                         + ", ".join(run_name(param, v) for v, _, _ in failures)
                         + f"; why: the lines above and the error column of sweep.csv); the completed "
                         f"runs are in {final}", failures)
    return rows


def _plot(path: str, rows: list[dict], param: str, params: CaseParameters) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = [n for n, _, _ in SWEEP_QUANTITIES if any(r[n] is not None for r in rows)]
    ncol = 4
    nrow = int(np.ceil(len(names) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4 * ncol, 3 * nrow), squeeze=False)
    x = np.array([r[param] for r in rows], dtype=float)
    logx = param in ("ca", "cell-moduli", "gel-moduli") and np.all(x > 0)
    for ax, name in zip(axes.ravel(), names):
        y = np.array([np.nan if r[name] is None else r[name] for r in rows], dtype=float)
        ax.plot(x, y, "o-")
        if logx:
            ax.set_xscale("log")
            if np.all(y > 0):
                ax.set_yscale("log")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(param)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle(f"{params.label}: summary quantities (paper's dimensionless units) against {param}")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_linearity(path: str, rows: list[dict], params: CaseParameters) -> None:
    """Quantities / Ca, normalised at the smallest Ca, against Ca; the kinematics departure if compared."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = sorted(rows, key=lambda r: r["ca"])
    ca = np.array([r["ca"] for r in rows], dtype=float)
    main = rows[0].get("kinematics", params.kinematics)
    other = "small" if main == "finite" else "finite"
    names = [n for n in LINEARITY_QUANTITIES if all(r.get(n) not in (None, 0) for r in rows)]
    compared = any(r.get("departure") is not None for r in rows)
    fig, axes = plt.subplots(1, 2 if compared else 1, figsize=(12 if compared else 7, 4.5), squeeze=False)
    ax = axes[0, 0]
    for k, name in enumerate(names):
        y = np.array([r[name] for r in rows], dtype=float) / ca
        line, = ax.plot(ca, np.abs(y / y[0]), "o-", label=f"{name} ({main})")
        if compared and all(r.get(f"{other}.{name}") is not None for r in rows):
            y2 = np.array([r[f"{other}.{name}"] for r in rows], dtype=float) / ca
            ax.plot(ca, np.abs(y2 / y[0]), "x--", color=line.get_color(), alpha=0.7, label=f"{name} ({other})")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("Ca")
    ax.set_ylabel("(quantity / Ca) / (its value at the smallest Ca)")
    ax.set_title("linear scaling: flat at 1", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    if compared:
        ax = axes[0, 1]
        dep = np.array([np.nan if r.get("departure") is None else r["departure"] for r in rows], dtype=float)
        ax.loglog(ca, dep, "o-", label="max relative difference, small vs finite")
        for level in (0.01, 0.1):
            ax.axhline(level, color="k", ls=":", lw=0.8)
        ax.set_xlabel("Ca")
        ax.set_title("departure of the small-strain result from the finite-strain one", fontsize=10)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle(f"{params.label}{' with the cell' if params.with_cell else ''}: where linear scaling ends")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
