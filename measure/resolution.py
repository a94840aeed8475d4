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


def lattice_dither(points: np.ndarray, lattice_m: float, rng=0, min_repeats: int = 3) -> np.ndarray:
    """Displacements (N, 3) that dither a fused cloud's lattice coordinates, each uniform within half a lattice step.

    points: (N, 3) metres in the frame the cloud was fused in. lattice_m: its lattice (``point_lattice``). rng: seed.
    A TSDF's points are its zero crossings along the voxel edges: two of a point's three coordinates are voxel
    planes, so a surface lying along an axis projects onto that axis as a comb with one tooth per voxel, and a
    density read finer than the voxel reads the teeth as walls and shoulders (docs/ROUNDS.md, issue 12's thirty-seventh and
    thirty-eighth rounds). Dither of one step, the standard remedy for a quantised signal, spreads each tooth over
    its own cell. The coordinate the crossing found (a wall's position across itself) is not a lattice value and
    gets none. A coordinate is a lattice value when at least min_repeats points hold it exactly and it lies a whole
    number of steps (within 0.2 %) from the planes most of those points share, so a flat face that gives many equal
    crossings off the planes is left alone. Zero rows where a point has no lattice coordinate.
    """
    p = np.asarray(points, dtype=np.float64)
    rng = np.random.default_rng(rng)
    v = float(lattice_m)
    d = np.zeros_like(p)
    for ax in range(p.shape[1]):
        u, inv, c = np.unique(p[:, ax], return_inverse=True, return_counts=True)
        held = c >= min_repeats
        if not held.any():
            continue
        # The planes' phase: the fraction of a step most of the held values' points share (the planes are many,
        # a face that happens to be held is one value).
        frac = (u / v) % 1.0
        phase = np.argmax(np.bincount(np.round(1000 * frac[held]).astype(int) % 1000, weights=c[held], minlength=1000)) / 1000
        off = (frac - phase + 0.5) % 1.0 - 0.5
        on = (held & (np.abs(off) < 2e-3))[inv]
        d[on, ax] = v * (rng.random(int(on.sum())) - 0.5)
    return d
