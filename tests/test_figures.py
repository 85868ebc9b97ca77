"""The figures: the PNG writer and the worker process that draws a run's figures.

The writer renders once, cropped to what is drawn plus the margin; the worker
draws a serial run's figures (steady and time-dependent).
"""

import io
import os
import subprocess
import sys

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from PIL import Image  # noqa: E402

from gelcell.output.drawing import _DPI, _PAD_INCHES, write_png  # noqa: E402


def test_write_png_crops_to_the_drawing_plus_the_margin(tmp_path):
    # a black rectangle of 2 x 1 inches in an otherwise empty 6 x 4 inch figure
    fig = plt.figure(figsize=(6, 4))
    fig.patches.append(plt.Rectangle((1 / 6, 1 / 4), 2 / 6, 1 / 4, transform=fig.transFigure, color="k", lw=0))
    path = tmp_path / "box.png"
    write_png(fig, str(path))
    plt.close(fig)
    image = np.asarray(Image.open(path).convert("RGB"))
    pad = round(_PAD_INCHES * _DPI)
    # size: the rectangle (antialiased edges may add a pixel) and the margin on every side
    assert abs(image.shape[1] - (2 * _DPI + 2 * pad)) <= 2
    assert abs(image.shape[0] - (1 * _DPI + 2 * pad)) <= 2
    # the margin is white, the inside black
    assert np.all(image[: pad - 1] == 255) and np.all(image[:, : pad - 1] == 255)
    assert np.all(image[pad + 2: -pad - 2, pad + 2: -pad - 2] == 0)


def test_write_png_keeps_an_empty_figure_whole(tmp_path):
    fig = plt.figure(figsize=(2, 1))
    path = tmp_path / "empty.png"
    write_png(fig, str(path))
    plt.close(fig)
    assert Image.open(path).size == (2 * _DPI, 1 * _DPI)


# -- the figure worker: a second process draws a serial run's figures ------------------------------
def _pixels(directory):
    return {f: np.asarray(Image.open(directory / f)) for f in sorted(os.listdir(directory)) if f.endswith(".png")}


def _run(out, monkeypatch, worker: str):
    from gelcell.case import CaseParameters, OutputSettings, RunConfig
    from gelcell.run.steady import run_case
    monkeypatch.setenv("GELCELL_FIGURE_WORKER", worker)
    params = CaseParameters.default("shear").with_mesh_size(3)
    return run_case(RunConfig(params, output=OutputSettings(progress=False)), str(out), stream=io.StringIO(),
                    fields=False)


@pytest.mark.skip_in_parallel
def test_worker_draws_the_same_figures_as_the_run_itself(tmp_path, monkeypatch):
    _run(tmp_path / "worker", monkeypatch, "1")
    _run(tmp_path / "here", monkeypatch, "0")
    a, b = _pixels(tmp_path / "worker"), _pixels(tmp_path / "here")
    assert sorted(a) == sorted(b) and len(a) == 6, sorted(a)
    for name in a:
        assert np.array_equal(a[name], b[name]), name


