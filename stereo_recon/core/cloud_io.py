"""The one point-cloud writer of the project (cloud.ply of a reconstruction, test and benchmark clouds)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from stereo_recon.core.errors import InputError

# Suffixes written as text (XYZ); every other suffix (.ply, .pcd) is written binary.
_TEXT_SUFFIXES = (".xyz", ".pts")


def write_cloud(path: str | os.PathLike, points_xyz: np.ndarray, colors_rgb: np.ndarray | None = None,
                normals: np.ndarray | None = None) -> Path:
    """Write a point cloud through Open3D: binary PLY/PCD or text XYZ, by the suffix of ``path``.

    points_xyz: (N, 3) metres. colors_rgb: (N, 3) RGB in [0, 1], or uint8 0-255; None: no colours.
    normals: (N, 3) unit normals; None: none. Raises InputError naming the file when it cannot be written.
    """
    import open3d as o3d

    path = Path(path)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points_xyz, dtype=np.float64)))
    if colors_rgb is not None and len(colors_rgb):
        c = np.asarray(colors_rgb)
        c = c / 255.0 if c.dtype == np.uint8 else c
        pcd.colors = o3d.utility.Vector3dVector(np.asarray(c, dtype=np.float64))
    if normals is not None and len(normals):
        pcd.normals = o3d.utility.Vector3dVector(np.asarray(normals, dtype=np.float64))
    if not o3d.io.write_point_cloud(str(path), pcd, write_ascii=path.suffix.lower() in _TEXT_SUFFIXES):
        raise InputError(f"{path}: could not write point cloud")
    return path
