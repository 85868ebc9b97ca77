"""Figures of a device run as PNG files: the drawing, from plain arrays (numpy and matplotlib only).

``gelcell.output.figures`` gathers the fields of a run into plain arrays on rank 0
(``figure_data``) and draws them here, in the process or in a worker process
(``python -m gelcell.output.drawing``, see ``gelcell.output.figures.FigureWorker``) that has
imported matplotlib while the run was solving.  Coordinates are in units of
L0; field values in SI-derived units (µm/s, µm, mPa) so that a bioengineer
reads them directly.

3D runs (``data["section"]`` set): the 2D figures show the mid-height plane
(their titles say so) and two more the vertical plane through the cell
(``data["vertical"]``, see ``gelcell.output.figures``).
"""

from __future__ import annotations

import functools
import io
import json
import os
import pickle
import sys
import typing

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
from matplotlib.collections import TriMesh  # noqa: E402

__all__ = ["render_device_figures", "device_figure_tasks", "run_tasks", "gouraud", "profiles_figure",
           "draw_transient_figures", "draw_periodic_figure", "write_png"]


def _triangulation(data):
    X, T, _ = data
    return mtri.Triangulation(X[:, 0], X[:, 1], T)


def _field_panel(ax, data, values, label, cmap="viridis", axes=("x", "y")):
    tri = _triangulation(data)
    m = gouraud(ax, tri, values, cmap)
    plt.colorbar(m, ax=ax, label=label, shrink=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel(f"{axes[0]} / L0")
    ax.set_ylabel(f"{axes[1]} / L0")
    return tri


def _in_section(title: str, data: dict) -> str:
    """A figure's title, with the section it shows in 3D."""
    return title if not data.get("section") else f"{title}\n({data['section']})"


def gouraud(ax, tri, values, cmap):
    """``ax.tripcolor(tri, values, shading="gouraud", cmap=cmap)``, the same pixels, without its
    autoscaling pass: that pass converts every triangle to a Path (0.3 s of a run's figures)
    only to find the bounding box of the points, already added to the data limits."""
    m = TriMesh(tri, array=np.asarray(values), cmap=cmap, linewidths=(0.25,), edgecolors="none",
                antialiaseds=False)
    m.autoscale_None()
    ax.grid(False)
    ax.update_datalim([(tri.x.min(), tri.y.min()), (tri.x.max(), tri.y.max())])
    ax.autoscale_view()
    ax.add_collection(m, autolim=False)
    return m


def _streamlines(ax, tri, vx, vy):
    xmin, xmax = tri.x.min(), tri.x.max()
    ymin, ymax = tri.y.min(), tri.y.max()
    nx = 200
    ny = max(20, int(nx * (ymax - ymin) / (xmax - xmin)))
    gx, gy = np.meshgrid(np.linspace(xmin, xmax, nx), np.linspace(ymin, ymax, ny))
    ix, iy = mtri.LinearTriInterpolator(tri, vx)(gx, gy), mtri.LinearTriInterpolator(tri, vy)(gx, gy)
    u, v = np.ma.filled(ix, 0.0), np.ma.filled(iy, 0.0)
    ax.streamplot(gx, gy, u, v, color="w", linewidth=0.6, density=1.2, arrowsize=0.6)


#: resolution of the figures, and the margin left around what is drawn (as savefig's pad_inches)
_DPI = 150
_PAD_INCHES = 0.1
#: room rendered around the figure for text that overhangs it (long titles, tick labels)
_OVERHANG_INCHES = 1.0


def write_png(fig, path: str) -> None:
    """Render ``fig`` once and write it as a PNG cropped to what is drawn, plus a margin.

    The figure is rendered with ``_OVERHANG_INCHES`` of room on every side, so
    that text reaching beyond the figure is kept, and the white rows and
    columns around the drawing are trimmed.  This replaces
    ``bbox_inches="tight"``, which lays every figure out and draws it twice.
    zlib level 1: the pixels are the same, the encoding takes a quarter of the time.
    """
    from matplotlib.transforms import Bbox
    from PIL import Image
    w, h = fig.get_size_inches()
    m = _OVERHANG_INCHES
    raw = io.BytesIO()
    fig.savefig(raw, format="rgba", dpi=_DPI, bbox_inches=Bbox.from_extents(-m, -m, w + m, h + m),
                facecolor="white")
    rgba = _as_image(np.frombuffer(raw.getbuffer(), dtype=np.uint8), (w + 2 * m) * _DPI, (h + 2 * m) * _DPI)
    drawn = rgba.view(np.uint32)[..., 0] != 0xFFFFFFFF      # a pixel not opaque white (40x np.any's speed)
    rows, cols = np.flatnonzero(drawn.any(axis=1)), np.flatnonzero(drawn.any(axis=0))
    if rows.size:
        pad = int(round(_PAD_INCHES * _DPI))
        r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + 1 + pad, rgba.shape[0])
        c0, c1 = max(cols[0] - pad, 0), min(cols[-1] + 1 + pad, rgba.shape[1])
    else:                       # nothing drawn: the figure itself
        k = int(round(m * _DPI))
        r0, r1, c0, c1 = k, rgba.shape[0] - k, k, rgba.shape[1] - k
    Image.fromarray(np.ascontiguousarray(rgba[r0:r1, c0:c1]), "RGBA").save(
        path, format="png", compress_level=1, dpi=(_DPI, _DPI))


