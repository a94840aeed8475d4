"""Exact renders of textured planes (boards, scenes) through a distorted pinhole camera, for tests.

Each output pixel's ray (inverse distortion, solved iteratively) is intersected with the plane and
the plane's texture is sampled there; supersampling averages several rays per pixel so edges are
anti-aliased like a real sensor's. Frames: OpenCV camera frames; a plane pose ``(R_cp, t_cp)`` maps
plane coordinates (x, y, 0) metres into the camera frame: ``X_cam = R_cp @ X_plane + t_cp``.
"""

from __future__ import annotations

import numpy as np

from calib.rig import StereoRig


def pixel_rays(K: np.ndarray, D: np.ndarray, image_size: tuple[int, int], supersample: int = 2) -> np.ndarray:
    """Normalised undistorted ray directions (S, H, W, 3) (z = 1) of each pixel's S = supersample^2 sub-samples."""
    import cv2

    w, h = image_size
    s = int(supersample)
    offs = (np.arange(s) + 0.5) / s - 0.5
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-12)  # converged to 1e-12 px at k1 = -0.2
    out = np.empty((s * s, h, w, 3))
    k = 0
    for oy in offs:
        for ox in offs:
            pts = np.stack([u + ox, v + oy], axis=-1).reshape(-1, 1, 2)
            xy = cv2.undistortPoints(pts, K, D, criteria=crit).reshape(h, w, 2)
            out[k, ..., :2] = xy
            out[k, ..., 2] = 1.0
            k += 1
    return out


def render_plane(texture: np.ndarray, tex_from_plane: np.ndarray, R_cp: np.ndarray, t_cp: np.ndarray,
                 rays: np.ndarray, background: float = 128.0) -> np.ndarray:
    """Render a textured plane seen along ``rays`` (from ``pixel_rays``); returns uint8 (H, W).

    texture: (h, w) uint8; tex_from_plane: (3,3) affine map from plane metres (x, y, 1) to texture
    pixel coordinates; R_cp, t_cp: plane-to-camera pose (metres). Pixels whose rays miss the plane
    (or hit it from behind) get ``background``.
    """
    import cv2

    R_cp = np.asarray(R_cp, dtype=np.float64)
    t_cp = np.asarray(t_cp, dtype=np.float64).reshape(3)
    n = R_cp[:, 2]
    acc = np.zeros(rays.shape[1:3], np.float64)
    tex = texture.astype(np.float32)
    for r in rays:
        denom = r @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (n @ t_cp) / denom
        X = r * s[..., None] - t_cp
        P = X @ R_cp  # = R_cp.T @ (X - t) per pixel: plane coordinates
        m = tex_from_plane
        mx = (m[0, 0] * P[..., 0] + m[0, 1] * P[..., 1] + m[0, 2]).astype(np.float32)
        my = (m[1, 0] * P[..., 0] + m[1, 1] * P[..., 1] + m[1, 2]).astype(np.float32)
        bad = ~np.isfinite(s) | (s <= 0)
        mx[bad] = -1e6
        my[bad] = -1e6
        img = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=float(background))
        acc += img
    return np.clip(np.rint(acc / len(rays)), 0, 255).astype(np.uint8)


def render_stereo_plane(rig: StereoRig, texture: np.ndarray, tex_from_plane: np.ndarray, R_cp: np.ndarray,
                        t_cp: np.ndarray, rays: tuple[np.ndarray, np.ndarray] | None = None,
                        noise_sigma: float = 0.0, rng: np.random.Generator | int | None = None,
                        background: float = 128.0) -> tuple[np.ndarray, np.ndarray]:
    """Render the plane (pose given in the LEFT camera frame) into both eyes of ``rig``.

    The right eye sees it at ``R @ R_cp, R @ t_cp + T`` (X_right = R X_left + T). Optional Gaussian
    pixel noise of ``noise_sigma`` grey levels.
    """
    if rays is None:
        rays = (pixel_rays(rig.K1, rig.D1, rig.image_size), pixel_rays(rig.K2, rig.D2, rig.image_size))
    left = render_plane(texture, tex_from_plane, R_cp, t_cp, rays[0], background)
    right = render_plane(texture, tex_from_plane, rig.R @ R_cp, rig.R @ np.asarray(t_cp).reshape(3) + rig.T, rays[1],
                         background)
    if noise_sigma > 0:
        g = np.random.default_rng(rng)
        left = np.clip(left + g.normal(0, noise_sigma, left.shape), 0, 255).astype(np.uint8)
        right = np.clip(right + g.normal(0, noise_sigma, right.shape), 0, 255).astype(np.uint8)
    return left, right


def look_at_pose(center_m: np.ndarray, distance_m: float, tilt_x_rad: float, tilt_y_rad: float, roll_rad: float,
                 board_center_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plane-to-camera pose placing the plane point ``board_center_m`` (x, y) at camera point ``center_m``
    direction scaled to ``distance_m``, the plane turned by the given tilts (rad) and roll (rad)."""
    import cv2

    R = (cv2.Rodrigues(np.array([tilt_x_rad, 0.0, 0.0]))[0] @ cv2.Rodrigues(np.array([0.0, tilt_y_rad, 0.0]))[0]
         @ cv2.Rodrigues(np.array([0.0, 0.0, roll_rad]))[0])
    c = np.asarray(center_m, dtype=np.float64)
    c = c / np.linalg.norm(c) * distance_m
    pc = np.array([board_center_m[0], board_center_m[1], 0.0])
    t = c - R @ pc
    return R, t
