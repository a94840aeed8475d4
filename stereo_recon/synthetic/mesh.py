"""Triangle-mesh primitives for the synthetic scenes (boxes, prisms, cones) with per-triangle materials.

All meshes are plain numpy arrays: vertices (N, 3) float64 metres, triangles (M, 3) int32, and one
material name per triangle. Winding is not relied upon: the renderer orients normals toward the ray.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Mesh:
    """A triangle soup with one material name per triangle.

    vertices: (N, 3) float64, metres, in the frame the mesh was built in.
    triangles: (M, 3) int32 vertex indices.
    materials: list of M material names (keys into the scene's material table).
    """

    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int32))
    materials: list[str] = field(default_factory=list)

    def extend(self, other: "Mesh") -> "Mesh":
        """Append ``other`` in place (vertex indices shifted); returns self."""
        off = len(self.vertices)
        self.vertices = np.vstack([self.vertices, other.vertices])
        self.triangles = np.vstack([self.triangles, other.triangles + off]).astype(np.int32)
        self.materials = self.materials + list(other.materials)
        return self

    def transformed(self, T: np.ndarray) -> "Mesh":
        """A copy with vertices mapped by the 4x4 rigid transform ``T`` (X' = R X + t)."""
        T = np.asarray(T, float)
        return Mesh(self.vertices @ T[:3, :3].T + T[:3, 3], self.triangles.copy(), list(self.materials))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min xyz, max xyz) of the vertices, metres."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)


# Faces of the unit box as quads over the corner indices (bit 0: x, bit 1: y, bit 2: z).
_BOX_QUADS = ((0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5))


def box(lo, hi, material: str, top_material: str | None = None) -> Mesh:
    """Axis-aligned box between corners ``lo`` and ``hi`` (metres); optional different top face material."""
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    if np.any(hi <= lo):
        raise ValueError(f"box: empty extent lo={lo} hi={hi}")
    corners = np.array([[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]] for i in range(8)])
    tris, mats = [], []
    for qi, (a, b, c, d) in enumerate(_BOX_QUADS):
        tris += [(a, b, c), (a, c, d)]
        m = top_material if (qi == 1 and top_material) else material
        mats += [m, m]
    return Mesh(corners, np.array(tris, np.int32), mats)


def prism_y(profile_xz: np.ndarray, y0: float, y1: float, material: str, cap_material: str | None = None) -> Mesh:
    """Extrude a convex polygon in the x-z plane along y from ``y0`` to ``y1`` (a wheel, a cab profile).

    profile_xz: (K, 2) convex polygon vertices in order, metres.
    """
    p = np.asarray(profile_xz, float)
    k = len(p)
    v = np.vstack([np.c_[p[:, 0], np.full(k, y0), p[:, 1]], np.c_[p[:, 0], np.full(k, y1), p[:, 1]]])
    tris, mats = [], []
    for i in range(k):
        j = (i + 1) % k
        tris += [(i, j, k + j), (i, k + j, k + i)]
        mats += [material, material]
    cap = cap_material or material
    for i in range(1, k - 1):  # fan triangulation of both convex caps
        tris += [(0, i, i + 1), (k, k + i + 1, k + i)]
        mats += [cap, cap]
    return Mesh(v, np.array(tris, np.int32), mats)


def prism_x(profile_yz: np.ndarray, x0: float, x1: float, material: str, cap_material: str | None = None) -> Mesh:
    """Extrude a convex polygon in the y-z plane along x from ``x0`` to ``x1`` (a tank's cross-section).

    profile_yz: (K, 2) convex polygon vertices in order, metres.
    """
    p = np.asarray(profile_yz, float)
    m = prism_y(p, x0, x1, material, cap_material)  # built with (x, y, z) = (y', x', z'): swap the first two axes
    m.vertices = m.vertices[:, [1, 0, 2]]
    return m


def elliptic_cylinder_x(centre_yz, half_width_m: float, half_height_m: float, x0: float, x1: float, material: str,
                        cap_material: str | None = None, segments: int = 24) -> Mesh:
    """Elliptic cylinder with axis along x; ``segments`` is a multiple of 4 so that vertices sit exactly at the
    four extremes (y = centre +- half_width_m, z = centre +- half_height_m): the mesh's bounds are the ellipse's."""
    if segments % 4:
        raise ValueError(f"elliptic_cylinder_x: segments must be a multiple of 4, got {segments}")
    ang = 2 * np.pi * np.arange(segments) / segments
    prof = np.c_[centre_yz[0] + half_width_m * np.cos(ang), centre_yz[1] + half_height_m * np.sin(ang)]
    return prism_x(prof, x0, x1, material, cap_material)


def cylinder_y(centre_xz, radius: float, y0: float, y1: float, material: str, cap_material: str | None = None, segments: int = 16) -> Mesh:
    """Cylinder with axis along y; a vertex sits exactly at the lowest point (z = centre - radius)."""
    ang = -np.pi / 2 + 2 * np.pi * np.arange(segments) / segments
    prof = np.c_[centre_xz[0] + radius * np.cos(ang), centre_xz[1] + radius * np.sin(ang)]
    return prism_y(prof, y0, y1, material, cap_material)


def cylinder_z(centre_xy, radius: float, z0: float, z1: float, material: str, segments: int = 12, top_radius: float | None = None) -> Mesh:
    """Upright cylinder (or truncated cone with ``top_radius``; 0 gives a cone) from z0 to z1."""
    ang = 2 * np.pi * np.arange(segments) / segments
    rt = radius if top_radius is None else top_radius
    cx, cy = centre_xy
    bot = np.c_[cx + radius * np.cos(ang), cy + radius * np.sin(ang), np.full(segments, z0)]
    top = np.c_[cx + rt * np.cos(ang), cy + rt * np.sin(ang), np.full(segments, z1)]
    v = np.vstack([bot, top, [[cx, cy, z0], [cx, cy, z1]]])
    k = segments
    tris = []
    for i in range(k):
        j = (i + 1) % k
        tris += [(i, j, k + j), (i, k + j, k + i), (2 * k, j, i), (2 * k + 1, k + i, k + j)]
    return Mesh(v, np.array(tris, np.int32), [material] * len(tris))


def quad(corners: np.ndarray, material: str) -> Mesh:
    """A planar quad from 4 corners in order (two triangles)."""
    return Mesh(np.asarray(corners, float), np.array([(0, 1, 2), (0, 2, 3)], np.int32), [material, material])


def rot_z(yaw_rad: float) -> np.ndarray:
    """3x3 rotation about +z (counter-clockwise seen from above)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose(R: np.ndarray, t) -> np.ndarray:
    """4x4 rigid transform from a rotation and a translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T
