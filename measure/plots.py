"""PNG plots for a measurement report: axis densities (paper Figs. 5-6), top view, side view.

Uses matplotlib's object-oriented API on the Agg canvas (no pyplot, no display, no global
state), so it works headless and from worker processes. Large point sets are subsampled
deterministically so each plot takes well under a second at 10^6 points. Every file is
written to a temporary sibling and renamed into place, so a plot is never half-written.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from stereo_recon.core.atomic import write_atomic

log = logging.getLogger(__name__)

# Most points drawn in a scatter; beyond that a plot shows a fixed random subset (seed 0).
MAX_SCATTER_POINTS = 40_000
# Histogram bins for samples in a density plot.
HIST_BINS = 120
DPI = 110

_HIST_COLOUR = "#c6dbef"
_KDE_COLOUR = "#08519c"
_PEAK_COLOUR = "#cb181d"
_MARKER_COLOURS = ("#238b45", "#6a51a3", "#d94801", "#525252")
_POINT_COLOUR = "#4a4a4a"
_BOX_COLOUR = "#cb181d"


def _new_figure(width_in: float = 8.0, height_in: float = 4.5) -> Figure:
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _height_for_aspect(width_in: float, span_x_m: float, span_y_m: float) -> float:
    """Figure height (inches) that fits an equal-aspect plot of the given data spans without wasted space."""
    plot_w = width_in - 2.6  # room for the axis labels and the legend on the right
    h = plot_w * max(span_y_m, 1e-9) / max(span_x_m, 1e-9) + 1.3
    return float(np.clip(h, 2.4, 7.0))


def _save_atomic(fig: Figure, path: str | os.PathLike) -> Path:
    """Render ``fig`` to PNG at ``path`` atomically (:func:`stereo_recon.core.atomic.write_atomic`)."""
    return write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=DPI), suffix=".png")


def subsample(points: np.ndarray, max_points: int = MAX_SCATTER_POINTS, seed: int = 0) -> np.ndarray:
    """A deterministic random subset of at most ``max_points`` rows (all rows, in order, if fewer)."""
    n = len(points)
    if n <= max_points:
        return points
    idx = np.random.default_rng(seed).choice(n, size=max_points, replace=False)
    idx.sort()
    return points[idx]


def _finite_rows(a, cols: int, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.size == 0:
        return np.empty((0, cols))
    if arr.ndim != 2 or arr.shape[1] < cols:
        raise ValueError(f"{name} must have shape (N, {cols}), got {arr.shape}")
    arr = arr[:, :cols]
    return arr[np.isfinite(arr).all(axis=1)]


def plot_density(
    path: str | os.PathLike,
    axis_name: str,
    grid_m,
    density,
    samples_m=None,
    peaks_m: Sequence[float] = (),
    markers_m: Mapping[str, float] | None = None,
    title: str = "",
    units: str = "m",
    facing_density=None,
) -> Path:
    """Density of point positions along one truck axis, like the paper's Figs. 5-6.

    path: PNG file to write.
    axis_name: e.g. "width" or "length" (used in the axis label).
    grid_m, density: (G,) positions along the axis (m) and the KDE values there (1/m).
    samples_m: optional (N,) positions whose histogram is drawn as light bars (normalised
        to a density, so it shares the KDE's scale).
    peaks_m: positions of the detected peaks (red dashed lines, values in the legend);
        with exactly two peaks their distance is drawn as a double arrow.
    markers_m: other labelled positions, e.g. {"front extreme": 7.93}.
    units: how the axis labels name the unit, e.g. "m, real size = model x 16" for a scaled model.
    facing_density: optional (G,) density of the points facing along the axis (the walls' own points),
        on the same grid and scale, which placed the surfaces; drawn dashed.
    """
    grid = np.asarray(grid_m, dtype=float).ravel()
    dens = np.asarray(density, dtype=float).ravel()
    if grid.shape != dens.shape:
        raise ValueError(f"grid_m and density differ in length: {grid.size} vs {dens.size}")
    fig = _new_figure(9.0, 4.5)
    ax = fig.add_subplot()
    kde_max = float(np.nanmax(dens)) if dens.size and np.isfinite(dens).any() else 0.0
    ymax = kde_max
    if samples_m is not None:
        s = np.asarray(samples_m, dtype=float).ravel()
        s = s[np.isfinite(s)]
        if s.size:
            # bins over the KDE's grid (stray samples far outside would make the bins useless),
            # normalised by ALL samples so the bars share the KDE's scale
            lo, hi = (float(grid.min()), float(grid.max())) if grid.size > 1 else (float(s.min()), float(s.max()))
            if hi <= lo:
                lo, hi = lo - 0.5e-6, hi + 0.5e-6
            counts, edges = np.histogram(s, bins=HIST_BINS, range=(lo, hi))
            hist = counts / (s.size * (edges[1] - edges[0]))
            ax.stairs(hist, edges, fill=True, color=_HIST_COLOUR, label=f"histogram ({s.size:,} points)")
            hist_max = float(hist.max())
            # a thin wall makes one tall bin; do not let it squash the KDE curve (bars are cut instead)
            ymax = max(ymax, min(hist_max, 1.6 * kde_max)) if kde_max > 0 else hist_max
    if grid.size:
        ax.plot(grid, dens, color=_KDE_COLOUR, lw=1.8, label="KDE")
    if facing_density is not None and grid.size:
        ax.plot(grid, np.asarray(facing_density, dtype=float).ravel(), color=_KDE_COLOUR, lw=1.2, ls="--",
                label="KDE of the facing points")
    if ymax <= 0:
        ymax = 1.0
    top = ymax * 1.18
    peaks = [float(p) for p in peaks_m if p is not None and np.isfinite(p)]
    peak_label = "peaks (" + ", ".join(f"{p:.3f}" for p in peaks) + " m)" if len(peaks) <= 4 else f"{len(peaks)} peaks"
    for i, p in enumerate(peaks):
        ax.axvline(p, color=_PEAK_COLOUR, ls="--", lw=1.2, label=peak_label if i == 0 else None)
    if len(peaks) == 2:
        a, b = sorted(peaks)
        y = ymax * 1.06
        ax.annotate("", xy=(a, y), xytext=(b, y), arrowprops=dict(arrowstyle="<->", color=_PEAK_COLOUR, lw=1.2))
        ax.text((a + b) / 2, y, f"{b - a:.3f} m", ha="center", va="bottom", fontsize=9, color=_PEAK_COLOUR,
                bbox=dict(facecolor="white", edgecolor="none", pad=1.0))
    for i, (label, pos) in enumerate((markers_m or {}).items()):
        if pos is None or not np.isfinite(pos):
            continue
        colour = _MARKER_COLOURS[i % len(_MARKER_COLOURS)]
        ax.axvline(float(pos), color=colour, ls=":", lw=1.5, label=f"{label} ({float(pos):.3f} m)")
    ax.set_ylim(0, top)
    ax.set_xlabel(f"position along the {axis_name} axis ({units})")
    ax.set_ylabel("density (1/m)")
    ax.set_title(title or f"{axis_name} density")
    ax.grid(alpha=0.3)
    # outside the axes: peaks sit near the edges of the range, where a legend inside would hide them
    fig.legend(loc="outside right upper", fontsize=8, framealpha=0.9)
    return _save_atomic(fig, path)


def _annotate_edge(ax, p: np.ndarray, q: np.ndarray, centre: np.ndarray, text: str, offset_m: float) -> None:
    """Double arrow parallel to edge p-q, pushed outward from ``centre`` by ``offset_m``, with a label."""
    mid = (p + q) / 2
    out = mid - centre
    n = np.linalg.norm(out)
    out = out / n if n > 0 else np.array([0.0, 1.0])
    a, b = p + out * offset_m, q + out * offset_m
    ax.annotate("", xy=tuple(a), xytext=tuple(b), arrowprops=dict(arrowstyle="<->", color=_BOX_COLOUR, lw=1.2))
    m = (a + b) / 2 + out * offset_m * 1.1
    # write along the edge (the axes have equal aspect, so data angles are screen angles)
    angle = float(np.degrees(np.arctan2(q[1] - p[1], q[0] - p[0])))
    angle = (angle + 90.0) % 180.0 - 90.0
    ax.text(m[0], m[1], text, ha="center", va="center", rotation=angle, rotation_mode="anchor", fontsize=10,
            color=_BOX_COLOUR, bbox=dict(facecolor="white", edgecolor="none", alpha=0.85, pad=1.0))


def _finish_view(fig, ax, path, title: str, xlabel: str, ylabel: str) -> Path:
    """Equal axes, labels, title, grid and the legend outside the plot; saved atomically to ``path``."""
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.legend(loc="outside right upper", fontsize=8, markerscale=8, framealpha=0.9)
    return _save_atomic(fig, path)


def plot_top_view(path: str | os.PathLike, xy_m, rect_corners_xy_m, length_m: float, width_m: float,
                  units: str = "m") -> Path:
    """Top view: truck points projected on the ground, the fitted rectangle, length and width.

    xy_m: (N, 2) ground-plane coordinates (m) of the truck's points.
    rect_corners_xy_m: (4, 2) corners of the fitted rectangle in order around it (m).
    length_m, width_m: the reported dimensions (annotated on the long and short edges).
    """
    pts = subsample(_finite_rows(xy_m, 2, "xy_m"))
    corners = np.asarray(rect_corners_xy_m, dtype=float)
    if corners.shape != (4, 2):
        raise ValueError(f"rect_corners_xy_m must have shape (4, 2), got {corners.shape}")
    extent = np.vstack([corners, pts]) if len(pts) else corners
    fig = _new_figure(9.0, _height_for_aspect(9.0, *(np.ptp(extent, axis=0) + 0.1 * np.ptp(extent, axis=0).min() + 1e-9)))
    ax = fig.add_subplot()
    if len(pts):
        ax.scatter(pts[:, 0], pts[:, 1], s=0.6, c=_POINT_COLOUR, alpha=0.5, linewidths=0, rasterized=True,
                   label="truck points" + (" (subsampled)" if len(pts) == MAX_SCATTER_POINTS else ""))
    closed = np.vstack([corners, corners[:1]])
    ax.plot(closed[:, 0], closed[:, 1], color=_BOX_COLOUR, lw=1.8, label="fitted rectangle")
    centre = corners.mean(axis=0)
    e01 = np.linalg.norm(corners[1] - corners[0])
    e12 = np.linalg.norm(corners[2] - corners[1])
    long_edge, short_edge = ((corners[0], corners[1]), (corners[1], corners[2])) if e01 >= e12 else ((corners[1], corners[2]), (corners[0], corners[1]))
    offset = 0.12 * max(min(e01, e12), 1e-6)
    _annotate_edge(ax, *long_edge, centre, f"length {length_m:.3f} m", offset)
    _annotate_edge(ax, *short_edge, centre, f"width {width_m:.3f} m", offset)
    # room around the box for the dimension arrows and their labels
    lo, hi = extent.min(axis=0) - 3.5 * offset, extent.max(axis=0) + 3.5 * offset
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    return _finish_view(fig, ax, path, "top view (ground plane)", f"x ({units})", f"y ({units})")


def plot_side_view(path: str | os.PathLike, xz_m, height_m: float, units: str = "m") -> Path:
    """Side view: truck points (along-length coordinate vs height above ground), ground line, height.

    xz_m: (N, 2) coordinates (m): position along the truck's length axis and height above
        the fitted ground plane (z = 0 is the ground).
    height_m: the reported height (drawn as a line and a double arrow from the ground).
    """
    pts = subsample(_finite_rows(xz_m, 2, "xz_m"))
    if len(pts):
        x0, x1 = float(pts[:, 0].min()), float(pts[:, 0].max())
    else:
        x0, x1 = 0.0, max(float(height_m), 1.0)
    span = max(x1 - x0, float(height_m), 1e-6)
    pad = 0.08 * span
    fig = _new_figure(9.0, _height_for_aspect(9.0, x1 - x0 + 3.2 * pad, float(height_m) + 2.5 * pad))
    ax = fig.add_subplot()
    if len(pts):
        ax.scatter(pts[:, 0], pts[:, 1], s=0.6, c=_POINT_COLOUR, alpha=0.5, linewidths=0, rasterized=True,
                   label="truck points" + (" (subsampled)" if len(pts) == MAX_SCATTER_POINTS else ""))
    ax.axhline(0.0, color="#8c6d31", lw=2.0, label="ground (z = 0)")
    ax.axhline(float(height_m), color=_BOX_COLOUR, ls="--", lw=1.4, label=f"height {height_m:.3f} m")
    xa = x1 + pad * 0.6
    ax.annotate("", xy=(xa, 0.0), xytext=(xa, float(height_m)), arrowprops=dict(arrowstyle="<->", color=_BOX_COLOUR, lw=1.2))
    ax.text(xa + pad * 0.2, float(height_m) / 2, f"{height_m:.3f} m", rotation=90, ha="left", va="center",
            fontsize=10, color=_BOX_COLOUR)
    ax.set_xlim(x0 - pad, x1 + 2.2 * pad)
    ax.set_ylim(-pad, float(height_m) + pad * 1.5)
    return _finish_view(fig, ax, path, "side view", f"along the length axis ({units})", f"height above ground ({units})")
