"""Disparity stage: analytic shifts, hole filling, depth conversion, and Middlebury 2014 bad-2.0 vs plain SGBM."""

from __future__ import annotations

import numpy as np
import pytest

from stereo_recon.disparity import (
    DisparityConfig,
    depth_from_disparity,
    disparity_map,
    disparity_range_for_depth,
    fill_holes_background,
    image_noise_sigma,
    preset,
    texture_snr,
)
from stereo_recon.core.errors import ConfigError
from stereo_recon.evaluation import bad_pixel_rate, load_middlebury_2014

SCENES = ("Adirondack", "Motorcycle", "Piano", "Playtable")


def _textured(rng, h=120, w=200):
    import cv2

    img = rng.integers(0, 256, (h // 4, w // 4), dtype=np.uint8)
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_CUBIC)


def test_constant_shift_recovered_subpixel(rng):
    # Right image = left shifted by a known sub-pixel disparity (linear interpolation of a smooth texture).
    import cv2

    d_true = 12.5
    left = _textured(rng, 160, 320)
    M = np.float32([[1, 0, -d_true], [0, 1, 0]])
    right = cv2.warpAffine(left, M, (320, 160), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    for name in ("fast", "balanced", "quality"):
        d = disparity_map(left, right, preset(name, num_disparities_px=32))
        core = d[20:-20, 60:-20]
        assert np.isfinite(core).mean() > 0.98, name
        # SGBM's sub-pixel (parabola, 1/16 px steps) is biased towards integers by < 0.25 px on a smooth texture.
        assert abs(np.nanmedian(core) - d_true) < 0.25, name


def test_fill_holes_takes_background():
    d = np.array([[5.0, np.nan, np.nan, 9.0, np.nan, 3.0, np.nan]], np.float32)
    out = fill_holes_background(d)
    np.testing.assert_allclose(out, [[5, 5, 5, 9, 3, 3, 3]])
    limited = fill_holes_background(d, max_gap_px=1)
    np.testing.assert_allclose(limited[0, [0, 3, 4, 5, 6]], [5, 9, 3, 3, 3])
    assert np.isnan(limited[0, 1:3]).all()


def test_fill_occlusion_only_as_wide_as_the_step():
    # A run as wide as the disparity step across it is an occlusion (the background's); a wider run is
    # unmatched surface and stays invalid; a run between two ends on one surface is interpolated.
    d = np.array([[10.0] + [np.nan] * 6 + [5.0, np.nan, np.nan, 9.0, np.nan, np.nan, 9.4]], np.float32)
    out = fill_holes_background(d, same_surface_px=1.0, occlusion_slack_px=0.0)
    assert np.isnan(out[0, 1:7]).all()                  # 6 px between 10 and 5: wider than the 5 px step
    np.testing.assert_allclose(out[0, 8:10], [5, 5])    # 2 px between 5 and 9: an occlusion, the background
    np.testing.assert_allclose(out[0, 11:13], [9.0 + 0.4 / 3, 9.0 + 0.8 / 3], rtol=1e-5)  # one surface
    np.testing.assert_allclose(fill_holes_background(d, occlusion_slack_px=1.0)[0, 1:7], 5.0)  # 6 <= 5 + 1


def _plain_panel_pair(rng, sigma=1.5, d_bg=6, d_fg=16):
    """A textured background at d_bg px with a plain panel (one grey level) at d_fg px in front of it,
    both eyes with pixel noise sigma: (left, right, panel's core slice)."""
    import cv2

    h, w = 160, 320
    small = rng.integers(0, 256, (h // 4, (w + 64) // 4), dtype=np.uint8)
    bg = cv2.resize(small, (w + 64, h), interpolation=cv2.INTER_CUBIC).astype(np.float32)
    left, right = bg[:, 32:32 + w].copy(), bg[:, 32 + d_bg:32 + d_bg + w].copy()
    left[40:120, 120:220] = 20.0
    right[40:120, 120 - d_fg:220 - d_fg] = 20.0
    noisy = lambda a: np.clip(a + rng.normal(0, sigma, a.shape), 0, 255).astype(np.uint8)  # noqa: E731
    return noisy(left), noisy(right), (slice(50, 110), slice(125, 215))


def test_texture_snr_tells_plain_paint_from_texture(rng):
    left, _, core = _plain_panel_pair(rng, sigma=1.5)
    assert abs(image_noise_sigma(left) - 1.5) < 0.5
    snr = texture_snr(left)
    assert np.median(snr[core]) < 1.5            # noise only
    assert np.median(snr[50:110, 20:100]) > 10   # the background's texture


def test_plain_panel_is_not_put_behind_itself(rng):
    # SGBM's paths carry the background's disparity into a plain panel: without the texture test a
    # fifth of it lands behind (farther than) the panel; with it, no pixel of the panel does.
    left, right, core = _plain_panel_pair(rng)
    d_fg = 16
    off = disparity_map(left, right, preset("balanced", num_disparities_px=32, fill_max_px=32))
    on = disparity_map(left, right, preset("balanced", num_disparities_px=32, fill_max_px=32, min_texture_snr=2.0,
                                           fill_occlusion_slack_px=3.0))
    assert np.mean(off[core] < d_fg - 1) > 0.1
    assert np.mean(on[core] < d_fg - 1) < 0.01
    textured = (slice(50, 110), slice(40, 100))
    assert np.isfinite(on[textured]).mean() > 0.98 and abs(np.nanmedian(on[textured]) - 6) < 0.3


def test_depth_from_disparity_and_range():
    d = np.array([[70.0, 7.0, 0.0, np.nan, 700.0]], np.float32)
    z = depth_from_disparity(d, focal_px=700.0, baseline_m=0.12, min_depth_m=0.3, max_depth_m=20.0)
    np.testing.assert_allclose(z[0, :2], [1.2, 12.0], rtol=1e-6)
    assert np.isnan(z[0, 2:]).all()  # zero, NaN, and 0.12 m (< 0.3 m) are invalid
    lo, num = disparity_range_for_depth(700.0, 0.12, 0.5, 20.0)
    assert lo <= 700 * 0.12 / 20 and lo + num >= 700 * 0.12 / 0.5 and num % 16 == 0
    lo, num = disparity_range_for_depth(700.0, 0.12, 0.01, 20.0, max_num_disparities=128)
    assert num == 128


def test_config_validation():
    with pytest.raises(ConfigError):
        DisparityConfig(block_size_px=4)
    with pytest.raises(ConfigError):
        preset("nope")
    with pytest.raises(ConfigError, match="unknown"):
        preset("fast", blocksize=3)
    assert DisparityConfig(num_disparities_px=70).num_disparities_16 == 80


@pytest.mark.realdata
def test_middlebury_2014_better_than_plain_sgbm(shared_data):
    """bad-2.0 (holes bad, non-occluded mask) on the 4 quarter-size scenes: ours vs plain SGBM in the same run.

    NOTES measured plain SGBM at 19.0 % average; our 'balanced' preset measured 10.8 %. The bound
    12 % is the issue's target; per scene ours must beat plain by >= 2 points (measured: 5-11).
    """
    ours, plain = [], []
    for scene in SCENES:
        pair = load_middlebury_2014(shared_data / "middlebury" / f"2014_{scene}_Q")
        kw = dict(num_disparities_px=pair.ndisp)
        e_plain = bad_pixel_rate(disparity_map(pair.left, pair.right, preset("plain", **kw)), pair.gt_disp_px,
                                 pair.nonocc_mask)
        e_ours = bad_pixel_rate(disparity_map(pair.left, pair.right, preset("balanced", **kw)), pair.gt_disp_px,
                                pair.nonocc_mask)
        assert e_ours["bad_pct"] < e_plain["bad_pct"] - 2.0, scene
        assert e_ours["density_pct"] > 99.0  # holes filled (they count as bad)
        ours.append(e_ours["bad_pct"])
        plain.append(e_plain["bad_pct"])
    # The plain reference reproduces the NOTES figure (19.0 %), so the comparison is the published one.
    assert np.mean(plain) == pytest.approx(19.0, abs=0.3)
    assert np.mean(ours) < np.mean(plain)
    assert np.mean(ours) <= 12.0


@pytest.mark.realdata
def test_lr_check_and_wls_on_real_pair(shared_data):
    """The right-matcher LR check removes mostly wrong pixels; WLS gives a dense map better than plain SGBM."""
    pair = load_middlebury_2014(shared_data / "middlebury" / "2014_Adirondack_Q")
    base = preset("balanced", num_disparities_px=pair.ndisp, fill_holes=False, median_px=0)
    raw = disparity_map(pair.left, pair.right, base)
    checked = disparity_map(pair.left, pair.right, preset("balanced", num_disparities_px=pair.ndisp, fill_holes=False,
                                                          median_px=0, lr_check_px=1.0))
    m = pair.nonocc_mask & np.isfinite(pair.gt_disp_px)

    def wrong_among_valid(d):
        v = m & np.isfinite(d)
        return float((np.abs(d[v] - pair.gt_disp_px[v]) > 2).mean()), int(v.sum())

    w_raw, n_raw = wrong_among_valid(raw)
    w_chk, n_chk = wrong_among_valid(checked)
    assert n_chk < n_raw  # the check removes pixels ...
    assert w_chk < w_raw  # ... and the remaining ones are more often right
    plain = bad_pixel_rate(disparity_map(pair.left, pair.right, preset("plain", num_disparities_px=pair.ndisp)),
                           pair.gt_disp_px, pair.nonocc_mask)
    wls = bad_pixel_rate(disparity_map(pair.left, pair.right, preset("wls", num_disparities_px=pair.ndisp)),
                         pair.gt_disp_px, pair.nonocc_mask)
    assert wls["density_pct"] > 99.0 and wls["bad_pct"] < plain["bad_pct"]
