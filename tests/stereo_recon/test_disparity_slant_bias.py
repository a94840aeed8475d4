"""Depth on weakly textured panels seen at a slant (issue 12's third failure mode), on a pair built
to show it: a plane whose disparity grows down the image (a roof or the ground seen from above),
painted with a texture of 2 % contrast, 3 DN of pixel noise."""

import cv2
import numpy as np
import pytest

from stereo_recon.disparity import disparity_map, preset

H, W, D0 = 360, 480, 20.0


def _slanted_pair(seed: int, contrast: float, gy: float):
    """Left/right uint8 images of a plane with disparity D0 + gy (y - H/2) px, and that disparity."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0, 1, (H, 2 * W)).astype(np.float32), (0, 0), 2.0)
    tex = 128 + contrast * 128 * tex / tex.std()
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    d = D0 + gy * (y - H / 2)
    left = cv2.remap(tex, x + W / 2, y, cv2.INTER_CUBIC)
    right = cv2.remap(tex, x + d + W / 2, y, cv2.INTER_CUBIC)   # right pixel x sees the left point x + d
    noisy = [np.clip(im + rng.normal(0, 3.0, im.shape), 0, 255).astype(np.uint8) for im in (left, right)]
    return noisy[0], noisy[1], d


def _median_error_px(contrast: float, gy: float, config) -> float:
    errs = []
    for seed in range(3):
        left, right, d = _slanted_pair(seed, contrast, gy)
        disp = disparity_map(left, right, config)
        ok = np.isfinite(disp)
        ok[:, :80] = False   # the left band has no match
        errs.append(float(np.median(disp[ok] - d[ok])))
    return float(np.mean(errs))


def test_textured_slanted_plane_is_unbiased():
    """With 20 % contrast the default matcher places a slanted plane within 0.02 px."""
    cfg = preset("balanced", num_disparities_px=64)
    for gy in (0.05, -0.05):
        assert abs(_median_error_px(0.2, gy, cfg)) < 0.02


@pytest.mark.xfail(strict=True, reason=(
    "known (2026-11-24): 3-path SGBM (the default 'balanced' preset) drags a weakly textured plane whose "
    "disparity grows downwards towards the rows above it: -0.17 px at 2 % contrast (+0.07 px when it "
    "falls). 4-path 'quality' (hh4) leaves -0.05 px here, but on 5 tuning draws it made the measured "
    "dimensions worse end to end (mean 3.24 -> 4.84 %), so the default stays"))
def test_weakly_textured_slanted_plane_is_unbiased():
    cfg = preset("balanced", num_disparities_px=64)
    for gy in (0.05, -0.05):
        assert abs(_median_error_px(0.02, gy, cfg)) < 0.05
