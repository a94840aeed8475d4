"""Point-cloud resolution: the median nearest-neighbour spacing (metres)."""

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
