"""Surface normals for the fused cloud: Open3D's PCA estimate, each flipped to face the camera nearest to its point.

A fused orbit is seen from all sides, so no single viewpoint orients every normal (the orbit's centre is
inside the truck); the camera nearest to a point is one that saw it, so facing it means facing outward.
"""

from __future__ import annotations

import numpy as np


def oriented_normals(points_xyz: np.ndarray, camera_centres: np.ndarray, radius_m: float, max_nn: int = 30) -> np.ndarray:
    """Unit normals (N, 3) of a cloud, each pointing toward the nearest camera centre.

    points_xyz: (N, 3) metres, world frame. camera_centres: (C, 3) metres, same frame (C >= 1).
    radius_m: neighbourhood radius of the plane fit (a few voxels); at most ``max_nn`` neighbours.
    Same input, same output (no randomness; the per-point fits are independent of thread order).
    """
    import open3d as o3d
    from scipy.spatial import cKDTree

    pts = np.asarray(points_xyz, dtype=np.float64)
    if len(pts) == 0:
        return np.zeros((0, 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=float(radius_m), max_nn=int(max_nn)))
    n = np.asarray(pcd.normals, dtype=np.float64)
    centres = np.asarray(camera_centres, dtype=np.float64).reshape(-1, 3)
    if len(centres):
        _, nearest = cKDTree(centres).query(pts)
        flip = np.einsum("ij,ij->i", n, centres[nearest] - pts) < 0
        n[flip] *= -1.0
    return n
