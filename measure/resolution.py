"""Point-cloud resolution: the median nearest-neighbour spacing, and the lattice a fused cloud sits on (metres)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def point_resolution(points: np.ndarray, sample_size: int = 20_000, rng=0, tree: cKDTree | None = None) -> float:
    """Median distance from a point to its nearest other point, on a seeded random subsample.

    points: (N, 3) metres. sample_size: how many query points (all of them when N is smaller).
    The neighbours are searched among ALL points, so the figure is the cloud's true spacing.
    Returns metres; 0.0 when more than half of the sampled points have an exact duplicate.
    """
    p = np.asarray(points, dtype=np.float64)
    if len(p) < 2:
        raise ValueError("need at least 2 points to measure the resolution")
    rng = np.random.default_rng(rng)
    idx = rng.choice(len(p), size=min(sample_size, len(p)), replace=False)
    if tree is None:
        tree = cKDTree(p, balanced_tree=False, compact_nodes=False)
    d, _ = tree.query(p[idx], k=2)
    return float(np.median(d[:, 1]))


def point_lattice(points: np.ndarray, min_repeats: int = 3, min_share: float = 0.05) -> float | None:
    """Spacing (m) of the lattice a fused cloud's points sit on, or None where they sit on none.

    A TSDF's surface points are its zero crossings along the voxel edges: two of a point's three coordinates
    are voxel-grid planes, each held exactly by many points. Per axis of the cloud's own frame: the values held
    by at least min_repeats points, where those points are at least min_share of all, and the median gap
    between consecutive such values; the median over the axes that have one. points: (N, 3) metres, in the
    frame the cloud was fused in (a rotation since spreads the planes' values).
    """
    p = np.asarray(points, dtype=np.float64)
    gaps = []
    for ax in range(p.shape[1]):
        u, c = np.unique(p[:, ax], return_counts=True)
        held = c >= min_repeats
        if held.sum() >= 3 and c[held].sum() >= min_share * len(p):
            gaps.append(float(np.median(np.diff(u[held]))))
    return float(np.median(gaps)) if gaps else None
