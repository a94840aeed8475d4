"""The stereo rig model: per-eye intrinsics and distortion, extrinsics, and rectification.

Conventions (``stereo_recon/conventions.py``): OpenCV camera frames, ``X_right = R @ X_left + T``
in metres (a right eye to the right of the left eye has ``T ~ [-B, 0, 0]``), image sizes
``(width, height)`` of ONE eye in pixels. Rectification follows ``cv2.stereoRectify`` with
``CALIB_ZERO_DISPARITY``: both rectified eyes share the focal length and principal point, so
depth is ``Z = focal_px * baseline_m / disparity_px``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stereo_recon.core.errors import InputError

log = logging.getLogger(__name__)

# Distortion vector lengths OpenCV accepts: [k1,k2,p1,p2(,k3(,k4,k5,k6(,s1..s4(,tx,ty))))].
_DIST_LENGTHS = (4, 5, 8, 12, 14)
# Two image sizes "have the same aspect" when width/height differ by less than this fraction
# (ZED's VGA 672x376 is 0.5% off 16:9; true crops differ by far more).
ASPECT_TOLERANCE = 0.01


def _as_float_array(name: str, value: Any, shape: tuple[int, ...] | None) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as err:
        raise InputError(f"rig: {name} is not numeric ({err})") from None
    if shape is not None and arr.shape != shape:
        raise InputError(f"rig: {name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"rig: {name} has non-finite values")
    arr.setflags(write=False)
    return arr


def _check_size(image_size: Any) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise InputError(f"rig: image_size must be (width, height), got {image_size!r}") from None
    if w <= 0 or h <= 0:
        raise InputError(f"rig: image_size must be positive, got {w}x{h}")
    return (w, h)


def same_aspect(a: tuple[int, int], b: tuple[int, int], tol: float = ASPECT_TOLERANCE) -> bool:
    """Whether two (width, height) sizes have the same aspect ratio within ``tol`` (relative)."""
    return abs((a[0] / a[1]) / (b[0] / b[1]) - 1.0) <= tol


def scale_K(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Camera matrix for an image resized by (sx, sy); pixel centres sit at integer coordinates."""
    K2 = np.array(K, dtype=np.float64, copy=True)
    K2[0, 0] *= sx
    K2[0, 1] *= sx
    K2[1, 1] *= sy
    # A pixel centre x maps to (x + 0.5) * s - 0.5 when the image is resized by s.
    K2[0, 2] = (K2[0, 2] + 0.5) * sx - 0.5
    K2[1, 2] = (K2[1, 2] + 0.5) * sy - 0.5
    return K2


