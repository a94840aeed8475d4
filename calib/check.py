"""Does a calibration fit a video? Vertical offsets of matched features, raw and after rectification.

In a correctly rectified pair every scene point lies on the same row in both eyes, so the
|y_left - y_right| of feature matches measures how well the calibration fits (a few tenths of a
pixel when it does). Comparing the raw frames with the rectified ones tells the two usual mistakes
apart: frames that are already rectified (ZED SDK exports) have |dy| ~ 0 raw and get WORSE when
rectified again; raw frames left unrectified have large raw |dy| that rectification removes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from calib.rig import Rectification, StereoRig, rectify_pair
from stereo_recon.core.errors import InputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CheckConfig:
    """Thresholds for calling a pair's rows aligned."""

    max_features: int = 3000        # SIFT keypoints per eye
    ratio: float = 0.75             # Lowe's ratio test
    ransac_px: float = 2.0          # fundamental-matrix RANSAC threshold (calibration independent outlier removal)
    min_matches: int = 20           # fewer: inconclusive
    good_median_px: float = 0.5     # aligned rows: median |dy| at most this (at 1280 px wide; scales with width)
    good_fraction: float = 0.6      # ... and at least this fraction of matches within 1 px (x width / 1280).
    # A calibration also fits when its rectification at least halves the raw rows' median |dy| and leaves
    # at most noisy_median_px: noisy frames (pixel noise, blur, MJPG) scatter SIFT's rows by 0.5-0.6 px
    # under an exact calibration (two rendered draws with raw rows 2.4 and 3.9 px off, rectified 0.56 and
    # 0.52 px, were refused as "does not fit"); another camera's calibration does not halve them.
    noisy_median_px: float = 1.0
    noisy_gain: float = 0.5
    # (not a p95 bound: moving or repeated content, e.g. a screen in view, gives a few per cent of
    # matches that fit the epipolar geometry found by RANSAC but not the scene)


def _gray(img: np.ndarray) -> np.ndarray:
    import cv2

    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def match_features(left: np.ndarray, right: np.ndarray, config: CheckConfig = CheckConfig()) -> tuple[np.ndarray, np.ndarray]:
    """SIFT matches between two images: (N,2) left and (N,2) right pixel coordinates.

    Ratio test, mutual best match, then RANSAC on the fundamental matrix, which removes wrong
    matches without assuming any calibration.
    """
    import cv2

    gl, gr = _gray(left), _gray(right)
    sift = cv2.SIFT_create(nfeatures=config.max_features)
    kl, dl = sift.detectAndCompute(gl, None)
    kr, dr = sift.detectAndCompute(gr, None)
    if dl is None or dr is None or len(kl) < 2 or len(kr) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    bf = cv2.BFMatcher(cv2.NORM_L2)
    fwd = bf.knnMatch(dl, dr, k=2)
    back = {m[0].queryIdx: m[0].trainIdx for m in bf.knnMatch(dr, dl, k=1) if m}
    good = [m[0] for m in fwd if len(m) == 2 and m[0].distance < config.ratio * m[1].distance
            and back.get(m[0].trainIdx) == m[0].queryIdx]
    pl = np.array([kl[m.queryIdx].pt for m in good], dtype=np.float64).reshape(-1, 2)
    pr = np.array([kr[m.trainIdx].pt for m in good], dtype=np.float64).reshape(-1, 2)
    if len(pl) >= 8:
        try:
            F, mask = cv2.findFundamentalMat(pl, pr, cv2.USAC_MAGSAC, config.ransac_px, 0.999, 10000)
        except cv2.error:   # MAGSAC asserts (!model.empty()) when no model fits: seen on envelope draw 2046/4
            F, mask = None, None
        if F is None or mask is None:   # no epipolar geometry: right matches cannot be told from wrong ones
            return np.zeros((0, 2)), np.zeros((0, 2))
        keep = mask.reshape(-1).astype(bool)
        pl, pr = pl[keep], pr[keep]
    return pl, pr


