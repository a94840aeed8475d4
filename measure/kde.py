"""Gaussian kernel density estimates on a binned grid (FFT), with the LSCV bandwidth of Eq. 8.

Binning the samples onto a fine regular grid (linear binning) makes both the density and the
cross-validation score cost O(M log M) in the number of bins M instead of O(n²) in the samples,
so 10⁶ projections take milliseconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import fftconvolve


@dataclass(frozen=True)
class Density:
    """A density on a regular grid: ``grid_m`` (M,) positions, ``density`` (M,) per metre, and its bandwidth."""

    grid_m: np.ndarray
    density: np.ndarray
    bandwidth_m: float
    n: int

    @property
    def step_m(self) -> float:
        return float(self.grid_m[1] - self.grid_m[0]) if len(self.grid_m) > 1 else 0.0


def linear_binning(x: np.ndarray, lo: float, step: float, n_bins: int, weights: np.ndarray | None = None) -> np.ndarray:
    """Counts on the grid lo + k*step (k = 0..n_bins-1), each sample split between its two nearest nodes."""
    t = (np.asarray(x, dtype=np.float64) - lo) / step
    k = np.clip(np.floor(t).astype(np.int64), 0, n_bins - 2)
    f = np.clip(t - k, 0.0, 1.0)
    w = np.ones(len(t)) if weights is None else np.asarray(weights, dtype=np.float64)
    c = np.bincount(k, weights=w * (1.0 - f), minlength=n_bins)
    c += np.bincount(k + 1, weights=w * f, minlength=n_bins)
    return c[:n_bins]


def _gauss(x: np.ndarray, s: float) -> np.ndarray:
    return np.exp(-0.5 * (x / s) ** 2) / (s * np.sqrt(2 * np.pi))


def lscv_bandwidth(counts: np.ndarray, step: float, h_min: float, h_max: float, n_candidates: int = 48) -> tuple[float, dict]:
    """Least-squares cross-validation bandwidth (Eq. 8) for a Gaussian kernel on binned data.

    CV(h) = 1/n² ΣΣ (K⋆K)_h(X_j − X_i) − 2/(n(n−1)) Σ_{i≠j} K_h(X_i − X_j); for a Gaussian K,
    K⋆K is a Gaussian of standard deviation √2·h. With binned counts c the double sums become
    Σ_m A(m)·f(m·step), where A is the autocorrelation of c (computed once by FFT), and the
    i = j terms are removed as n·f(0). Minimised over log-spaced candidates in [h_min, h_max].
    Returns (h, {"candidates_m", "cv"}).
    """
    c = np.asarray(counts, dtype=np.float64)
    n = float(c.sum())
    if n < 3:
        return float(h_max), {"candidates_m": [], "cv": []}
    h_min = max(float(h_min), 1e-12)
    h_max = max(float(h_max), h_min * 1.0001)
    # Lags beyond 6·√2·h_max contribute nothing.
    max_lag = int(min(len(c) - 1, np.ceil(6 * np.sqrt(2) * h_max / step)))
    ac = fftconvolve(c, c[::-1], mode="full")[len(c) - 1 : len(c) + max_lag]
    ac = np.maximum(ac, 0.0)
    lags = np.arange(max_lag + 1) * step
    wts = np.where(np.arange(max_lag + 1) == 0, 1.0, 2.0)  # ±m
    a = ac * wts
    hs = np.geomspace(h_min, h_max, n_candidates)
    cv = np.empty(len(hs))
    for i, h in enumerate(hs):
        term1 = float(a @ _gauss(lags, np.sqrt(2) * h)) / n**2
        term2 = (float(a @ _gauss(lags, h)) - n * _gauss(np.zeros(1), h)[0]) * 2 / (n * (n - 1))
        cv[i] = term1 - term2
    i = int(np.argmin(cv))
    return float(hs[i]), {"candidates_m": hs, "cv": cv}


def binned_kde(x: np.ndarray, bandwidth_m: float | None = None, step_m: float | None = None, h_range_m: tuple[float, float] | None = None,
               max_bins: int = 1 << 14, pad_bw: float = 4.0, counts_override: np.ndarray | None = None, grid_lo: float | None = None) -> Density:
    """Gaussian KDE of 1-D samples on a regular grid.

    x: (n,) samples, metres. bandwidth_m: None => LSCV (Eq. 8) over ``h_range_m`` (default from
    the grid step to a quarter of the sample range). step_m: grid step (default range/4096,
    capped at ``max_bins`` bins). Returns a :class:`Density` (integrates to 1).
    """
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    if n == 0:
        raise ValueError("no samples")
    lo_x, hi_x = float(x.min()), float(x.max())
    span = max(hi_x - lo_x, 1e-9)
    if step_m is None:
        step_m = span / 4096
    h_hi = h_range_m[1] if h_range_m else span / 4
    pad = pad_bw * (bandwidth_m if bandwidth_m else h_hi)
    n_bins = int(np.ceil((span + 2 * pad) / step_m)) + 2
    if n_bins > max_bins:
        step_m = (span + 2 * pad) / (max_bins - 2)
        n_bins = max_bins
    lo = (lo_x - pad) if grid_lo is None else grid_lo
    counts = linear_binning(x, lo, step_m, n_bins) if counts_override is None else counts_override
    if bandwidth_m is None:
        h_lo = h_range_m[0] if h_range_m else 2 * step_m
        bandwidth_m, _ = lscv_bandwidth(counts, step_m, max(h_lo, step_m), h_hi)
    dens = smooth_counts(counts, step_m, bandwidth_m)
    grid = lo + step_m * np.arange(n_bins)
    return Density(grid, dens, float(bandwidth_m), n)


def smooth_counts(counts: np.ndarray, step_m: float, bandwidth_m: float) -> np.ndarray:
    """Binned counts convolved with a Gaussian of ``bandwidth_m``; normalised to a density per metre."""
    half = int(np.ceil(5 * bandwidth_m / step_m))
    half = min(half, len(counts))
    k = _gauss(np.arange(-half, half + 1) * step_m, bandwidth_m)
    dens = fftconvolve(counts, k, mode="same")
    dens = np.maximum(dens, 0.0)
    total = counts.sum()
    return dens / total if total > 0 else dens


def kde_standard_error(density: np.ndarray, n: float, bandwidth_m: float) -> np.ndarray:
    """Sampling standard error (1/m) of a Gaussian KDE of n points at bandwidth_m (m) where it reads density
    (1/m, normalised): sqrt(f R(K) / (n h)), R(K) = 1 / (2 sqrt(pi)) for a Gaussian kernel."""
    return np.sqrt(np.asarray(density) / (2 * np.sqrt(np.pi) * max(float(n), 1.0) * bandwidth_m))


def local_maxima(density: np.ndarray, min_rel: float = 0.0) -> np.ndarray:
    """Indices of strict-or-plateau local maxima of a 1-D array with value >= min_rel * max."""
    d = np.asarray(density)
    if len(d) < 3:
        return np.array([int(np.argmax(d))]) if len(d) else np.zeros(0, dtype=int)
    left = np.r_[-np.inf, d[:-1]]
    right = np.r_[d[1:], -np.inf]
    idx = np.flatnonzero((d > left) & (d >= right))
    return idx[d[idx] >= min_rel * d.max()]


def refine_peak(grid: np.ndarray, density: np.ndarray, i: int) -> float:
    """Sub-bin peak position by a parabola through the peak bin and its neighbours."""
    if 0 < i < len(density) - 1:
        y0, y1, y2 = density[i - 1], density[i], density[i + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            off = 0.5 * (y0 - y2) / den
            return float(grid[i] + np.clip(off, -1, 1) * (grid[1] - grid[0]))
    return float(grid[i])
