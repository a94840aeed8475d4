"""Motion-stereo stage: depth of a fusion view from a second, later frame of the flight (a wide baseline).

Why: the rig's 12 cm baseline resolves 1 px of disparity into Z² / (f B) metres of depth - 1.3 m at
9 m from HD720 - and on plain painted truck panels SGBM only interpolates between the panel's
edges, off by 0.3-2 px in a way that differs from view to view. Averaging those in the TSDF does
not cancel them (its truncation clips the errors unevenly), so full-scale side walls came out 4-5 cm
off. The drone itself moves ~1 m between frames of an orbit; pairing a fusion view with a frame
whose camera centre is ``baseline_rel`` x the scene depth away makes the same pixel error ~8x
smaller in metres. The pair is rectified from the two (final) camera poses with OpenCV's
``stereoRectify``, matched with 8-path SGBM (3-path SGBM drags plain slanted panels towards one
edge: +2 cm on full-scale walls, 8 paths: 0-1 cm), and checked against the rig's own depth. The
median ratio of the rig's depth to the wide depth measures odometry's scale (the wide baselines
are odometry's steps); ``reconstruct`` rescales the trajectory by it. That ratio is read at corners
tracked into the rig's right eye and into the partner (``sparse_rig_ratios``), not from SGBM, whose
sub-pixel pull towards whole pixels is 1-2 % of a far scene's 2-5 px rig disparity.

Used by ``reconstruct`` for far scenes (``ReconstructConfig.far_scene_depth_baselines``) or on request
(``motion_stereo``). On model trucks flown close (Table 2's orbits, 0.9-1.7 m: under 14.2 rig baselines) it
does not help the width (their narrow walls come out 1-2 mm inside), so there the rig's depth is fused.

Frames: every pose is world-from-camera (``conventions``) of a *rectified left* camera, metres;
the returned depth lives in a rotated copy of the fusion view's camera (same centre), whose pose
``T_wc @ [R_rect^T]`` and intrinsics come with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from stereo_recon.disparity import DisparityConfig, depth_from_disparity, disparity_map
from stereo_recon.core.errors import ConfigError
from stereo_recon.trajectory import rotation_angle_deg


@dataclass(frozen=True)
class MotionStereoConfig:
    """Every parameter of motion stereo (partner choice, rectification, matching, checks)."""

    # Wanted distance between the two camera centres, as a fraction of the fusion view's median depth.
    # 0.11 = 1 m at 9 m: 8x the ZED2's baseline at full scale; at model scale (1.7 m) 19 cm.
    baseline_rel: float = 0.11
    # The partner must move mostly sideways in the view's image (|x| of the baseline over its length):
    # a forward or vertical motion puts the epipole in or near the image and rectification fails.
    min_lateral_frac: float = 0.75
    # Largest rotation between the two views (deg); beyond it the panels look too different to match.
    max_rotation_deg: float = 30.0
    # A view waits at most this many frames for its partner, then keeps the rig's depth only.
    max_partner_gap_frames: int = 30
    # Matching: 8-path SGBM (OpenCV's MODE_HH) on the pair rectified at fusion resolution.
    mode: str = "hh"
    # Wide depth is kept where it agrees with the rig's depth within this many px of the *rig's*
    # disparity (its errors on plain panels reach 2 px; this rejects gross mismatches only).
    check_px: float = 3.0
    # Where the wide pair has no valid depth (occlusions, the image border it does not share), fill with
    # the rig's depth. Off: on the sample truck with exact poses the filled rig depth (biased on plain
    # walls) moved the width from -0.86 % to -2.37 %; other views cover those holes.
    fill_from_rig: bool = False
    # Upper bound of the disparity search of the wide pair (px at fusion resolution).
    max_num_disparities: int = 256
    # Voxel of the fusion when wide depth is fused, in full-resolution pixel footprints at the first
    # view's median depth (replaces FusionConfig.voxel_footprint_px; None keeps it). Why finer: the
    # wide pair's depth error is ~baseline_rel^-1 = 9 footprints per px of disparity error, the rig's at
    # model scale Z/B = 12-16, so the same TSDF smoothing needs a finer grid. Measured on the two
    # full-scale presets with exact poses: width -1.06 / -1.22 % at 2 px, -0.87 / -0.87 % at 1.5,
    # -0.67 / -0.82 % at 1.25, -0.58 / -0.68 % at 1.0 (fusion 4 -> 15 s). On model trucks (rig depth)
    # 1.0 lost flatbed decks' edges (truck 12 W -2.24 -> -4.56 %), so FusionConfig keeps 2.
    voxel_footprint_px: float | None = 1.0
    # Rescale the trajectory (odometry's, at the bundle adjustment's scale when SfM refined it) by the median
    # ratio of the rig's depth to the wide pairs' depth (``reconstruct``): the wide pairs' baselines are the
    # path's steps, so that ratio is the path's scale error as the rig's dense depth sees it. Skipped when it
    # exceeds max_rescale (the run's ``trajectory_scale`` gate then refuses it). 0.15 (was 0.05): on tuning
    # seeds 2045-2046 the ratio applied left the path within 0.6 % of the true scale on 70 of the 71 runs it
    # was applied to (1.5 % on the other); the one beyond 5 % (+6.48 %, true +6.20 %) read L -6.65 / H -6.30 %
    # unscaled and -0.12 / -0.22 % rescaled; a step 10 % short is measured within 0.3 %
    # (tests/stereo_recon/test_motion_stereo.py).
    rescale_trajectory: bool = True
    max_rescale: float = 0.15
    # The rig's depth that ratio is taken from. "lk" (default): corners of every paired view, tracked with
    # pyramidal Lucas-Kanade into the rig's right eye (the rig's disparity) and into the partner frame (the
    # wide pair's depth, triangulated from the two poses) (``sparse_rig_ratios``). Why: SGBM's sub-pixel
    # disparity is biased towards whole pixels, and a far scene holds the rig's disparity at 2-5 px, where
    # 0.05 px is 1-2 %: with true poses on full-scale tuning draws (seed 2056), 8-path SGBM's ratio read
    # -1.67 / -0.67 % (the runs' trajectories came out -1.65 / -0.59 % small), the tracked corners
    # -0.47 / +0.09 %. Lucas-Kanade's continuous fit has no such pull and costs ~0.2 s a view, so every
    # paired view counts. The SGBM modes ("hh", "hh4", "sgbm", "sgbm3way") match up to ``scale_views``
    # views, evenly spread, again with that mode (0: the fused 3-path depth of every paired view), as before
    # (3-path SGBM reads a weakly textured ground 0.0-0.5 % too far; 8 paths: 0.0 % on 4 model-scale draws).
    scale_views: int = 8
    scale_mode: str = "lk"
    # "lk": corners per view (OpenCV goodFeaturesToTrack, quality 0.001 of the strongest, 4 px apart), the
    # tracker's window (px), and the largest forward-backward track disagreement (px) and rig row offset (px)
    # a corner may show; a view gives a ratio from at least ``scale_min_corners`` corners.
    scale_corners: int = 8000
    scale_lk_window_px: int = 21
    scale_lk_max_fb_px: float = 0.2
    scale_lk_max_row_px: float = 0.5
    scale_min_corners: int = 30
    # ... and a corner counts only where its rig disparity agrees within this (px) with the wide depth at the
    # view's median ratio (iterated three times). Measured with true poses on 6 tuning draws of seed 2056:
    # every corner's median -0.56 .. +0.12 % (mean |.| 0.34 %), within 0.5 px +0.10 .. -0.21 % (0.13 %).
    scale_lk_gate_px: float = 0.5

    def __post_init__(self) -> None:
        if not 0 < self.baseline_rel < 1:
            raise ConfigError(f"motion stereo baseline_rel={self.baseline_rel}: must be in (0, 1)")
        if not 0 < self.min_lateral_frac <= 1:
            raise ConfigError(f"motion stereo min_lateral_frac={self.min_lateral_frac}: must be in (0, 1]")
        if not 0 < self.max_rotation_deg < 90:
            raise ConfigError(f"motion stereo max_rotation_deg={self.max_rotation_deg}: must be in (0, 90)")
        if self.max_partner_gap_frames < 1:
            raise ConfigError(f"motion stereo max_partner_gap_frames={self.max_partner_gap_frames}: must be >= 1")
        if not self.check_px > 0:
            raise ConfigError(f"motion stereo check_px={self.check_px}: must be > 0")
        if self.scale_views < 0:
            raise ConfigError(f"motion stereo scale_views={self.scale_views}: must be >= 0")
        if self.scale_mode not in ("lk", "sgbm3way", "sgbm", "hh", "hh4"):
            raise ConfigError(f"motion stereo scale_mode={self.scale_mode!r}: expected lk, sgbm3way, sgbm, hh or hh4")
        if self.scale_corners < 1 or self.scale_lk_window_px < 5 or self.scale_min_corners < 1:
            raise ConfigError("motion stereo scale_corners, scale_min_corners must be >= 1 and scale_lk_window_px >= 5")
        if not (self.scale_lk_max_fb_px > 0 and self.scale_lk_max_row_px > 0 and self.scale_lk_gate_px > 0):
            raise ConfigError("motion stereo scale_lk_max_fb_px, scale_lk_max_row_px and scale_lk_gate_px must be > 0")


def partner_ok(T_wc_a: np.ndarray, T_wc_b: np.ndarray, depth_m: float, config: MotionStereoConfig) -> bool:
    """Whether view b makes a wide-baseline pair with view a.

    T_wc_a, T_wc_b: (4, 4) world-from-camera poses (m); depth_m: median scene depth of view a (m).
    True when the centres are at least ``baseline_rel`` x depth apart, the baseline runs mostly along
    a's image x axis and the views are turned by at most ``max_rotation_deg``.
    """
    if not (np.isfinite(depth_m) and depth_m > 0):
        return False
    rel = np.linalg.inv(T_wc_a) @ T_wc_b  # b's centre in a's camera frame
    t = rel[:3, 3]
    dist = float(np.linalg.norm(t))
    return bool(dist >= config.baseline_rel * depth_m and abs(t[0]) >= config.min_lateral_frac * dist
                and rotation_angle_deg(rel[:3, :3]) <= config.max_rotation_deg)


@dataclass(frozen=True)
class MotionPair:
    """Rectification of a (view, partner) pair, at the output size.

    maps_a / maps_b: float32 (map_x, map_y) for ``cv2.remap`` from each full-size input image.
    K_rect: (3, 3) intrinsics of the rectified view a (px, output size). R_rect_a: (3, 3) rotation
    rectified-from-camera of view a. baseline_m: distance between the centres. partner_left: the
    partner is the left camera of the rectified pair (images are then mirrored for matching).
    """

    maps_a: tuple[np.ndarray, np.ndarray]
    maps_b: tuple[np.ndarray, np.ndarray]
    K_rect: np.ndarray
    R_rect_a: np.ndarray
    baseline_m: float
    partner_left: bool
    size_px: tuple[int, int]


def rectify_motion_pair(K: np.ndarray, T_wc_a: np.ndarray, T_wc_b: np.ndarray, image_size: tuple[int, int],
                        out_size: tuple[int, int]) -> MotionPair:
    """Rectify two views of one moving pinhole camera (no distortion: images already rectified by the rig).

    K: (3, 3) px intrinsics of both input images (size ``image_size`` (w, h)); T_wc_a, T_wc_b: (4, 4)
    world-from-camera poses (m); out_size: (w, h) of the rectified images (e.g. the fusion resolution).
    """
    import cv2

    rel = np.linalg.inv(T_wc_b) @ T_wc_a  # X_b = R X_a + t  (OpenCV's stereo extrinsics, conventions)
    R, t = rel[:3, :3], rel[:3, 3]
    zero = np.zeros(5)
    K = np.asarray(K, dtype=np.float64)
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(K, zero, K, zero, tuple(image_size), R, t.reshape(3, 1),
                                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
                                                newImageSize=tuple(out_size))
    maps_a = cv2.initUndistortRectifyMap(K, zero, R1, P1, tuple(out_size), cv2.CV_32FC1)
    maps_b = cv2.initUndistortRectifyMap(K, zero, R2, P2, tuple(out_size), cv2.CV_32FC1)
    # a's centre seen from b: t. x < 0 means a is to the left of b (OpenCV: T ~ [-B, 0, 0]).
    return MotionPair(maps_a, maps_b, P1[:3, :3].copy(), R1, float(np.linalg.norm(t)), bool(t[0] > 0),
                      (int(out_size[0]), int(out_size[1])))


def _rig_depth_in_rect(pair: MotionPair, depth_a_m: np.ndarray) -> np.ndarray:
    """The rig's depth of view a (full size, its own camera frame) resampled as z in a's rectified frame."""
    import cv2

    z = cv2.remap(np.nan_to_num(np.asarray(depth_a_m, np.float32), nan=0.0), *pair.maps_a, cv2.INTER_NEAREST)
    w, h = pair.size_px
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(pair.K_rect).T  # rectified rays, z' = 1
    rz = rays @ pair.R_rect_a[:, 2]  # z of the same ray in a's camera frame: (R_rect^T r)_z
    with np.errstate(divide="ignore", invalid="ignore"):
        zr = (z / rz).astype(np.float32)
    zr[~(z > 0)] = np.nan
    return zr


def _search_range(fb_px_m: float, z_m: np.ndarray, max_num16: int) -> tuple[int, int]:
    """(min disparity, number of disparities) px covering depths z_m (valid, m) with 25 % margins, for focal x
    baseline fb_px_m (px m); the number is a multiple of 16, at least 16 and at most max_num16."""
    z_lo, z_hi = np.percentile(z_m, [0.5, 99.5])
    d_min = max(0, int(math.floor(fb_px_m / (1.25 * z_hi))) - 1)
    d_max = int(math.ceil(fb_px_m / (0.8 * z_lo))) + 1
    return d_min, max(16, int(min(math.ceil((d_max - d_min) / 16.0) * 16, max_num16)))


def _depth_ratio(rig_z: np.ndarray, z: np.ndarray, rig_fb_px_m: float, check_px: float) -> tuple[np.ndarray, float]:
    """Where the rig's depth rig_z and the wide depth z (m, same pixels) agree within check_px of the rig's
    disparity, and the median of rig_z / z there (NaN under 100 such pixels): the trajectory's scale error."""
    with np.errstate(invalid="ignore", divide="ignore"):
        agree = np.abs(rig_fb_px_m / z - rig_fb_px_m / rig_z) <= check_px  # False where either is NaN
    return agree, (float(np.median(rig_z[agree] / z[agree])) if agree.sum() > 100 else float("nan"))


