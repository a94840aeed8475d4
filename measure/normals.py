"""Local plane fits of a point cloud: each point's k nearest neighbours' covariance, and the normals from it.

Written here rather than taken from Open3D's ``estimate_normals`` so that the measure layer stays on
numpy/scipy and the result is the same on every thread count. Used by the ground's initial normal
(``measure.ground``) and by the walls' and roof's facing points (``measure.dimensions``).
"""

from __future__ import annotations

import numpy as np


def local_pca(xyz: np.ndarray, k: int, chunk: int = 100_000) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (N, 3, ascending, m²) and eigenvectors (N, 3, 3; column j belongs to value j) of the
    covariance of each point's k nearest neighbours (itself included) in the points xyz (N, 3, m).

    Processed ``chunk`` points at a time to bound memory; the result does not depend on it.
    """
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, dtype=np.float64)
    tree = cKDTree(xyz)
    w = np.empty((len(xyz), 3))
    v = np.empty((len(xyz), 3, 3))
    for s0 in range(0, len(xyz), chunk):
        _, idx = tree.query(xyz[s0:s0 + chunk], k=k)
        nb = xyz[idx] - xyz[idx].mean(axis=1, keepdims=True)
        w[s0:s0 + chunk], v[s0:s0 + chunk] = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    return w, v


def point_normals(xyz: np.ndarray, k: int = 16) -> np.ndarray:
    """Unit surface normals (N, 3) from a plane fit to each point's k nearest neighbours (sign arbitrary).

    xyz: (N, 3) points (m). A k-neighbour fit is scale-free (no radius to choose) and deterministic.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    return local_pca(xyz, int(min(max(k, 3), len(xyz))))[1][:, :, 0]
