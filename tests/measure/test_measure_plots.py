"""PNG plots for measurement reports (measure/plots.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure.plots import MAX_SCATTER_POINTS, plot_density, plot_side_view, plot_top_view, subsample

# colours the plots use (BGR as OpenCV reads them)
RED_BGR = np.array([0x1D, 0x18, 0xCB])      # peaks / fitted box / height
BLUE_BGR = np.array([0x9C, 0x51, 0x08])     # KDE curve


def _read(path):
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, f"{path} is not a readable PNG"
    assert open(path, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    return img


def _count_colour(img, bgr, tol=30):
    return int((np.abs(img.astype(int) - bgr).max(axis=2) <= tol).sum())


def _box_points(rng, n, length=12.0, width=2.5, height=3.9):
    x = rng.uniform(0, length, n)
    y = np.where(rng.random(n) < 0.5, 0.0, width) + rng.normal(0, 0.01, n)
    z = rng.uniform(0.3, height, n)
    return np.c_[x, y, z]


def test_density_plot_is_a_valid_non_blank_png(tmp_path, rng):
    samples = np.r_[rng.normal(0.0, 0.02, 5000), rng.normal(2.5, 0.02, 5000)]
    grid = np.linspace(-0.3, 2.8, 300)
    dens = 0.5 * (np.exp(-0.5 * (grid / 0.03) ** 2) + np.exp(-0.5 * ((grid - 2.5) / 0.03) ** 2)) / (0.03 * np.sqrt(2 * np.pi))
    out = plot_density(tmp_path / "sub" / "width.png", "width", grid, dens, samples_m=samples, peaks_m=(0.0, 2.5),
                       markers_m={"front extreme": 2.6}, title="width density")
    assert out == tmp_path / "sub" / "width.png"
    img = _read(out)
    assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 600
    assert img.std() > 10
    assert _count_colour(img, RED_BGR) > 200     # the two peak lines and the distance arrow
    assert _count_colour(img, BLUE_BGR) > 200    # the KDE curve
    assert [p.name for p in out.parent.iterdir()] == ["width.png"]   # no temp file left behind


def test_density_plot_without_samples_or_peaks_and_bad_shapes(tmp_path):
    grid = np.linspace(0, 1, 50)
    img = _read(plot_density(tmp_path / "d.png", "length", grid, np.ones_like(grid)))
    assert img.std() > 5
    with pytest.raises(ValueError, match="differ"):
        plot_density(tmp_path / "e.png", "length", grid, np.ones(10))


def test_top_and_side_views_of_a_million_points(tmp_path, rng):
    pts = _box_points(rng, 1_000_000)
    corners = np.array([[0.0, 0.0], [12.0, 0.0], [12.0, 2.5], [0.0, 2.5]])
    top = _read(plot_top_view(tmp_path / "top.png", pts[:, :2], corners, 12.0, 2.5))
    side = _read(plot_side_view(tmp_path / "side.png", pts[:, [0, 2]], 3.9))
    for img in (top, side):
        assert img.shape[0] > 300 and img.shape[1] > 600 and img.std() > 10
        assert _count_colour(img, RED_BGR) > 300
    # the side view's points fill a 12 x 3.6 m block: many dark-grey pixels
    assert (side.max(axis=2) < 200).sum() > 20_000


def test_plots_accept_nan_rows_and_model_scale(tmp_path, rng):
    pts = _box_points(rng, 20_000, length=1.2, width=0.25, height=0.4)
    pts[::97] = np.nan
    corners = np.array([[0.0, 0.0], [1.2, 0.0], [1.2, 0.25], [0.0, 0.25]])
    assert _read(plot_top_view(tmp_path / "t.png", pts[:, :2], corners, 1.2, 0.25)).std() > 10
    assert _read(plot_side_view(tmp_path / "s.png", pts[:, [0, 2]], 0.4)).std() > 10
    with pytest.raises(ValueError, match="shape"):
        plot_top_view(tmp_path / "u.png", pts[:, :2], corners[:3], 1.2, 0.25)


def test_subsample_is_deterministic_and_bounded(rng):
    pts = rng.normal(size=(MAX_SCATTER_POINTS * 3, 2))
    a, b = subsample(pts), subsample(pts)
    assert len(a) == MAX_SCATTER_POINTS and np.array_equal(a, b)
    small = pts[:100]
    assert subsample(small) is small