def dy_stats(pl: np.ndarray, pr: np.ndarray, scale: float = 1.0) -> dict:
    """Statistics of the row offsets of matched points (N,2): median/p95 |dy|, signed mean dy, the fraction
    within ``scale`` px, and the fraction of negative disparities."""
    if len(pl) == 0:
        return {"matches": 0, "median_dy_px": float("nan"), "p95_dy_px": float("nan"), "mean_dy_px": float("nan"),
                "within_1px_fraction": float("nan"), "negative_disparity_fraction": float("nan")}
    dy = pl[:, 1] - pr[:, 1]
    ady = np.abs(dy)
    return {"matches": int(len(pl)), "median_dy_px": float(np.median(ady)), "p95_dy_px": float(np.percentile(ady, 95)),
            "mean_dy_px": float(np.mean(dy)), "within_1px_fraction": float(np.mean(ady <= 1.0 * scale)),
            "negative_disparity_fraction": float(np.mean(pl[:, 0] - pr[:, 0] < 0))}


def epipolar_error(left: np.ndarray, right: np.ndarray, rig_or_rect: StereoRig | Rectification,
                   config: CheckConfig = CheckConfig()) -> dict:
    """Median and 95th percentile |y_left - y_right| px of feature matches after rectification, and the match count.

    left, right: raw frames of one eye each. A StereoRig maps the raw matches through its
    rectification exactly; a bare Rectification remaps the images and matches those.
    """
    if isinstance(rig_or_rect, StereoRig):
        rig = rig_or_rect
        rect = rig.rectification()
        pl, pr = match_features(left, right, config)
        scale = max(1.0, rig.image_size[0] / 1280.0)
        return dy_stats(rect.rectify_points(pl, "left", rig), rect.rectify_points(pr, "right", rig), scale)
    l2, r2 = rectify_pair(left, right, rig_or_rect)
    return dy_stats(*match_features(l2, r2, config), max(1.0, rig_or_rect.image_size[0] / 1280.0))


def _good(s: dict, cfg: CheckConfig, scale: float) -> bool:
    return (s["matches"] >= cfg.min_matches and s["median_dy_px"] <= cfg.good_median_px * scale
            and s["within_1px_fraction"] >= cfg.good_fraction)