def sparse_rig_ratios(gray_a: np.ndarray, gray_a_right: np.ndarray, gray_b: np.ndarray, K: np.ndarray,
                      T_a: np.ndarray, T_b: np.ndarray, rig_fb_px_m: float, depth_a_m: np.ndarray,
                      config: MotionStereoConfig) -> np.ndarray:
    """The rig's depth over the wide pair's depth at corners of view a: odometry's scale error, per corner.

    Each corner is tracked (pyramidal Lucas-Kanade, checked forwards and backwards) into the rig's right eye,
    whose disparity gives the rig's depth fB / d, and into the partner frame b, where it is triangulated
    from the two poses (the wide depth, in odometry's scale). gray_a, gray_a_right: the rig's rectified grey
    pair of view a; gray_b: frame b's rectified left grey image; K: the rectified intrinsics (px); T_a, T_b:
    world-from-rectified-left-camera poses (m); rig_fb_px_m: the rig's focal x baseline (px m); depth_a_m:
    view a's fused rig depth (m, NaN invalid), only the trackers' starting guess. Returns the ratios (empty
    when no corner passes).
    """
    import cv2

    p = cv2.goodFeaturesToTrack(gray_a, config.scale_corners, 0.001, 4, blockSize=7)
    if p is None or len(p) < config.scale_min_corners:
        return np.zeros(0)
    p = p.reshape(-1, 1, 2).astype(np.float32)
    h, w = gray_a.shape[:2]
    xi = np.clip(np.round(p[:, 0, 0]).astype(int), 0, w - 1)
    yi = np.clip(np.round(p[:, 0, 1]).astype(int), 0, h - 1)
    z0 = depth_a_m[yi, xi].astype(np.float64)
    ok0 = np.isfinite(z0) & (z0 > 0)
    if ok0.sum() < config.scale_min_corners:
        return np.zeros(0)
    z0 = np.where(ok0, z0, np.median(z0[ok0]))
    lk = dict(winSize=(config.scale_lk_window_px, config.scale_lk_window_px), maxLevel=3,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 0.001), flags=cv2.OPTFLOW_USE_INITIAL_FLOW)

    def track(img_a, img_b, guess):
        q, st, _ = cv2.calcOpticalFlowPyrLK(img_a, img_b, p, guess.astype(np.float32).copy(), **lk)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(img_b, img_a, q, p.copy(), **lk)
        good = (st[:, 0] == 1) & (st2[:, 0] == 1) & (np.linalg.norm((back - p)[:, 0], axis=1) < config.scale_lk_max_fb_px)
        return q[:, 0].astype(np.float64), good

    # The rig: the right eye sees the corner fB / z px to the left, on the same row.
    guess = p.copy()
    guess[:, 0, 0] -= (rig_fb_px_m / z0).astype(np.float32)
    q_r, good = track(gray_a, gray_a_right, guess)
    d_rig = p[:, 0, 0] - q_r[:, 0]
    good &= (np.abs(q_r[:, 1] - p[:, 0, 1]) < config.scale_lk_max_row_px) & (d_rig > 0.5)
    # The partner: start where the fused depth and the two poses put the corner.
    Kinv = np.linalg.inv(K)
    rays = (Kinv @ np.vstack([p[:, 0].T.astype(np.float64), np.ones(len(p))])) * z0
    T_ba = np.linalg.inv(T_b) @ T_a
    Xb = T_ba[:3, :3] @ rays + T_ba[:3, 3:4]
    front = Xb[2] > 1e-6
    xb = (K @ Xb)[:2] / np.where(front, Xb[2], 1.0)
    guess_b = np.where(front[:, None], xb.T, p[:, 0]).reshape(-1, 1, 2)
    q_b, good_b = track(gray_a, gray_b, guess_b)
    good &= good_b & front
    if good.sum() < config.scale_min_corners:
        return np.zeros(0)
    T_aw = np.linalg.inv(T_a)
    P_a = K @ T_aw[:3]
    P_b = K @ np.linalg.inv(T_b)[:3]
    X = cv2.triangulatePoints(P_a, P_b, p[good, 0].T.astype(np.float64), q_b[good].T)
    X = X[:3] / X[3]
    z_wide = (T_aw[:3, :3] @ X + T_aw[:3, 3:4])[2]
    xb_hat = P_b @ np.vstack([X, np.ones(X.shape[1])])
    reproj = np.linalg.norm((xb_hat[:2] / xb_hat[2]).T - q_b[good], axis=1)
    keep = (z_wide > 0) & (reproj < 1.0)
    d, ratio = d_rig[good][keep], (rig_fb_px_m / d_rig[good][keep]) / z_wide[keep]
    # Corners that straddle a depth edge or were tracked to a look-alike read the rig's disparity off by far
    # more than the scale can explain, mostly on one side (nearer): only those whose disparity agrees with
    # the wide depth at the view's own median scale within ``scale_lk_gate_px`` count.
    m = np.ones(len(ratio), bool)
    for _ in range(3):
        if m.sum() < config.scale_min_corners:
            break
        k = float(np.median(ratio[m]))
        m = np.abs(d * (1.0 - ratio / k)) <= config.scale_lk_gate_px
    return ratio[m]


