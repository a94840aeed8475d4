"""Disparity stage: rectified stereo pair -> sub-pixel disparity (px) -> metric depth (m).

Semi-global matching (OpenCV ``StereoSGBM``, Hirschmüller 2008) tuned for HD720 ZED frames,
then left-right consistency, speckle removal, optional WLS smoothing, background hole filling
and a median filter. Disparities follow the Middlebury/OpenCV convention
``x_right = x_left - d`` (positive for a right eye to the right of the left eye).

The Middlebury evaluation helpers (PFM reader, ``calib.txt`` parser, bad-pixel rate) live in
:mod:`stereo_recon.evaluation`.

Measured on the four Middlebury 2014 quarter-size training scenes (bad-2.0, holes counted as
bad, non-occluded mask; ``benchmarks/bench_depth.py``): plain SGBM 19.0 %, preset ``fast``
11.1 %, ``balanced`` 10.7 %, ``quality`` 9.9 %, ``wls`` 12.2 %.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, fields, replace

import numpy as np

from stereo_recon.core.errors import ConfigError, InputError

log = logging.getLogger(__name__)

_MODES = {"sgbm": 0, "hh": 1, "sgbm3way": 2, "hh4": 3}  # cv2.STEREO_SGBM_MODE_* values


@dataclass(frozen=True)
class DisparityConfig:
    """Every parameter of the disparity stage (defaults = preset ``balanced``)."""

    # Disparity search range [min, min + num) px; num is rounded up to a multiple of 16 (SGBM needs it).
    # Derive it from the depth range with ``disparity_range_for_depth`` (d = f * B / Z).
    min_disparity_px: int = 0
    num_disparities_px: int = 128
    # Matching window (odd). 3 keeps thin structures (truck edges, mirrors); 5-7 is smoother on weak texture.
    block_size_px: int = 3
    # Smoothness penalties as multiples of channels * block_size^2 (OpenCV's recommended scaling).
    p1_per_px: int = 8
    p2_per_px: int = 32
    # SGBM path mode: "sgbm3way" (fast, 3 directions in one pass), "sgbm" (5 paths), "hh" (8 paths, full), "hh4".
    mode: str = "sgbm3way"
    # Best cost must beat the second best by this margin (%), else invalid.
    uniqueness_pct: int = 10
    # SGBM's built-in left-right check (max |d_left - d_right| px, from the same cost volume; < 0 disables).
    disp12_max_diff_px: int = 1
    # Separate right-matcher consistency check (px); None = off (it doubles the matching time).
    lr_check_px: float | None = None
    # Clip of the x-Sobel pre-filter applied by SGBM (1..63; 0 = OpenCV's default).
    pre_filter_cap: int = 63
    # Speckle filter: connected regions smaller than this (px) whose disparity varies less than range px are removed.
    speckle_window_px: int = 200
    speckle_range_px: int = 1
    # Match on colour (3 channels) instead of grey; grey was as good on Middlebury and 40 % faster.
    use_color: bool = False
    # Weighted-least-squares filter (ximgproc); None = off. Needs the right matcher (doubles the time).
    wls_lambda: float | None = None
    wls_sigma_color: float = 1.5
    # After WLS, pixels with WLS confidence (0..255) below this become invalid; None keeps all.
    wls_min_confidence: float | None = None
    # Fill invalid pixels along each row with the lower (background) of the two neighbouring valid
    # disparities: occlusions are background surfaces, so this is right far more often than not.
    fill_holes: bool = True
    # Fill only gaps up to this width (px); None fills every gap (including the left border band).
    fill_max_px: int | None = None
    # Gaps whose ends differ by at most this (px, + 0.1 px per px of gap) lie on one surface and are
    # interpolated, not filled with the farther end (None: always the farther end).
    fill_same_surface_px: float | None = 1.0
    # Fill a run with its farther end only when the run is no wider than the disparity step across it plus
    # this slack (px): an occlusion's width is that step; a wider run is unmatched surface (plain paint),
    # which the farther end would put behind the truck (None: any run up to fill_max_px).
    fill_occlusion_slack_px: float | None = None
    # Pixels whose texture the image noise drowns are invalid before the fill: the x-gradient's RMS over
    # texture_window_px (odd) below min_texture_snr x the noise's own (sigma estimated per image, Immerkaer
    # 1996). Why: on plain paint (a black roof: contrast under a grey level) SGBM's paths carry the disparity
    # in from where they enter the region, often the background's, which puts the panel behind the truck
    # and carves the fused surface there. None: off.
    min_texture_snr: float | None = None
    texture_window_px: int = 9
    # Median filter on the final map (0 = off, 3 or 5; OpenCV supports only these for float images).
    median_px: int = 5
    # Sub-pixel refinement window (odd px; None = off): a Lucas-Kanade fit of the disparity (plus a
    # brightness offset) over this window around each SGBM match. SGBM's parabola interpolation
    # locks towards integers (0.11 px off between integers on a textured plane; 0.04 px after the
    # fit). Where a window has too little horizontal gradient (plain paint) it changes nothing.
    subpixel_window_px: int | None = 9
    # Gauss-Newton steps of that fit, and the largest total change it may make (px).
    subpixel_iterations: int = 1
    subpixel_max_step_px: float = 1.0

    def __post_init__(self) -> None:
        if self.mode not in _MODES:
            raise ConfigError(f"disparity mode {self.mode!r}: expected one of {sorted(_MODES)}")
        if self.block_size_px < 1 or self.block_size_px % 2 == 0:
            raise ConfigError(f"block_size_px={self.block_size_px}: must be a positive odd number")
        if self.num_disparities_px < 16:
            raise ConfigError(f"num_disparities_px={self.num_disparities_px}: must be >= 16")
        if self.subpixel_window_px is not None and (self.subpixel_window_px < 3 or self.subpixel_window_px % 2 == 0):
            raise ConfigError(f"subpixel_window_px={self.subpixel_window_px}: must be an odd number >= 3 (or None)")
        if self.median_px not in (0, 1, 3, 5):
            raise ConfigError(f"median_px={self.median_px}: must be 0, 3 or 5")
        if self.min_texture_snr is not None and not self.min_texture_snr > 0:
            raise ConfigError(f"min_texture_snr={self.min_texture_snr}: must be > 0 (or None)")
        if self.texture_window_px < 3 or self.texture_window_px % 2 == 0:
            raise ConfigError(f"texture_window_px={self.texture_window_px}: must be an odd number >= 3")
        if self.fill_occlusion_slack_px is not None and not self.fill_occlusion_slack_px >= 0:
            raise ConfigError(f"fill_occlusion_slack_px={self.fill_occlusion_slack_px}: must be >= 0 (or None)")
        if not 0 <= self.pre_filter_cap <= 63:
            raise ConfigError(f"pre_filter_cap={self.pre_filter_cap}: must be in 0..63")

    @property
    def num_disparities_16(self) -> int:
        """``num_disparities_px`` rounded up to a multiple of 16."""
        return int(math.ceil(self.num_disparities_px / 16.0) * 16)


# Named presets. Timings are relative to bare cv2 SGBM (3-way, block 5, colour) on the same frames.
PRESETS: dict[str, dict] = {
    # No median; SGBM's internal LR check only; fill holes. Cheapest.
    "fast": dict(block_size_px=3, mode="sgbm3way", median_px=0, speckle_window_px=100, speckle_range_px=2,
                 subpixel_window_px=None),
    # The default: grey 3-way SGBM, block 3, speckle 200/1, background fill + 5x5 median.
    "balanced": dict(),
    # 4-path full-resolution dynamic programming (HH4): ~2x slower, ~1 point better on Middlebury.
    "quality": dict(mode="hh4"),
    # Plain OpenCV SGBM as in the reference numbers (3-way, block 5, colour, P1=8*3*25, P2=32*3*25,
    # uniqueness 10, speckle 100/2, disp12MaxDiff 1), no post-processing: the baseline to beat.
    "plain": dict(block_size_px=5, use_color=True, pre_filter_cap=0, speckle_window_px=100, speckle_range_px=2,
                  fill_holes=False, median_px=0, subpixel_window_px=None),
    # WLS-smoothed (ximgproc, right matcher + confidence): smoother surfaces, 2x the matching time,
    # 12.2 % on Middlebury (worse than "balanced": WLS smears across occlusion boundaries).
    "wls": dict(wls_lambda=2000.0, wls_sigma_color=1.5),
}


def preset(name: str, **overrides) -> DisparityConfig:
    """The named preset (``fast``, ``balanced``, ``quality``, ``plain``, ``wls``) with field overrides."""
    if name not in PRESETS:
        raise ConfigError(f"disparity preset {name!r}: expected one of {sorted(PRESETS)}")
    known = {f.name for f in fields(DisparityConfig)}
    unknown = set(overrides) - known
    if unknown:
        raise ConfigError(f"disparity config: unknown key(s) {sorted(unknown)}")
    cfg = DisparityConfig(**PRESETS[name])
    return replace(cfg, **overrides) if overrides else cfg


def disparity_range_for_depth(focal_px: float, baseline_m: float, min_depth_m: float, max_depth_m: float,
                              max_num_disparities: int = 256) -> tuple[int, int]:
    """Disparity search range ``(min_disparity_px, num_disparities_px)`` covering depths [min, max] m.

    d = f * B / Z; the range is rounded outwards and ``num`` to a multiple of 16. When the range
    would exceed ``max_num_disparities`` the near limit is raised (logged), never the far one.
    """
    if not (focal_px > 0 and baseline_m > 0 and 0 < min_depth_m < max_depth_m):
        raise ConfigError(f"disparity range: need focal_px>0, baseline_m>0, 0<min_depth_m<max_depth_m "
                          f"(got {focal_px}, {baseline_m}, {min_depth_m}, {max_depth_m})")
    fb = focal_px * baseline_m
    d_min = max(0, int(math.floor(fb / max_depth_m)) - 1)
    d_max = int(math.ceil(fb / min_depth_m)) + 1
    num = int(math.ceil((d_max - d_min) / 16.0) * 16)
    if num > max_num_disparities:
        num = int(max_num_disparities // 16 * 16)
        log.warning("disparity range capped at %d px: depths below %.2f m are not matched",
                    num, fb / (d_min + num))
    return d_min, max(16, num)


def make_matcher(config: DisparityConfig, channels: int = 1):
    """The ``cv2.StereoSGBM`` matcher for ``config`` (``channels`` = 1 grey, 3 colour)."""
    import cv2

    b = config.block_size_px
    return cv2.StereoSGBM_create(
        minDisparity=int(config.min_disparity_px),
        numDisparities=config.num_disparities_16,
        blockSize=b,
        P1=config.p1_per_px * channels * b * b,
        P2=config.p2_per_px * channels * b * b,
        disp12MaxDiff=int(config.disp12_max_diff_px),
        preFilterCap=int(config.pre_filter_cap),
        uniquenessRatio=int(config.uniqueness_pct),
        speckleWindowSize=int(config.speckle_window_px),
        speckleRange=int(config.speckle_range_px),
        mode=_MODES[config.mode],
    )


def _prepare(img: np.ndarray, use_color: bool) -> np.ndarray:
    import cv2

    if img.dtype != np.uint8:
        raise InputError(f"disparity: images must be uint8, got {img.dtype}")
    if img.ndim == 2:
        return img
    if use_color:
        return img
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def fill_holes_background(disp_px: np.ndarray, max_gap_px: int | None = None,
                          same_surface_px: float | None = None, occlusion_slack_px: float | None = None) -> np.ndarray:
    """Fill NaN runs in each row with the smaller of the two bounding valid disparities.

    disp_px: (H, W) float32, NaN = invalid. Occluded pixels belong to the background, which
    has the smaller disparity, so taking the lower neighbour is the classic occlusion fill.
    Runs longer than ``max_gap_px`` (None = no limit) stay NaN. When ``same_surface_px`` is
    given, a run whose two neighbours differ by at most that plus 0.1 px per px of run length
    (one surface, e.g. unmatched weak texture on a slanted panel, not an occlusion) is filled
    by linear interpolation instead: the lower neighbour would put the whole run too far. When
    ``occlusion_slack_px`` is given, a run is filled with the lower neighbour only when it is no wider
    than the two neighbours' difference plus that slack (an occlusion's width); wider runs stay NaN.
    Returns a new array.
    """
    d = np.asarray(disp_px, dtype=np.float32)
    h, w = d.shape
    valid = np.isfinite(d)
    holes = np.flatnonzero(~valid)
    if holes.size == 0 or holes.size == d.size:
        return d.copy()
    # Column of the nearest valid pixel to the left / right of every pixel (-1 / w: none); int16 when
    # the width allows (half the memory traffic of int32: this scan is most of the function's time).
    it = np.int16 if w < 32767 else np.int32
    cols = np.arange(w, dtype=it)
    left = np.where(valid, cols, it(-1))
    np.maximum.accumulate(left, axis=1, out=left)
    right = np.where(valid, cols, it(w))[:, ::-1]
    np.minimum.accumulate(right, axis=1, out=right)
    right = right[:, ::-1]
    # Gather only at the holes (typically 10-20 % of the pixels).
    lc = left.ravel()[holes].astype(np.int64)
    rc = right.ravel()[holes].astype(np.int64)
    if max_gap_px is not None:  # runs too long to fill (run length between the two valid neighbours)
        short = (rc - lc - 1) <= max_gap_px
        holes, lc, rc = holes[short], lc[short], rc[short]
    row0 = holes - holes % w
    flat = d.ravel()
    d_left = np.where(lc >= 0, flat[row0 + np.maximum(lc, 0)], np.inf)
    d_right = np.where(rc < w, flat[row0 + np.minimum(rc, w - 1)], np.inf)
    fill = np.minimum(d_left, d_right)
    with np.errstate(invalid="ignore"):  # inf - inf where a run touches the border
        step = d_right - d_left
    one = np.zeros(len(holes), bool)
    if same_surface_px is not None:
        gap = (rc - lc).astype(np.float32)
        t = ((holes % w) - lc).astype(np.float32) / np.maximum(gap, 1.0)
        with np.errstate(invalid="ignore"):
            one = np.isfinite(step) & (np.abs(step) <= same_surface_px + 0.1 * gap)
        fill = np.where(one, d_left + t * np.where(one, step, 0.0), fill)
    if occlusion_slack_px is not None:
        with np.errstate(invalid="ignore"):
            occl = one | ~np.isfinite(step) | ((rc - lc - 1) <= np.abs(step) + occlusion_slack_px)
        fill = np.where(occl, fill, np.nan)
    fill[~np.isfinite(fill)] = np.nan
    out = d.copy()
    out.ravel()[holes] = fill
    return out


def image_noise_sigma(img: np.ndarray) -> float:
    """The image's noise sigma (grey levels), Immerkaer's (1996) Laplacian-difference estimate.

    img: (H, W) grey or (H, W, 3) BGR (converted to grey). Robust to edges and texture because the
    3x3 kernel cancels locally linear intensity; the estimate is the mean absolute response scaled.
    """
    import cv2

    g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(g.astype(np.float32), -1, k)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2.0) / 6.0 * np.mean(np.abs(r)))


def texture_snr(img: np.ndarray, window_px: int = 9) -> np.ndarray:
    """Per pixel, the RMS of the x-gradient (3x3 Sobel) over window_px x window_px divided by the RMS the
    image noise alone gives it (sqrt(12) sigma): ~1 on plain paint, >> 1 where there is texture to match.

    img: (H, W) grey or (H, W, 3) BGR. Returns (H, W) float32.
    """
    import cv2

    g = (img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)).astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
    e = cv2.boxFilter(gx * gx, -1, (int(window_px), int(window_px)))
    sigma = max(image_noise_sigma(g), 0.25)   # a noiseless image: a quarter grey level (8-bit quantisation)
    return np.sqrt(np.maximum(e, 0.0)) / np.float32(np.sqrt(12.0) * sigma)


def _median_valid(d: np.ndarray, k: int) -> np.ndarray:
    """k x k median of a float map that keeps NaN where the input is NaN (NaN treated as 0 inside)."""
    import cv2

    filled = np.array(d, dtype=np.float32, copy=True)
    cv2.patchNaNs(filled, 0.0)
    out = cv2.medianBlur(filled, k)
    out[np.isnan(d)] = np.nan
    return out


def _right_disparity(matcher, left: np.ndarray, right: np.ndarray):
    """Right-view disparity (int16, x16) and the right matcher, via ximgproc."""
    import cv2

    rm = cv2.ximgproc.createRightMatcher(matcher)
    return rm.compute(right, left), rm


def disparity_map(left_rect_gray: np.ndarray, right_rect_gray: np.ndarray,
                  config: DisparityConfig = DisparityConfig()) -> np.ndarray:
    """Disparity of the left rectified image, float32 px (sub-pixel, 1/16 px steps), NaN = invalid.

    left_rect_gray, right_rect_gray: (H, W) grey or (H, W, 3) BGR uint8, rectified (epipolar
    lines are rows). Colour input is converted to grey unless ``config.use_color``.
    """
    if left_rect_gray.shape != right_rect_gray.shape:
        raise InputError(f"disparity: left {left_rect_gray.shape} and right {right_rect_gray.shape} differ in shape")
    left = _prepare(left_rect_gray, config.use_color)
    right = _prepare(right_rect_gray, config.use_color)
    channels = 1 if left.ndim == 2 else left.shape[2]
    matcher = make_matcher(config, channels)
    raw = matcher.compute(left, right)
    invalid_raw = raw < (config.min_disparity_px * 16)  # SGBM writes (minDisparity - 1) * 16 for invalid

    if config.wls_lambda is not None:
        import cv2

        raw_right, _ = _right_disparity(matcher, left, right)
        wls = cv2.ximgproc.createDisparityWLSFilter(matcher)
        wls.setLambda(float(config.wls_lambda))
        wls.setSigmaColor(float(config.wls_sigma_color))
        guide = left_rect_gray
        filtered = wls.filter(raw, guide, disparity_map_right=raw_right)
        disp = filtered.astype(np.float32) / 16.0
        disp[filtered < config.min_disparity_px * 16] = np.nan
        if config.wls_min_confidence is not None:
            disp[wls.getConfidenceMap() < config.wls_min_confidence] = np.nan
    else:
        disp = raw.astype(np.float32)
        disp *= np.float32(1.0 / 16.0)
        disp[invalid_raw] = np.nan
        if config.lr_check_px is not None:
            raw_right, _ = _right_disparity(matcher, left, right)
            disp = _lr_consistency(disp, raw_right.astype(np.float32) / -16.0, config.lr_check_px)

    if config.subpixel_window_px is not None:
        disp = refine_subpixel(left, right, disp, config.subpixel_window_px, config.subpixel_iterations,
                               config.subpixel_max_step_px)
    if config.min_texture_snr is not None:
        disp[texture_snr(left_rect_gray, config.texture_window_px) < config.min_texture_snr] = np.nan
    if config.fill_holes:
        disp = fill_holes_background(disp, config.fill_max_px, config.fill_same_surface_px, config.fill_occlusion_slack_px)
    if config.median_px in (3, 5):
        disp = _median_valid(disp, config.median_px)
    return disp


@functools.lru_cache(maxsize=4)
def _pixel_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Column and row coordinates (H, W) float32 of every pixel (cached: built once per image size)."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    xs.flags.writeable = False
    ys.flags.writeable = False
    return xs, ys


def refine_subpixel(left: np.ndarray, right: np.ndarray, disp_px: np.ndarray, window_px: int = 9,
                    iterations: int = 1, max_step_px: float = 1.0) -> np.ndarray:
    """Refine a disparity map to sub-pixel accuracy by a windowed Lucas-Kanade fit along the rows.

    left, right: rectified (H, W) grey or (H, W, 3) uint8 images; disp_px: (H, W) float32 left
    disparity (px, x_right = x_left - d), NaN = invalid. Per pixel, minimises
    sum_window (L(x) - R(x - d) - b)^2 over d and a brightness offset b, starting at the SGBM
    value. Pixels whose window straddles a disparity step (> 1.5 px range), has too little
    horizontal gradient, or would move by more than ``max_step_px`` keep their input value.
    Returns a new float32 map (NaN where the input is NaN).

    Written by hand because OpenCV offers no refinement of a given disparity map against the
    images (its ximgproc filters smooth disparities; they do not re-fit them to the data).
    """
    import cv2

    L = (cv2.cvtColor(left, cv2.COLOR_BGR2GRAY) if left.ndim == 3 else left).astype(np.float32)
    R = (cv2.cvtColor(right, cv2.COLOR_BGR2GRAY) if right.ndim == 3 else right).astype(np.float32)
    d0 = np.asarray(disp_px, dtype=np.float32)
    valid = np.isfinite(d0)
    if not valid.any():
        return d0.copy()
    h, w = d0.shape
    k = (int(window_px), int(window_px))
    gx = cv2.Sobel(R, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)  # central difference, per px
    # cv2 arithmetic and uint8 masks (SIMD, threaded) throughout: numpy temporaries on full frames
    # cost as much here as the fit itself.
    def patched(value: float) -> np.ndarray:
        a = d0.copy()
        cv2.patchNaNs(a, value)
        return a

    # Disparity range within the window: refine only where the window sees one surface.
    kernel = np.ones(k, np.uint8)
    spread = cv2.subtract(cv2.dilate(patched(-1e6), kernel), cv2.erode(patched(1e6), kernel))
    ok = cv2.bitwise_and(cv2.compare(spread, 1.5, cv2.CMP_LE), cv2.compare(d0, d0, cv2.CMP_EQ))  # NaN != NaN
    n = float(k[0] * k[1])
    xs, ys = _pixel_grid(h, w)
    d = patched(0.0)
    d_start = d.copy()
    box = functools.partial(cv2.boxFilter, ddepth=-1, ksize=k, normalize=False)
    for _ in range(max(int(iterations), 0)):
        mx = cv2.subtract(xs, d)
        g = cv2.remap(gx, mx, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        e = cv2.subtract(L, cv2.remap(R, mx, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
        # Residual e + g*delta - b; normal equations of (delta, b), window sums by box filters.
        sgg, sg = box(cv2.multiply(g, g)), box(g)
        sge, se = box(cv2.multiply(g, e)), box(e)
        det = cv2.addWeighted(sgg, n, cv2.multiply(sg, sg), -1.0, 0.0)  # >= 0 (Cauchy-Schwarz)
        num = cv2.addWeighted(cv2.multiply(sg, se), 1.0, sge, -n, 0.0)
        strong = cv2.compare(det, n * n * 4.0, cv2.CMP_GT)  # mean centred gradient^2 >= 4 (grey levels/px)^2
        delta = cv2.divide(num, cv2.max(det, 1.0))
        cv2.copyTo(cv2.add(d, delta), cv2.bitwise_and(ok, strong), d)
        ok = cv2.bitwise_and(ok, cv2.compare(cv2.absdiff(d, d_start), max_step_px, cv2.CMP_LE))
    out = d0.copy()  # NaN stays NaN: ok is 0 there
    cv2.copyTo(d, ok, out)
    return out


def _lr_consistency(disp_left: np.ndarray, disp_right: np.ndarray, max_diff_px: float) -> np.ndarray:
    """Invalidate left disparities whose match in the right view disagrees by more than max_diff_px."""
    h, w = disp_left.shape
    dl = np.nan_to_num(disp_left, nan=0.0)
    xr = np.clip(np.rint(np.arange(w)[None, :] - dl).astype(np.int64), 0, w - 1)
    dr = disp_right[np.arange(h)[:, None], xr]
    out = disp_left.copy()
    out[~(np.abs(dr - disp_left) <= max_diff_px)] = np.nan
    return out


def depth_from_disparity(disp_px: np.ndarray, focal_px: float, baseline_m: float,
                         min_depth_m: float = 0.3, max_depth_m: float = 20.0) -> np.ndarray:
    """Metric depth Z = f * B / d (m), float32, NaN where invalid or outside [min, max] m.

    disp_px: (H, W) disparity of the left rectified image in px (NaN = invalid); focal_px the
    rectified focal length; baseline_m the stereo baseline. Defaults are the ZED2's range.
    """
    d = np.asarray(disp_px, dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.float32(focal_px * baseline_m) / d
    z[~(d > 0)] = np.nan
    z[(z < min_depth_m) | (z > max_depth_m)] = np.nan
    return z