def _as_image(flat: np.ndarray, width: float, height: float) -> np.ndarray:
    """The (rows, columns, 4) array of raw RGBA bytes rendered for a canvas of about width x height pixels."""
    n = flat.size // 4
    for columns in sorted({int(np.floor(width)), int(round(width)), int(np.ceil(width))}):
        if columns > 0 and n % columns == 0 and abs(n // columns - height) <= 1:
            return flat.reshape(n // columns, columns, 4)
    raise RuntimeError(f"cannot read a rendered figure of {n} pixels as about {width:.0f} x {height:.0f}")


def _save(fig, directory, name) -> list[str]:
    write_png(fig, os.path.join(directory, name))
    plt.close(fig)
    return [name]


def profiles_figure(path: str, profiles: dict, V: float, L: float, label: str, overlay: dict | None = None,
                    labels: tuple[str, str] = ("with cell", "without cell"), where: str = "") -> None:
    """The four Gamma1 profiles v_fx, v_fy, u_sx, u_sy against the undeformed coordinate.

    ``V``, ``L``: µm/s and µm per unit of velocity and length; ``label``: the device's name;
    ``where``: appended to the title (3D: " at mid-height", where v_fz = u_sz = 0 by symmetry).
    """
    along = "X" if np.ptp(profiles["X"]) >= np.ptp(profiles["Y"]) else "Y"
    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex=True)
    spec = [("v_fx", V, "v_f,x [µm/s]"), ("v_fy", V, "v_f,y [µm/s]"),
            ("u_sx", L, "u_s,x [µm]"), ("u_sy", L, "u_s,y [µm]")]
    for ax, (key, factor, ylabel) in zip(axes.ravel(), spec):
        ax.plot(profiles[along], factor * profiles[key], "-", label=labels[0])
        if overlay is not None:
            ax.plot(overlay[along], factor * overlay[key], "--", label=labels[1])
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel(f"{along} / L0 along Γ1")
    if overlay is not None:
        axes[0, 0].legend()
    fig.suptitle(f"{label}: profiles along Γ1{where}")
    write_png(fig, path)
    plt.close(fig)


def _mark_cells(ax, specs) -> None:
    """Outline and (several cells) label every cell on a field panel."""
    t = np.linspace(0, 2 * np.pi, 100)
    for spec in specs:
        centre, r = np.asarray(spec.centre), 0.5 * spec.diameter
        ax.plot(centre[0] + r * np.cos(t), centre[1] + r * np.sin(t), "w-", lw=0.6)
        if len(specs) > 1:
            ax.annotate(spec.name.replace("cell_", "c"), centre + np.array([0, 1.3 * r]), ha="center",
                        fontsize=6, color="w")


def _panel_size(data: dict) -> tuple[float, float]:
    return (11, 3.2) if data["wide"] else (8, 4)


def _velocity_figure(directory: str, data: dict) -> list[str]:
    speed = data["speed"]
    fig, ax = plt.subplots(figsize=_panel_size(data))
    vals = speed[2]
    tri = _field_panel(ax, speed, data["V"] * np.linalg.norm(vals, axis=1), "|v_f| [µm/s]")
    _streamlines(ax, tri, vals[:, 0], vals[:, 1])
    _mark_cells(ax, data["cells"])
    ax.set_title(_in_section("interstitial velocity in the gel", data))
    return _save(fig, directory, "gel_velocity.png")


def _pressure_figure(directory: str, data: dict) -> list[str]:
    pressure = data["pressure"]
    fig, ax = plt.subplots(figsize=_panel_size(data))
    _field_panel(ax, pressure, data["S"] * pressure[2], "p [mPa]", cmap="coolwarm")
    ax.set_title(_in_section("pore pressure in the gel", data))
    return _save(fig, directory, "gel_pressure.png")


def _displacement_figure(directory: str, data: dict) -> list[str]:
    disp, vm, size = data["disp"], data["vm"], _panel_size(data)
    fig, axes = plt.subplots(2, 1, figsize=(size[0], 2 * size[1]))
    _field_panel(axes[0], disp, data["L"] * np.linalg.norm(disp[2], axis=1), "|u_s| [µm]")
    axes[0].set_title(_in_section("network displacement", data))
    _field_panel(axes[1], vm, data["S"] * vm[2], "von Mises of σ_s [mPa]", cmap="magma")
    for ax in axes:
        _mark_cells(ax, data["cells"])
    axes[1].set_title("von Mises stress of the network")
    return _save(fig, directory, "gel_displacement_von_mises.png")


def _profiles_task(directory: str, data: dict) -> list[str]:
    profiles_figure(os.path.join(directory, "gamma1_profiles.png"), data["profiles"], data["V"], data["L"],
                    data["label"], data["overlay"], where=" at mid-height" if data.get("section") else "")
    return ["gamma1_profiles.png"]


def _cell_displacement_figure(directory: str, data: dict) -> list[str]:
    X, _, U = data["cell"]
    specs, t = data["cells"], np.linspace(0, 2 * np.pi, 200)
    fig, ax = plt.subplots(figsize=(5, 5) if len(specs) == 1 else (8, 5))
    # each cell's displacement relative to its own centroid, each cell outlined and labelled
    for spec, cs in zip(specs, data["cells_summary"]):
        centre, r = np.asarray(spec.centre), 0.5 * spec.diameter
        mine = np.linalg.norm(X - centre, axis=1) <= r * (1 + 1e-6)
        # (3D: the mid-height plane's vertices, the in-plane components)
        rel = U[mine][:, :2] - np.asarray(cs["centroid_displacement"])[:2]
        ax.quiver(X[mine, 0], X[mine, 1], data["L"] * rel[:, 0], data["L"] * rel[:, 1], angles="xy")
        ax.plot(centre[0] + r * np.cos(t), centre[1] + r * np.sin(t), "k-", lw=0.5)
        if len(specs) > 1:
            ax.annotate(spec.name, centre + np.array([0, 1.15 * r]), ha="center", fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x / L0")
    ax.set_ylabel("y / L0")
    ax.set_title(_in_section("cell displacement relative to its centroid [µm, arrows not to scale]", data))
    return _save(fig, directory, "cell_displacement.png")


def _traction_parts_figure(directory: str, data: dict, spec) -> list[str]:
    specs, t = data["cells"], np.linspace(0, 2 * np.pi, 200)
    centre, r = np.asarray(spec.centre), 0.5 * spec.diameter
    fig, axes = plt.subplots(2, 2, figsize=(9, 8))
    for ax, (key, (Xg, Tg, values)) in zip(axes.ravel(), data["parts"].items()):
        # draw only the triangles that reach into the window; the colour scale still spans every
        # vertex value (the scale is set from the value array, which stays whole)
        lo, hi = centre - 4 * r, centre + 4 * r
        corners = Xg[Tg]
        inside = np.all((corners.max(axis=1) >= lo) & (corners.min(axis=1) <= hi), axis=1)
        _field_panel(ax, (Xg, Tg[inside], values), data["S"] * values, "von Mises [mPa]", cmap="magma")
        ax.set_xlim(centre[0] - 4 * r, centre[0] + 4 * r)
        ax.set_ylim(centre[1] - 4 * r, centre[1] + 4 * r)
        for other in specs:
            c2, r2 = np.asarray(other.centre), 0.5 * other.diameter
            ax.plot(c2[0] + r2 * np.cos(t), c2[1] + r2 * np.sin(t), "w-", lw=0.8)
        ax.set_title({"pressure": "pressure  −p I", "brinkman": "Brinkman  φ_f σ_f",
                      "network": "network  φ_s σ_s", "total": "total"}[key])
    fig.suptitle(_in_section("stress parts in the gel around the cell (von Mises)" if len(specs) == 1 else
                             f"stress parts in the gel around {spec.name} (von Mises)", data))
    fig.subplots_adjust(wspace=0.5, hspace=0.35)
    return _save(fig, directory, "cell_traction_parts.png" if len(specs) == 1 else f"{spec.name}_traction_parts.png")


def device_figure_tasks(directory: str, data: dict) -> list[tuple[float, typing.Callable[[], list[str]]]]:
    """The figures of a device run as independent tasks ``(cost, draw)``, in the order their files
    are listed; each ``draw()`` writes its PNG file and returns its name.  The costs are the
    seconds each took at the default mesh (shear with a cell), used only to order the work."""
    tasks = [(0.4, functools.partial(_velocity_figure, directory, data)),
             (0.15, functools.partial(_pressure_figure, directory, data)),
             (0.3, functools.partial(_displacement_figure, directory, data)),
             (0.25, functools.partial(_profiles_task, directory, data))]
    if data["cell"] is not None:
        tasks.append((0.12, functools.partial(_cell_displacement_figure, directory, data)))
        tasks += [(0.5, functools.partial(_traction_parts_figure, directory, data, spec)) for spec in data["cells"]]
    if data.get("vertical") is not None:
        tasks += [(0.3, functools.partial(_vertical_velocity_figure, directory, data)),
                  (0.3, functools.partial(_vertical_displacement_figure, directory, data))]
    return tasks


def _vertical_size(section) -> tuple[float, float]:
    """A panel as wide as the 2D ones, as high as the section's aspect asks (plus room for the labels)."""
    X = section[0]
    aspect = np.ptp(X[:, 1]) / max(np.ptp(X[:, 0]), 1e-300)
    return 11, 1.2 + 8 * aspect


def _vertical_limits(ax, section) -> None:
    """The section's own extent (the cells' circles reach beyond the computed half height)."""
    X = section[0]
    ax.set_xlim(X[:, 0].min(), X[:, 0].max())
    ax.set_ylim(X[:, 1].min(), X[:, 1].max())


def _vertical_velocity_figure(directory: str, data: dict) -> list[str]:
    """|v_f| on the vertical plane y = y_cell, with the streamlines of its in-plane part (v_f,x, v_f,z)."""
    vert = data["vertical"]
    speed, (i, k) = vert["speed"], vert["components"]
    fig, ax = plt.subplots(figsize=_vertical_size(speed))
    vals = speed[2]
    tri = _field_panel(ax, speed, data["V"] * np.linalg.norm(vals, axis=1), "|v_f| [µm/s]", axes=("x", "z"))
    _streamlines(ax, tri, vals[:, i], vals[:, k])
    _mark_cells(ax, vert["cells"])
    _vertical_limits(ax, speed)
    ax.set_title(f"interstitial velocity in the gel (vertical plane y = {vert['y']:.4g} through the cell)")
    return _save(fig, directory, "gel_velocity_vertical.png")


def _vertical_displacement_figure(directory: str, data: dict) -> list[str]:
    """|u_s| and the network's von Mises stress on the vertical plane y = y_cell."""
    vert = data["vertical"]
    disp, vm = vert["disp"], vert["vm"]
    w, h = _vertical_size(disp)
    fig, axes = plt.subplots(2, 1, figsize=(w, 2 * h))
    _field_panel(axes[0], disp, data["L"] * np.linalg.norm(disp[2], axis=1), "|u_s| [µm]", axes=("x", "z"))
    _field_panel(axes[1], vm, data["S"] * vm[2], "von Mises of σ_s [mPa]", cmap="magma", axes=("x", "z"))
    for ax, section in zip(axes, (disp, vm)):
        _mark_cells(ax, vert["cells"])
        _vertical_limits(ax, section)
    axes[0].set_title(f"network displacement (vertical plane y = {vert['y']:.4g} through the cell)")
    axes[1].set_title("von Mises stress of the network")
    return _save(fig, directory, "gel_displacement_von_mises_vertical.png")


def render_device_figures(directory: str, data: dict, processes: int = 1) -> list[str]:
    """Draw the figures of a device run from gathered data (``gelcell.output.figures.figure_data``) into
    ``directory``; returns the file names.  Pure numpy and matplotlib (also run in a worker process).

    ``processes > 1`` draws them in that many forked processes (the figure worker does, on an
    otherwise idle core): the figures are independent and the same pixels result.
    """
    tasks = device_figure_tasks(directory, data)
    return [name for names in run_tasks([draw for _, draw in tasks], [cost for cost, _ in tasks], processes)
            for name in names]


#: the tasks of run_tasks, inherited by its forked processes (nothing is pickled but an index)
_TASKS: list = []


def _run_task(index: int):
    return _TASKS[index]()


def run_tasks(tasks: list, costs: list[float], processes: int) -> list:
    """``[task() for task in tasks]``, by ``processes`` forked processes when more than one.

    Dealt out one at a time, the costliest first (longest-processing-time order), so the
    processes finish close together; the results keep the order of ``tasks``.  Forking needs a
    process without MPI or threads: the figure worker, never the run itself.
    """
    processes = min(processes, len(tasks))
    if processes < 2:
        return [task() for task in tasks]
    import multiprocessing
    global _TASKS
    order = sorted(range(len(tasks)), key=lambda i: -costs[i])
    _TASKS = tasks
    try:
        with multiprocessing.get_context("fork").Pool(processes) as pool:
            done = pool.map(_run_task, order, chunksize=1)
    finally:
        _TASKS = []
    results = [None] * len(tasks)
    for i, result in zip(order, done):
        results[i] = result
    return results


def draw_transient_figures(directory: str, rows: list[dict], summary: dict, params, comm) -> list[str]:
    """trajectory.png and iterations.png of a time-dependent run; rank 0 draws, returns the file names."""
    if comm.rank != 0:
        return []
    fig = _trajectory_figure(rows, summary["transient"], params)
    written = _save(fig, directory, "trajectory.png")
    return written + _save(_iterations_figure(rows, summary["transient"]), directory, "iterations.png")


def draw_periodic_figure(directory: str, rows: list[dict], block: dict, params, comm) -> list[str]:
    """periodic_cycle.png: the last cycle's tracked quantities and the inflow, each normalised to [0, 1]."""
    if comm.rank != 0 or not block["per_cycle"]:
        return []
    return _save(_periodic_figure(rows, block, params), directory, "periodic_cycle.png")


#: the curves of periodic_cycle.png: (column, label, reporting kind or None for dimensionless)
_PERIODIC_CURVES = (("centroid_x", "centroid x", "length"), ("centroid_y", "centroid y", "length"),
                    ("centroid_z", "centroid z", "length"), ("cell_strain_max", "cell's peak von Mises strain", None),
                    ("cell_stress_max", "cell's peak von Mises stress", "stress"),
                    ("max_network_displacement", "max |u_s|", "length"))


def _normalised(q: np.ndarray) -> np.ndarray | None:
    """(q - min) / (max - min), or None for a constant q."""
    span = np.ptp(q)
    return None if not span > 0 else (q - np.min(q)) / span


def _periodic_figure(rows: list[dict], block: dict, params):
    """The last cycle against its phase t/P, from the sample at its start (the previous cycle's last)."""
    steps, count = block["steps_per_period"], block["cycles"]
    cycle = rows[(count - 1) * steps: count * steps + 1]
    phase = np.linspace(0.0, 1.0, len(cycle))
    lags = block["per_cycle"][-1]["phase_lag"]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    inflow = _normalised(np.array([r["inflow"] for r in cycle]))
    if inflow is not None:
        ax.plot(phase, inflow, "k--", lw=1.6, label="inflow f(t)")
    for column, label, kind in _PERIODIC_CURVES:
        if column not in cycle[0] or not np.all(np.isfinite([r[column] for r in cycle])):
            continue
        q = np.array([r[column] for r in cycle])
        curve = _normalised(q)
        if curve is None:
            continue
        unit = {None: "", "length": " µm", "stress": " mPa"}[kind]     # params.to_report's units
        values = q if kind is None else params.to_report(q, kind)
        lag = lags.get(column)
        lag_words = "" if lag is None else f", lag {lag['degrees']:.1f}°"
        ax.plot(phase, curve, "-", marker=".", ms=3,
                label=f"{label} {np.min(values):.4g} to {np.max(values):.4g}{unit}{lag_words}")
    verdict = "periodic" if block["converged"] else "not yet periodic"
    change = "" if block["change"] is None else f", change {block['change']:.1e}"
    ax.set_title(f"{params.label}: the last of {count} cycles ({verdict}{change}), period "
                 f"{params.to_si(block['period'], 'time'):.3g} s")
    ax.set_xlabel("phase t / period in the last cycle")
    ax.set_ylabel("normalised: (q - min) / (max - min) over the cycle")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7)
    return fig


def _trajectory_figure(rows: list[dict], tr: dict, params):
    """The centroid's x and y (3D: and z, if it moves) against t (y, z on their own axis, steady values and
    t50/t90/t99 marked); without a cell, max |u_s|."""
    seconds = params.to_si(np.array([r["t"] for r in rows]), "time")
    L = params.to_report(1.0, "length")
    fig, ax = plt.subplots(figsize=(8, 4.5))
    if params.with_cell:
        _draw_centroids(ax, rows, seconds, L, params)
        for q, style in (("t50", "--"), ("t90", "-."), ("t99", ":")):
            if tr.get(q) is not None:
                ax.axvline(params.to_si(tr[q], "time"), color="grey", ls=style, lw=0.8, label=q)
    else:
        u = L * np.array([r["max_network_displacement"] for r in rows])
        ax.plot(seconds, u, "C0-", label="max |u_s|")
        ax.axhline(u[-1], color="C0", ls=":", lw=0.8)
        ax.set_ylabel("max |u_s| [µm]")
        ax.set_title(f"{params.label} without a cell: the network from rest")
    ax.set_xlabel("t [s]")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    return fig


def _draw_centroids(ax, rows: list[dict], seconds: np.ndarray, L: float, params) -> None:
    """Each cell's centroid x (several cells: the extremes' curve dashed) and the y motion on a twin axis."""
    x = L * np.array([r["centroid_x"] for r in rows])
    y = L * np.array([r["centroid_y"] for r in rows])
    n_cells = sum(1 for k in rows[-1] if k.startswith("cell_") and k.endswith("_centroid_x"))
    if n_cells > 1:
        for k in range(1, n_cells + 1):
            ax.plot(seconds, L * np.array([r.get(f"cell_{k}_centroid_x", np.nan) for r in rows]), "-",
                    lw=0.9, label=f"cell_{k} x")
    ax.plot(seconds, x, "C0-" if n_cells <= 1 else "k--", label="centroid x" if n_cells <= 1 else
            "x of the cell that moves most")
    ax.axhline(x[-1], color="C0", ls=":", lw=0.8, label=f"final x {x[-1]:.4g} µm")
    ax.set_ylabel("centroid displacement x [µm]", color="C0")
    # 3D: z (zero by symmetry for a cell at mid-height, then not drawn)
    z = L * np.array([r.get("centroid_z", 0.0) for r in rows])
    if np.any(y != 0) or np.any(z != 0):
        # the much smaller y (and z) motion on its own axis (y zero by symmetry in the normal-flow device)
        ay = ax.twinx()
        ay.plot(seconds, y, "C3-", label="centroid y")
        ay.axhline(y[-1], color="C3", ls=":", lw=0.8)
        if np.any(z != 0):
            ay.plot(seconds, z, "C2-", label="centroid z")
            ay.axhline(z[-1], color="C2", ls=":", lw=0.8)
        ay.set_ylabel("centroid displacement y [µm]" if not np.any(z != 0) else "centroid displacement y, z [µm]",
                      color="C3")
    ax.set_title(f"{params.label}: the cell's centroid from rest" if n_cells <= 1 else
                 f"{params.label}: the cells' centroids from rest")


def _iterations_figure(rows: list[dict], tr: dict):
    """Coupling iterations per window (the first row is the initial state)."""
    fig, ax = plt.subplots(figsize=(8, 3.5))
    its = [r["iterations"] for r in rows[1:]]
    ax.bar(np.arange(1, len(its) + 1), its, width=1.0, color="C0")
    ax.set_xlabel("time window")
    ax.set_ylabel("iterations")
    mean = tr.get("iterations_mean")
    ax.set_title(f"iterations per window (mean {mean:.2f})" if mean is not None else "iterations per window")
    ax.grid(alpha=0.3, axis="y")
    return fig


def _worker_main() -> int:
    """``python -m gelcell.output.drawing``: read one pickled ``(directory, data)`` from stdin, draw it,
    print the JSON list of the file names written.  matplotlib is imported before the data
    arrives (the parent starts this process early, so that the import overlaps its solve)."""
    directory, data = pickle.load(sys.stdin.buffer)
    # the run waits for the figures once it has written its other files: use every core meanwhile
    names = render_device_figures(directory, data, processes=len(os.sched_getaffinity(0)))
    sys.stdout.write(json.dumps(names) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(_worker_main())
