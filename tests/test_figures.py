"""The PNG writer of the figures: one rendering, cropped to what is drawn plus the margin."""

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from PIL import Image  # noqa: E402

from gelcell.plots import _DPI, _PAD_INCHES, write_png  # noqa: E402


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
