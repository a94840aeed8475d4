"""A ZED2-like stereo rig and the exact per-pixel viewing rays of a distorted pinhole camera.

The factory-like calibration below is fictitious but has the magnitudes of a real ZED2 (HD720:
fx ~ 528 px, k1 ~ -0.04, 120 mm baseline, mrad rotations and sub-mm TY/TZ between the eyes).
"""

from __future__ import annotations

import logging
from functools import lru_cache

import cv2
import numpy as np

from stereo_recon.core.errors import ConfigError

log = logging.getLogger(__name__)

# ZED resolutions (one eye), as the factory .conf names them.
RESOLUTIONS: dict[str, tuple[int, int]] = {"2K": (2208, 1242), "FHD": (1920, 1080), "HD720": (1280, 720), "VGA": (672, 376)}
# Focal length relative to HD720 (the ZED's 2K and FHD share the full-resolution focal length).
_FOCAL_FACTOR = {"2K": 2.0, "FHD": 2.0, "HD720": 1.0, "VGA": 0.5}

SYNTH_SERIAL = 28000001  # serial number used for the synthetic rig's SN<serial>.conf

# HD720 factory-like values: (fx, fy, cx offset from centre, cy offset, k1, k2, p1, p2, k3).
_LEFT_HD = (528.47, 528.30, 6.15, 2.52, -0.0412, 0.0098, -0.00021, 0.00034, -0.0021)
_RIGHT_HD = (527.92, 527.81, 1.87, -1.23, -0.0405, 0.0093, 0.00018, -0.00027, -0.0018)
# Stereo: baseline mm, TY mm, TZ mm, RX (tilt), CV (convergence, about y), RZ (roll) rad.
_STEREO = {"baseline_mm": 119.93, "ty_mm": 0.042, "tz_mm": -0.31, "rx_rad": 0.0012, "cv_rad": 0.0021, "rz_rad": -0.00043}
# The two ZED lens families at HD720 (same layout as _LEFT_HD): the first-generation ZED / ZED Mini
# (narrower field, strong barrel distortion, k1 ~ -0.17) and the ZED2 / ZED2i (wider, k1 ~ -0.04).
LENS_FAMILIES: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "zed": ((699.8, 699.6, 3.1, -1.9, -0.1712, 0.0260, 0.00012, -0.00035, 0.0),
            (700.3, 700.1, -2.4, 1.1, -0.1695, 0.0252, -0.00020, 0.00022, 0.0)),
    "zed2": (_LEFT_HD, _RIGHT_HD),
}


def resolution_size(name: str) -> tuple[int, int]:
    """(width, height) of one eye for a ZED resolution name (2K, FHD, HD720, VGA)."""
    key = name.upper().replace("HD1080", "FHD").replace("HD2K", "2K")
    if key == "HD":
        key = "HD720"
    if key not in RESOLUTIONS:
        raise ConfigError(f"--resolution: unknown ZED resolution {name!r}; choose one of {', '.join(RESOLUTIONS)}")
    return RESOLUTIONS[key]


def _intrinsics(vals, res: str) -> tuple[np.ndarray, np.ndarray]:
    w, h = RESOLUTIONS[res]
    f = _FOCAL_FACTOR[res]
    fx, fy, dcx, dcy, k1, k2, p1, p2, k3 = vals
    # The optical-centre offset and focal length follow the pixel pitch of the resolution.
    K = np.array([[fx * f, 0.0, (w - 1) / 2 + dcx * f], [0.0, fy * f, (h - 1) / 2 + dcy * f], [0.0, 0.0, 1.0]])
    return K, np.array([k1, k2, p1, p2, k3])


def zed2_rig(resolution: str = "HD720", rectified: bool = False):
    """The synthetic ZED2's calibration as a :class:`calib.rig.StereoRig`.

    Raw mode (default): distorted eyes, R = Rodrigues([RX, CV, RZ]), T = [-B, TY, TZ] (metres),
    as a ZED factory ``.conf`` describes them. ``rectified=True``: the ideal rectified pinhole pair
    an SVO export contains (left intrinsics' focal length, centred principal point, D = 0, R = I,
    T = [-B, 0, 0]).
    """
    return stereo_rig(resolution, rectified, _LEFT_HD, _RIGHT_HD, _STEREO)