def verdict_from_matches(pl: np.ndarray, pr: np.ndarray, rig: StereoRig, config: CheckConfig = CheckConfig()) -> dict:
    """Compare |dy| of raw matches with |dy| after ``rig``'s rectification and say which fits.

    Returns ``{"raw": stats, "rectified": stats, "verdict": ..., "message": ...}`` with verdict one of
    "ok", "already_rectified" (do not rectify again), "not_rectified" (frames are raw but the
    calibration says rectified), "calibration_mismatch", "swapped_eyes", "inconclusive".
    """
    rect = rig.rectification()
    scale = max(1.0, rig.image_size[0] / 1280.0)
    raw = dy_stats(pl, pr, scale)
    rl, rr = rect.rectify_points(pl, "left", rig), rect.rectify_points(pr, "right", rig)
    rec = dy_stats(rl, rr, scale)
    out = {"raw": raw, "rectified": rec, "image_size": list(rig.image_size), "rig_rectified": rig.rectified,
           "thresholds": {"median_px": config.good_median_px * scale, "within_px": scale,
                          "within_fraction": config.good_fraction}}
    n = raw["matches"]
    if n < config.min_matches:
        out.update(verdict="inconclusive", message=f"only {n} reliable feature matches (need {config.min_matches}); "
                   "use frames of a textured scene")
        return out
    good_raw, good_rec = _good(raw, config, scale), _good(rec, config, scale)
    if good_rec and rec["negative_disparity_fraction"] > 0.5:
        out.update(verdict="swapped_eyes", message=f"rows align but {100 * rec['negative_disparity_fraction']:.0f}% of "
                   "matches have negative disparity: the left and right eyes look swapped")
    elif rig.rectified:
        if good_raw:
            out.update(verdict="ok", message=f"frames are rectified, as the calibration says: median |dy| "
                       f"{raw['median_dy_px']:.2f} px, p95 {raw['p95_dy_px']:.2f} px over {n} matches")
        else:
            out.update(verdict="not_rectified", message=f"the calibration says the frames are rectified, but matched "
                       f"features differ by median {raw['median_dy_px']:.2f} px (p95 {raw['p95_dy_px']:.2f}) in row: the frames "
                       "look raw (unrectified); pass the camera's .conf or rig YAML instead")
    elif good_rec and (not good_raw or rec["median_dy_px"] <= raw["median_dy_px"] + 0.05 * scale):
        out.update(verdict="ok", message=f"calibration fits: after rectification median |dy| {rec['median_dy_px']:.2f} px, "
                   f"p95 {rec['p95_dy_px']:.2f} px over {n} matches (raw frames: median {raw['median_dy_px']:.2f} px)")
    elif (not good_raw and rec["median_dy_px"] <= config.noisy_median_px * scale
          and rec["median_dy_px"] <= config.noisy_gain * raw["median_dy_px"]):
        out.update(verdict="ok", message=f"calibration fits, the matches are noisy: rectification brings rows from median "
                   f"|dy| {raw['median_dy_px']:.2f} px to {rec['median_dy_px']:.2f} px (p95 {rec['p95_dy_px']:.2f} px) over {n} matches")
    elif good_raw:
        out.update(verdict="already_rectified", message=f"the frames are already rectified (raw median |dy| "
                   f"{raw['median_dy_px']:.2f} px); rectifying them again with this calibration makes rows disagree "
                   f"(median {rec['median_dy_px']:.2f} px, p95 {rec['p95_dy_px']:.2f} px). Use the rectified parameters "
                   "(--calib fx,fy,cx,cy,baseline_m) or a rig marked rectified")
    else:
        out.update(verdict="calibration_mismatch", message=f"rows disagree both raw (median |dy| {raw['median_dy_px']:.2f} px) "
                   f"and rectified (median {rec['median_dy_px']:.2f} px, p95 {rec['p95_dy_px']:.2f} px): this calibration does "
                   "not fit the video (another camera or resolution, or it has drifted)")
    return out


def detect_rectification_mismatch(left: np.ndarray, right: np.ndarray, rig: StereoRig,
                                  config: CheckConfig = CheckConfig()) -> dict:
    """One pair: are these frames raw or already rectified, and does ``rig`` fit? See ``verdict_from_matches``."""
    for name, img in (("left", left), ("right", right)):
        if (img.shape[1], img.shape[0]) != rig.image_size:
            raise InputError(f"calib-check: {name} frame is {img.shape[1]}x{img.shape[0]} but the calibration is for "
                             f"{rig.image_size[0]}x{rig.image_size[1]}")
    pl, pr = match_features(left, right, config)
    return verdict_from_matches(pl, pr, rig, config)


def check_pairs(pairs, rig: StereoRig, config: CheckConfig = CheckConfig()) -> dict:
    """Pool matches of several ``(name, left, right)`` pairs and judge the calibration once; per-pair stats included."""
    all_l, all_r, per = [], [], []
    rect = rig.rectification()
    for name, left, right in pairs:
        if (left.shape[1], left.shape[0]) != rig.image_size:
            raise InputError(f"calib-check: {name} is {left.shape[1]}x{left.shape[0]} per eye but the calibration is for "
                             f"{rig.image_size[0]}x{rig.image_size[1]}")
        pl, pr = match_features(left, right, config)
        all_l.append(pl)
        all_r.append(pr)
        scale = max(1.0, rig.image_size[0] / 1280.0)
        per.append({"frame": name, "raw": dy_stats(pl, pr, scale),
                    "rectified": dy_stats(rect.rectify_points(pl, "left", rig), rect.rectify_points(pr, "right", rig), scale)})
    if not per:
        raise InputError("calib-check: no frames to check")
    pl = np.concatenate(all_l) if all_l else np.zeros((0, 2))
    pr = np.concatenate(all_r) if all_r else np.zeros((0, 2))
    out = verdict_from_matches(pl, pr, rig, config)
    out["frames"] = per
    return out
