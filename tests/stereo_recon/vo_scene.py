"""A small textured synthetic scene rendered with Open3D ray casting, for pose tests and benchmarks.

Ground plane (world z = 0, z up) with a box "truck" and a few boxes; a solid 3-D value-noise
texture (so every surface has corners); a rectified pinhole left camera on a circular orbit.
Returns images, z-depth maps and exact world-from-camera poses (OpenCV camera axes).
"""

from __future__ import annotations

import numpy as np


_TEX_CACHE: dict = {}
_DIR_CACHE: dict = {}


def _noise_image(seed: int, size: int = 2048) -> np.ndarray:
    """Tileable multi-octave noise image in [0, 1] (float32, size x size), cached per seed."""
    import cv2

    if seed not in _TEX_CACHE:
        rng = np.random.default_rng(seed)
        img = np.zeros((size, size), np.float32)
        for cells, amp in ((24, 0.45), (80, 0.3), (256, 0.25)):
            small = rng.random((cells, cells)).astype(np.float32)
            # Wrap-pad so the cubic upsampling tiles seamlessly.
            pad = np.pad(small, 2, mode="wrap")
            up = cv2.resize(pad, None, fx=size / cells, fy=size / cells, interpolation=cv2.INTER_CUBIC)
            o = int(round(2 * size / cells))
            img += amp * up[o:o + size, o:o + size]
        img = (img - img.mean()) / (img.std() + 1e-9)
        _TEX_CACHE[seed] = np.clip(0.5 + 0.22 * img, 0, 1).astype(np.float32)
    return _TEX_CACHE[seed]


def texture(p: np.ndarray, normal: np.ndarray, seed: int = 0, texel_m: float = 0.01) -> np.ndarray:
    """Grey level in [0, 255] of world points p (N,3) with unit normals (N,3).

    A tiled 2-D noise image projected along each surface's dominant normal axis (a solid-looking
    texture with corners at every scale), times a Lambertian-like shade per face orientation.
    """
    import cv2

    tex = _noise_image(seed)
    axis = np.argmax(np.abs(normal), axis=1)
    ab = np.where(axis[:, None] == 0, p[:, [1, 2]], np.where(axis[:, None] == 1, p[:, [0, 2]], p[:, [0, 1]]))
    ab = ab + 1.37 * axis[:, None]  # decorrelate the three projections
    n, cols = len(p), 1024
    rows = -(-n // cols)
    uv = np.zeros((rows * cols, 2), np.float32)
    uv[:n] = np.mod(ab / texel_m, tex.shape[0])  # remap maps must stay below 32767 per side
    mx, my = uv[:, 0].reshape(rows, cols), uv[:, 1].reshape(rows, cols)
    v = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).reshape(-1)[:n].astype(np.float64)
    shade = 0.75 + 0.25 * np.abs(normal @ np.array([0.3, -0.4, 0.87]))
    return np.clip(255 * v * shade, 0, 255)


def build_scene(seed: int = 0):
    """Open3D RaycastingScene with the ground and boxes (metres, z up)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    rng = np.random.default_rng(seed)
    ground = o3d.geometry.TriangleMesh.create_box(16.0, 16.0, 0.1).translate((-8.0, -8.0, -0.1))
    boxes = [ground, o3d.geometry.TriangleMesh.create_box(2.5, 1.0, 1.0).translate((-1.25, -0.5, 0.0))]
    for k in range(5):
        a = 2 * np.pi * k / 5 + rng.uniform(0, 0.5)
        r = rng.uniform(1.6, 2.4)
        s = rng.uniform(0.3, 0.6, 3)
        boxes.append(o3d.geometry.TriangleMesh.create_box(*s).translate((r * np.cos(a), r * np.sin(a), 0.0)))
    for m in boxes:
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
    return scene


def orbit_poses(n: int, radius_m: float = 4.0, height_m: float = 2.5, target=(0.0, 0.0, 0.3),
                arc_deg: float = 360.0, wobble_m: float = 0.15) -> np.ndarray:
    """(n,4,4) world-from-camera poses on a circle looking at target (OpenCV axes, y down)."""
    T = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        th = np.radians(arc_deg) * k / n
        c = np.array([radius_m * np.cos(th), radius_m * np.sin(th), height_m + wobble_m * np.sin(3 * th)])
        z = np.asarray(target) - c
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        T[k, :3, :3] = np.column_stack([x, y, z])
        T[k, :3, 3] = c
    return T


def render(scene, K: np.ndarray, size: tuple[int, int], T_wc: np.ndarray, supersample: int = 2, seed: int = 0):
    """Grey image (H,W) uint8 and z-depth (H,W) float32 metres (NaN where no hit) of one view."""
    import open3d as o3d

    w, h = size

    def cast(ss):
        key = (ss, w, h, *np.round(K.ravel(), 9))
        if key not in _DIR_CACHE:
            u, v = np.meshgrid((np.arange(w * ss) + 0.5) / ss - 0.5, (np.arange(h * ss) + 0.5) / ss - 0.5)
            _DIR_CACHE[key] = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)],
                                       -1).reshape(-1, 3).astype(np.float32)
        d = _DIR_CACHE[key]
        rays = np.empty((len(d), 6), np.float32)
        rays[:, :3] = T_wc[:3, 3]
        rays[:, 3:] = d @ T_wc[:3, :3].T.astype(np.float32)
        ans = scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy()  # along d whose z is 1: the z-depth
        return t, rays[:, :3] + t[:, None] * rays[:, 3:], ans["primitive_normals"].numpy()

    t, p, nrm = cast(supersample)
    hit = np.isfinite(t)
    g = np.zeros(len(t), np.float32)
    g[hit] = texture(p[hit].astype(np.float64), nrm[hit].astype(np.float64), seed)
    img = g.reshape(h, supersample, w, supersample).mean(axis=(1, 3))
    t1 = t if supersample == 1 else cast(1)[0]
    depth = np.where(np.isfinite(t1), t1, np.nan).reshape(h, w).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), depth


def render_orbit(n: int = 60, size=(320, 240), f_px: float = 260.0, seed: int = 0, supersample: int = 2,
                 baseline_m: float | None = None, **orbit_kw):
    """(K, images list, depths list, T_wc (n,4,4)) of an orbit; with baseline_m also the right eye's
    images (rectified pair, right eye baseline_m along the left camera's +x) as a fifth item."""
    w, h = size
    K = np.array([[f_px, 0, (w - 1) / 2], [0, f_px, (h - 1) / 2], [0, 0, 1.0]])
    scene = build_scene(seed)
    T = orbit_poses(n, **orbit_kw)
    imgs, depths, rights = [], [], []
    for Tk in T:
        im, d = render(scene, K, size, Tk, supersample=supersample, seed=seed)
        imgs.append(im)
        depths.append(d)
        if baseline_m is not None:
            Tr = Tk.copy()
            Tr[:3, 3] = Tk[:3, 3] + baseline_m * Tk[:3, 0]
            rights.append(render(scene, K, size, Tr, supersample=supersample, seed=seed)[0])
    if baseline_m is not None:
        return K, imgs, depths, T, rights
    return K, imgs, depths, T