@dataclass(frozen=True, eq=False)
class StereoRig:
    """A calibrated stereo pair.

    K1, K2: (3,3) intrinsics of the left/right eye, px. D1, D2: (k,) OpenCV distortion
    ``[k1, k2, p1, p2, k3, ...]`` (k in 4, 5, 8, 12, 14). R (3,3), T (3,) metres: the right eye's
    extrinsics, ``X_right = R @ X_left + T``. image_size: (width, height) of one eye, px.
    rectified: the frames are already rectified (pinhole, D = 0, R = I, K1 = K2, T = [-B, 0, 0]);
    rectification is then the identity. metadata: free-form (source, rms_px, date, serial, ...).
    """

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]
    rectified: bool = False
    metadata: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        # rectifications computed so far, per (alpha, map type); not a dataclass field, so
        # dataclasses.asdict / manifests never carry the remap tables
        set_(self, "_cache", {})
        set_(self, "K1", _as_float_array("K1", self.K1, (3, 3)))
        set_(self, "K2", _as_float_array("K2", self.K2, (3, 3)))
        for name in ("D1", "D2"):
            d = _as_float_array(name, self.__dict__[name], None).reshape(-1)
            if d.size == 0:
                d = np.zeros(5)
            if d.size not in _DIST_LENGTHS:
                raise InputError(f"rig: {name} must have {', '.join(map(str, _DIST_LENGTHS))} coefficients, got {d.size}")
            d = d.copy()
            d.setflags(write=False)
            set_(self, name, d)
        R = np.asarray(self.R, dtype=np.float64)
        if R.size == 3:  # a rotation vector is accepted for convenience
            import cv2

            R = cv2.Rodrigues(R.reshape(3, 1))[0]
        R = _as_float_array("R", R, (3, 3))
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise InputError("rig: R is not a rotation matrix (R @ R.T != I or det < 0)")
        set_(self, "R", R)
        set_(self, "T", _as_float_array("T", np.asarray(self.T, dtype=np.float64).reshape(-1), (3,)))
        set_(self, "image_size", _check_size(self.image_size))
        set_(self, "rectified", bool(self.rectified))
        set_(self, "metadata", dict(self.metadata or {}))
        for name, K in (("K1", self.K1), ("K2", self.K2)):
            if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1.0) > 1e-9 or np.any(K[2, :2] != 0) or K[1, 0] != 0:
                raise InputError(f"rig: {name} is not a camera matrix [[fx,s,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0")
        if self.rectified:
            B = abs(self.T[0])
            if (np.any(self.D1 != 0) or np.any(self.D2 != 0) or np.abs(self.R - np.eye(3)).max() > 1e-9
                    or np.abs(self.K1 - self.K2).max() > 1e-9 or np.abs(self.T[1:]).max() > 1e-9 * max(B, 1.0)):
                raise InputError("rig: a rig marked rectified needs D1 = D2 = 0, R = I, K1 = K2 and T = [-B, 0, 0]")

    # -- value semantics --------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, StereoRig):
            return NotImplemented
        return (self.image_size == other.image_size and self.rectified == other.rectified
                and all(np.array_equal(getattr(self, n), getattr(other, n)) for n in ("K1", "D1", "K2", "D2", "R", "T")))

    __hash__ = None  # type: ignore[assignment]  # holds arrays

    def as_dict(self) -> dict:
        """Plain lists/numbers (for JSON manifests): K1 D1 K2 D2 R T image_size rectified metadata."""
        out = {n: getattr(self, n).tolist() for n in ("K1", "D1", "K2", "D2", "R", "T")}
        out.update(image_size=list(self.image_size), rectified=self.rectified, baseline_m=self.baseline_m,
                   metadata=dict(self.metadata))
        return out

    @property
    def baseline_m(self) -> float:
        """Distance between the eyes' centres, metres (|T|)."""
        return float(np.linalg.norm(self.T))

    def replace(self, **changes: Any) -> "StereoRig":
        """A copy with some fields changed (metadata is kept unless given)."""
        kw = {n: getattr(self, n) for n in ("K1", "D1", "K2", "D2", "R", "T", "image_size", "rectified", "metadata")}
        kw.update(changes)
        return StereoRig(**kw)

    # -- resolution ---------------------------------------------------------------------------
    def scaled(self, image_size: tuple[int, int]) -> "StereoRig":
        """The same rig for frames resized to ``image_size`` (width, height); the aspect must match.

        Intrinsics scale per axis; distortion and extrinsics do not change.
        """
        new = _check_size(image_size)
        if new == self.image_size:
            return self
        if not same_aspect(new, self.image_size):
            raise InputError(f"calibration is for {self.image_size[0]}x{self.image_size[1]} frames but the frames are "
                             f"{new[0]}x{new[1]} (a different aspect ratio, so it cannot be scaled)")
        sx, sy = new[0] / self.image_size[0], new[1] / self.image_size[1]
        meta = dict(self.metadata)
        meta["scaled_from"] = list(self.image_size)
        K1 = scale_K(self.K1, sx, sy)
        K2 = K1 if self.rectified else scale_K(self.K2, sx, sy)
        return self.replace(K1=K1, K2=K2, image_size=new, metadata=meta)

    @classmethod
    def from_rectified(cls, fx: float, fy: float, cx: float, cy: float, baseline_m: float,
                       image_size: tuple[int, int], **metadata: Any) -> "StereoRig":
        """A rig for frames that are already rectified: pinhole K shared by both eyes, D = 0, R = I, T = [-B, 0, 0]."""
        if not baseline_m > 0:
            raise InputError(f"rectified calibration: baseline must be > 0 m, got {baseline_m}")
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)
        meta = {"source": "rectified parameters"}
        meta.update(metadata)
        return cls(K1=K, D1=np.zeros(5), K2=K, D2=np.zeros(5), R=np.eye(3), T=np.array([-float(baseline_m), 0.0, 0.0]),
                   image_size=image_size, rectified=True, metadata=meta)

    # -- rectification --------------------------------------------------------------------------
    def rectification(self, alpha: float = 0.0, map_type: str = "32FC1") -> "Rectification":
        """Rectify with ``cv2.stereoRectify`` (CALIB_ZERO_DISPARITY) and build remap tables (cached per rig).

        alpha: 0 keeps only valid pixels, 1 keeps every source pixel (black borders).
        map_type: "32FC1" (float maps, exact) or "16SC2" (fixed point, faster remap).
        For a rig marked rectified, the result is the identity and the maps are None.
        """
        key = (float(alpha), map_type)
        if key not in self._cache:
            self._cache[key] = _rectify(self, float(alpha), map_type)
        return self._cache[key]