def rig_depth_for_scale(gray_a: np.ndarray, gray_a_right: np.ndarray, depth_a_m: np.ndarray, disparity: DisparityConfig,
                        config: MotionStereoConfig, rig_fb_px_m: float) -> np.ndarray:
    """The rig's depth (m, full size, NaN invalid) of view a matched again with ``config.scale_mode`` SGBM.

    gray_a, gray_a_right: the rig's rectified grey pair of view a; depth_a_m: its fused (3-path) depth, which
    sets the search range; disparity: the rig's SGBM settings (range and mode replaced); rig_fb_px_m: the
    rig's focal x baseline (px m).
    """
    ok = np.isfinite(depth_a_m)
    if ok.sum() < 100:
        return np.full(depth_a_m.shape, np.nan, np.float32)
    d_min, num = _search_range(rig_fb_px_m, depth_a_m[ok], disparity.num_disparities_16)
    dcfg = replace(disparity, min_disparity_px=d_min, num_disparities_px=num, mode=config.scale_mode)
    d = disparity_map(gray_a, gray_a_right, dcfg)
    return depth_from_disparity(d, rig_fb_px_m, 1.0, 1e-3, 1e6)


def motion_depth(gray_a: np.ndarray, gray_b: np.ndarray, depth_a_m: np.ndarray, pair: MotionPair,
                 disparity: DisparityConfig, config: MotionStereoConfig, rig_fb_px_m: float,
                 depth_max_m: float, scale_depth_a_m: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Depth (m) of view a from the wide pair (a, b), in a's rectified frame at ``pair.size_px``.

    gray_a, gray_b: full-size rectified grey images of the two views; depth_a_m: the rig's depth of
    view a (full size, metres, NaN invalid), used for the search range, the check and the fill.
    disparity: SGBM settings (its range and mode are replaced here); rig_fb_px_m: focal x baseline of
    the rig (px m), to express the check in the rig's disparity. scale_depth_a_m: the rig's depth of view a
    from ``rig_depth_for_scale`` (full size, m), or None; its ratio to the wide depth is counted as
    ``rig_scale_ratio_median``. Returns (depth, counts).
    """
    import cv2

    rig_z = _rig_depth_in_rect(pair, depth_a_m)
    ok = np.isfinite(rig_z) & (rig_z <= depth_max_m)
    counts = {"wide_valid": 0.0, "rig_filled": 0.0, "rig_ratio_median": float("nan"),
              "rig_scale_ratio_median": float("nan")}
    if ok.sum() < 100:  # nothing to set the search range from: the rig's depth only (or nothing)
        return (rig_z if config.fill_from_rig else np.full_like(rig_z, np.nan)), counts
    d_min, num = _search_range(float(pair.K_rect[0, 0]) * pair.baseline_m, rig_z[ok], config.max_num_disparities // 16 * 16)
    if pair.size_px[0] - (d_min + num) <= disparity.block_size_px // 2:
        # The search range is as wide as the rectified image (a long baseline for the depth, as a wrong pose
        # makes it): SGBM cannot match it and OpenCV refuses with an error. The rig's depth only, as above.
        counts["wide_skipped"] = 1.0
        return (rig_z if config.fill_from_rig else np.full_like(rig_z, np.nan)), counts
    a = cv2.remap(gray_a, *pair.maps_a, cv2.INTER_LINEAR)
    b = cv2.remap(gray_b, *pair.maps_b, cv2.INTER_LINEAR)
    if pair.partner_left:  # match mirrored images, so that a is the left eye and disparities stay positive
        a, b = np.ascontiguousarray(a[:, ::-1]), np.ascontiguousarray(b[:, ::-1])
    scale = pair.size_px[0] / gray_a.shape[1]
    fill = None if disparity.fill_max_px is None else max(1, int(round(disparity.fill_max_px * scale)))
    dcfg = replace(disparity, min_disparity_px=d_min, num_disparities_px=num, mode=config.mode, fill_max_px=fill)
    d = disparity_map(a, b, dcfg)
    if pair.partner_left:
        d = np.ascontiguousarray(d[:, ::-1])
    z = depth_from_disparity(d, float(pair.K_rect[0, 0]), pair.baseline_m, 1e-3, 1e6)
    # The rig's depth over the wide depth where both see: the trajectory's scale error (reconstruct).
    agree, counts["rig_ratio_median"] = _depth_ratio(rig_z, z, rig_fb_px_m, config.check_px)
    if scale_depth_a_m is not None:
        _, counts["rig_scale_ratio_median"] = _depth_ratio(_rig_depth_in_rect(pair, scale_depth_a_m), z, rig_fb_px_m,
                                                           config.check_px)
    # Where the rig has no depth the check cannot run; the wide pair alone is trusted there.
    good = np.isfinite(z) & (agree | ~np.isfinite(rig_z))
    out = np.where(good, z, np.nan).astype(np.float32)
    counts["wide_valid"] = float(good.mean())
    if config.fill_from_rig:
        hole = ~good & np.isfinite(rig_z)
        out[hole] = rig_z[hole]
        counts["rig_filled"] = float(hole.mean())
    return out, counts