def stereo_rig(resolution: str, rectified: bool, left_hd, right_hd, stereo: dict):
    """A ZED-like rig from HD720 factory-style values, as :func:`zed2_rig` builds its own.

    left_hd / right_hd: (fx, fy, cx offset from the image centre, cy offset, k1, k2, p1, p2, k3) at HD720 (px);
    stereo: baseline_mm, ty_mm, tz_mm, rx_rad, cv_rad, rz_rad (the .conf's [STEREO] values).
    """
    from calib.rig import StereoRig

    res = {v: k for k, v in RESOLUTIONS.items()}[resolution_size(resolution)]
    size = RESOLUTIONS[res]
    K1, D1 = _intrinsics(tuple(left_hd), res)
    K2, D2 = _intrinsics(tuple(right_hd), res)
    B = stereo["baseline_mm"] / 1000.0
    meta = {"source": "stereo_recon.synthetic (ZED2-like, fictitious factory calibration)", "serial": SYNTH_SERIAL, "resolution": res}
    if rectified:
        return StereoRig.from_rectified(float(K1[0, 0]), float(K1[0, 0]), (size[0] - 1) / 2, (size[1] - 1) / 2, B, size, **meta)
    R, _ = cv2.Rodrigues(np.array([stereo["rx_rad"], stereo["cv_rad"], stereo["rz_rad"]], float))
    T = np.array([-B, stereo["ty_mm"] / 1000.0, stereo["tz_mm"] / 1000.0])
    return StereoRig(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=size, rectified=False, metadata=meta)


def _distort(x: np.ndarray, y: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's radial-tangential model (k1, k2, p1, p2, k3) on normalised coordinates."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


@lru_cache(maxsize=8)
def _rays_cached(K_bytes: bytes, D_bytes: bytes, width: int, height: int) -> np.ndarray:
    K = np.frombuffer(K_bytes, np.float64).reshape(3, 3)
    D = np.frombuffer(D_bytes, np.float64)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pts = np.stack([u.ravel(), v.ravel()], axis=1)
    d5 = np.zeros(5)
    d5[: min(5, len(D))] = D[:5]
    if np.any(D[5:] != 0):
        raise ConfigError("synthetic renderer supports the 5-coefficient (k1 k2 p1 p2 k3) distortion model only")
    # Newton from the distorted coordinates themselves (cv2.undistortPoints' few fixed-point
    # iterations can land far off near the corners); the model is monotonic over the image.
    xd_t = (pts[:, 0] - K[0, 2]) / K[0, 0]
    yd_t = (pts[:, 1] - K[1, 2]) / K[1, 1]
    x, y = xd_t.copy(), yd_t.copy()
    k1, k2, p1, p2, k3 = d5
    for _ in range(20):  # Newton on the 2x2 distortion Jacobian: quadratic convergence
        xd, yd = _distort(x, y, d5)
        ex, ey = xd - xd_t, yd - yd_t
        if max(np.abs(ex).max(), np.abs(ey).max()) * K[0, 0] < 1e-9:
            break
        r2 = x * x + y * y
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        g = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        a = rad + 2 * x * x * g + 2 * p1 * y + 6 * p2 * x
        b = 2 * x * y * g + 2 * p1 * x + 2 * p2 * y
        d = rad + 2 * y * y * g + 6 * p1 * y + 2 * p2 * x
        det = a * d - b * b
        x -= (d * ex - b * ey) / det
        y -= (a * ey - b * ex) / det
    else:
        raise ConfigError("synthetic camera: the distortion model cannot be inverted over the whole image")
    rays = np.stack([x, y, np.ones_like(x)], axis=1).astype(np.float32)
    rays.setflags(write=False)
    return rays


def pixel_rays(K: np.ndarray, D: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Viewing rays of every pixel centre, row-major: (H*W, 3) float32 camera-frame directions with z = 1.

    K: (3,3) intrinsics, px; D: OpenCV distortion (k1 k2 p1 p2 k3); image_size: (width, height).
    A ray ``t * d`` hits a surface at z-depth ``t`` (metres). Cached per camera (read-only array).
    """
    K = np.ascontiguousarray(K, np.float64)
    D = np.ascontiguousarray(np.ravel(D) if D is not None else np.zeros(5), np.float64)
    return _rays_cached(K.tobytes(), D.tobytes(), int(image_size[0]), int(image_size[1]))


def project_points(X_cam: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Project camera-frame points (N, 3) to distorted pixels (N, 2) with the same model the rays invert."""
    d5 = np.zeros(5)
    D = np.ravel(D)
    d5[: min(5, len(D))] = D[:5]
    x = X_cam[:, 0] / X_cam[:, 2]
    y = X_cam[:, 1] / X_cam[:, 2]
    xd, yd = _distort(x, y, d5)
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)
