"""The figures of a sweep: each summary quantity against the swept parameter, and linear scaling in Ca."""

from __future__ import annotations

import numpy as np

from gelcell.case import CaseParameters

__all__ = ["SWEEP_QUANTITIES", "LINEARITY_QUANTITIES", "plot_sweep", "plot_linearity"]


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


def plot_sweep(path: str, rows: list[dict], param: str, params: CaseParameters) -> None:
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


def plot_linearity(path: str, rows: list[dict], params: CaseParameters) -> None:
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
    for name in names:
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