@dataclass(frozen=True, eq=False)
class Rectification:
    """Rectifying rotations/projections of a rig, plus remap tables.

    R1, R2 (3,3): rotation from each raw eye's frame to its rectified frame. P1, P2 (3,4):
    rectified projections (``P2[0,3] = -focal_px * baseline_m``). Q (4,4): disparity-to-depth.
    map_left/map_right: ``(map1, map2)`` for ``cv2.remap``, or None when the frames are already
    rectified. focal_px, cx_px, cy_px: pinhole of the LEFT rectified camera; baseline_m > 0.
    roi_left/roi_right: (x, y, w, h) of all-valid pixels in the rectified images.
    """

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    map_left: tuple[np.ndarray, np.ndarray] | None
    map_right: tuple[np.ndarray, np.ndarray] | None
    focal_px: float
    baseline_m: float
    cx_px: float
    cy_px: float
    image_size: tuple[int, int]
    roi_left: tuple[int, int, int, int]
    roi_right: tuple[int, int, int, int]
    identity: bool = False  # True: the input frames are already rectified

    @property
    def K_rect(self) -> np.ndarray:
        """(3,3) intrinsics of the rectified left camera."""
        return np.array(self.P1[:3, :3], dtype=np.float64)

    def rectify_points(self, pts_px: np.ndarray, eye: str, rig: StereoRig) -> np.ndarray:
        """Map raw pixel coordinates (N,2) of one eye ("left"/"right") to rectified pixel coordinates (N,2)."""
        import cv2

        pts = np.asarray(pts_px, dtype=np.float64).reshape(-1, 1, 2)
        if self.identity or len(pts) == 0:
            return pts.reshape(-1, 2).copy()
        # more iterations than cv2.undistortPoints' default 5: strong distortion near corners
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
        if eye == "left":
            out = cv2.undistortPoints(pts, rig.K1, rig.D1, R=self.R1, P=self.P1, criteria=crit)
        elif eye == "right":
            out = cv2.undistortPoints(pts, rig.K2, rig.D2, R=self.R2, P=self.P2, criteria=crit)
        else:
            raise ValueError(f"eye must be 'left' or 'right', got {eye!r}")
        return out.reshape(-1, 2)


def _rectify(rig: StereoRig, alpha: float, map_type: str) -> Rectification:
    import cv2

    w, h = rig.image_size
    if rig.rectified:
        K = rig.K1
        f, B = float(K[0, 0]), float(-rig.T[0])
        P1 = np.hstack([K, np.zeros((3, 1))])
        P2 = P1.copy()
        P2[0, 3] = -f * B
        # Q as cv2.stereoRectify builds it for Tx = -B and equal principal points.
        Q = np.array([[1, 0, 0, -K[0, 2]], [0, 1, 0, -K[1, 2]], [0, 0, 0, f], [0, 0, 1.0 / B, 0]], dtype=np.float64)
        return Rectification(R1=np.eye(3), R2=np.eye(3), P1=P1, P2=P2, Q=Q, map_left=None, map_right=None,
                             focal_px=f, baseline_m=B, cx_px=float(K[0, 2]), cy_px=float(K[1, 2]), image_size=(w, h),
                             roi_left=(0, 0, w, h), roi_right=(0, 0, w, h), identity=True)
    T = rig.T
    if abs(T[0]) < max(abs(T[1]), abs(T[2])):
        raise InputError(f"calibration: T = {np.round(T, 4).tolist()} m is not a side-by-side (horizontal) rig")
    if T[0] > 0:
        raise InputError(f"calibration: T[0] = {T[0]:.4f} m > 0 means the right eye is LEFT of the left eye "
                         "(eyes swapped, or T in another convention; expected X_right = R X_left + T with T ~ [-B, 0, 0])")
    R1, R2, P1, P2, Q, roi1, roi2 = cv2.stereoRectify(rig.K1, rig.D1, rig.K2, rig.D2, (w, h), rig.R,
                                                      rig.T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha, newImageSize=(w, h))
    m_type = {"32FC1": cv2.CV_32FC1, "16SC2": cv2.CV_16SC2}.get(map_type)
    if m_type is None:
        raise ValueError(f"map_type must be '32FC1' or '16SC2', got {map_type!r}")
    map_l = cv2.initUndistortRectifyMap(rig.K1, rig.D1, R1, P1, (w, h), m_type)
    map_r = cv2.initUndistortRectifyMap(rig.K2, rig.D2, R2, P2, (w, h), m_type)
    f = float(P1[0, 0])
    B = float(-P2[0, 3] / P2[0, 0])
    log.debug("rectified: f=%.2f px, B=%.4f m, roi L %s R %s", f, B, roi1, roi2)
    return Rectification(R1=R1, R2=R2, P1=P1, P2=P2, Q=Q, map_left=tuple(map_l), map_right=tuple(map_r), focal_px=f,
                         baseline_m=B, cx_px=float(P1[0, 2]), cy_px=float(P1[1, 2]), image_size=(w, h),
                         roi_left=tuple(int(v) for v in roi1), roi_right=tuple(int(v) for v in roi2))


def rectify_pair(left: np.ndarray, right: np.ndarray, rect: Rectification,
                 interpolation: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Remap a raw pair into rectified images (same size); returns the inputs unchanged for an identity rectification.

    left, right: (H, W) or (H, W, C) images of one eye each, of ``rect.image_size``.
    """
    for name, img in (("left", left), ("right", right)):
        if img is None or img.ndim < 2:
            raise InputError(f"rectify: {name} image is empty")
        if (img.shape[1], img.shape[0]) != tuple(rect.image_size):
            raise InputError(f"rectify: {name} image is {img.shape[1]}x{img.shape[0]} but the calibration is for "
                             f"{rect.image_size[0]}x{rect.image_size[1]}")
    if rect.identity or rect.map_left is None:
        return left, right
    import cv2

    interp = cv2.INTER_LINEAR if interpolation is None else interpolation
    return (cv2.remap(left, rect.map_left[0], rect.map_left[1], interp),
            cv2.remap(right, rect.map_right[0], rect.map_right[1], interp))