@pytest.mark.skip_in_parallel
def test_a_failed_worker_leaves_the_figures_to_the_run(tmp_path, monkeypatch, capfd):
    import gelcell.output.figures as plots

    class BrokenWorker(plots.FigureWorker):
        def __init__(self):
            self.proc = subprocess.Popen([sys.executable, "-c", "import sys; sys.stderr.write('boom'); sys.exit(3)"],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    monkeypatch.setattr("gelcell.output.figures.FigureWorker", BrokenWorker)
    summary = _run(tmp_path / "run", monkeypatch, "1")
    assert "figure worker failed (exit 3): boom" in capfd.readouterr().err
    pngs = [f for f in summary["files"] if f.endswith(".png")]
    assert len(pngs) == 6 and all((tmp_path / "run" / f).stat().st_size > 0 for f in pngs)


def test_the_worker_side_needs_neither_dolfinx_nor_mpi():
    code = ("import sys, gelcell.output.drawing; "
            "print([m for m in ('dolfinx', 'mpi4py', 'petsc4py', 'ufl') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip() == "[]", out


@pytest.mark.skip_in_parallel
def test_closing_a_worker_stops_it():
    from gelcell.output.figures import FigureWorker
    worker = FigureWorker()           # waits for data that never comes
    assert os.getpgid(worker.proc.pid) == worker.proc.pid    # its group: close() stops what it forked
    worker.close()
    assert worker.proc.returncode is not None


@pytest.mark.skip_in_parallel
def test_figures_carry_the_device_name_titles_and_units(tmp_path, monkeypatch):
    import gelcell.output.drawing
    texts = {}

    def record(fig, path):
        texts[os.path.basename(path)] = {
            "suptitle": fig._suptitle.get_text() if fig._suptitle is not None else "",
            "titles": [ax.get_title() for ax in fig.axes],
            "ylabels": [ax.get_ylabel() for ax in fig.axes]}
        open(path, "wb").close()

    monkeypatch.setattr(gelcell.output.drawing, "write_png", record)
    _run(tmp_path / "run", monkeypatch, "0")        # drawn in this process, so the recorder sees them
    profiles = texts["gamma1_profiles.png"]
    assert profiles["suptitle"] == "shear flow: profiles along Γ1", profiles
    assert profiles["ylabels"] == ["v_f,x [µm/s]", "v_f,y [µm/s]", "u_s,x [µm]", "u_s,y [µm]"], profiles
    assert "interstitial velocity in the gel" in texts["gel_velocity.png"]["titles"]
    assert "|v_f| [µm/s]" in texts["gel_velocity.png"]["ylabels"]           # the colour bar
    assert "p [mPa]" in texts["gel_pressure.png"]["ylabels"]
    assert texts["cell_traction_parts.png"]["suptitle"] == "stress parts in the gel around the cell (von Mises)"


def test_write_png_keeps_text_that_overhangs_the_figure(tmp_path):
    # a title wider than its 2-inch figure (by less than the overhang room): neither end may be cut off
    fig = plt.figure(figsize=(2, 2))
    fig.suptitle("a title wider than its figure")
    path = tmp_path / "title.png"
    write_png(fig, str(path))
    plt.close(fig)
    image = np.asarray(Image.open(path).convert("RGB"))
    pad = round(_PAD_INCHES * _DPI)
    ink = np.flatnonzero(np.any(image < 255, axis=(0, 2)))
    assert image.shape[1] > 2 * _DPI                      # wider than the figure
    assert abs(ink[0] - pad) <= 1 and abs(image.shape[1] - 1 - ink[-1] - pad) <= 1   # the margin on both sides


# -- drawing: the gouraud panel and the figures shared among processes -----------------------------
def _render(fig):
    buf = io.BytesIO()
    fig.savefig(buf, format="rgba", dpi=50)
    plt.close(fig)
    return buf.getvalue()


def test_gouraud_draws_the_pixels_of_tripcolor():
    import matplotlib.tri as mtri
    from gelcell.output.drawing import gouraud
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-1, 2, 200), rng.uniform(0, 0.5, 200)
    tri = mtri.Triangulation(x, y)
    values = np.sin(3 * x) * y
    images = []
    for draw in (lambda ax, t: ax.tripcolor(t, values, shading="gouraud", cmap="magma"),
                 lambda ax, t: gouraud(ax, t, values, "magma")):
        fig, ax = plt.subplots(figsize=(4, 2))
        plt.colorbar(draw(ax, tri), ax=ax)
        images.append(_render(fig))
    assert images[0] == images[1]


def _square(i):
    return i * i


def _fails():
    raise ValueError("task failed")


@pytest.mark.skip_in_parallel          # forks: never from an MPI process
def test_run_tasks_keeps_the_order_of_the_tasks_whatever_their_costs():
    import functools
    from gelcell.output.drawing import run_tasks
    tasks = [functools.partial(_square, i) for i in range(7)]
    costs = [0.1, 0.9, 0.3, 0.3, 0.8, 0.0, 0.5]
    assert run_tasks(tasks, costs, processes=2) == [i * i for i in range(7)]
    assert run_tasks(tasks, costs, processes=1) == [i * i for i in range(7)]
    with pytest.raises(ValueError, match="task failed"):
        run_tasks(tasks[:2] + [_fails], costs[:3], processes=2)


def _run_transient(out, monkeypatch, worker: str):
    from transient_cases import case, tau
    from gelcell.case import RunConfig, TimeSettings
    from gelcell.run.transient_case import run_transient_case
    monkeypatch.setenv("GELCELL_FIGURE_WORKER", worker)
    params = case("shear")
    settings = TimeSettings(transient=True, dt=tau(params) / 40, t_end=2 * tau(params) / 40)
    return run_transient_case(RunConfig(params, time=settings), str(out), fields=False, stream=io.StringIO())


@pytest.mark.skip_in_parallel
def test_worker_draws_a_time_dependent_run_s_figures_as_the_run_itself(tmp_path, monkeypatch):
    summary = _run_transient(tmp_path / "worker", monkeypatch, "1")
    _run_transient(tmp_path / "here", monkeypatch, "0")
    a, b = _pixels(tmp_path / "worker"), _pixels(tmp_path / "here")
    assert sorted(a) == sorted(b) and len(a) == 8, sorted(a)
    assert sorted(a) == sorted(f for f in summary["files"] if f.endswith(".png"))
    for name in a:
        assert np.array_equal(a[name], b[name]), name
