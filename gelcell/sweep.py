"""``gelcell sweep``: one case per value of a parameter, tabulated and plotted."""

from __future__ import annotations

import csv
import os

import numpy as np

from mpi4py import MPI

from femtools.io import atomic_directory
from gelcell.output import write_json_file
from gelcell.parameters import CaseParameters
from gelcell.runner import run_case

__all__ = ["run_sweep", "SWEEP_QUANTITIES"]

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


def _row(summary: dict) -> dict:
    row = {}
    for name, key, sub in SWEEP_QUANTITIES:
        v = summary.get(key)
        row[name] = None if v is None else (v if sub is None else v[sub])
    c = summary.get("coupling") or {}
    row["iterations"] = c.get("iterations")
    row["converged"] = c.get("converged", True)
    row["Ca"] = summary["parameters"]["dimensionless"]["Ca"] if "dimensionless" in summary["parameters"] else None
    return row


def run_sweep(cases: list[CaseParameters], param: str, values: list[float], out: str, *,
              monolithic: bool = False, scheme: str = "serial", acceleration: str = "iqn-ils",
              verbose: bool = False, comm: MPI.Comm = MPI.COMM_WORLD, gamma2: str = "dirichlet") -> list[dict]:
    """Run every case; write sweep.csv/json, sweep.png and runs/<param>=<value>/summary.json."""
    rows = []
    with atomic_directory(out, comm) as tmp:
        for value, params in zip(values, cases):
            run_dir = os.path.join(tmp, "runs", f"{param}={value:g}")
            summary = run_case(params, run_dir, monolithic=monolithic, scheme=scheme,
                               acceleration=acceleration, comm=comm, verbose=verbose, figures=False,
                               fields=False, gamma2=gamma2)
            rows.append({param: value, **_row(summary)})
        write_json_file(os.path.join(tmp, "sweep.json"), rows, comm)
        if comm.rank == 0:
            with open(os.path.join(tmp, "sweep.csv"), "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=list(rows[0]))
                w.writeheader()
                w.writerows(rows)
            _plot(os.path.join(tmp, "sweep.png"), rows, param, cases[0])
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
    fig.suptitle(f"{params.case} flow: summary quantities (paper's dimensionless units) against {param}")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
