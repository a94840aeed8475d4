"""Motion stereo: a textured slanted plane seen from two poses of one camera, exact depth known.

View b is rendered from view a through the plane's homography H = K (R + t n^T / d) K^-1 (X_b = R X_a + t),
so the only error sources are rectification from the poses and matching. Checks the pose conventions
(partner to the right and to the left: the mirrored path), the depth against the exact plane, and
that a wrong step length shows up in the ratio the trajectory is rescaled by.
"""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from stereo_recon.disparity import preset  # noqa: E402
from stereo_recon.core.errors import ConfigError  # noqa: E402
from stereo_recon.disparity import depth_from_disparity, disparity_map  # noqa: E402
from stereo_recon.motion_stereo import (MotionStereoConfig, motion_depth, partner_ok, rectify_motion_pair,  # noqa: E402
                                        rig_depth_for_scale, sparse_rig_ratios)
from stereo_recon.stages.motion import rig_scale, scale_view_indices  # noqa: E402

W, H, F = 640, 360, 500.0
K = np.array([[F, 0, W / 2 - 0.5], [0, F, H / 2 - 0.5], [0, 0, 1.0]])
Z0 = 5.0
N = np.array([-0.3, 0.1, 1.0])  # plane n . X = Z0 in camera a (slanted in x and y)
RIG_FB = F * 0.12  # a ZED2-like rig on the same camera (px m)


def _yaw(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _pose(R_wc: np.ndarray, c: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_wc, c
    return T


def _scene(centre_b, yaw_b_deg, seed=0):
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(size=(H, W)).astype(np.float32), (0, 0), 1.5)
    img_a = np.clip(128 + 60 * tex / tex.std(), 0, 255).astype(np.uint8)
    T_a = np.eye(4)
    T_b = _pose(_yaw(yaw_b_deg), np.asarray(centre_b, float))
    rel = np.linalg.inv(T_b) @ T_a  # X_b = R X_a + t
    Hab = K @ (rel[:3, :3] + np.outer(rel[:3, 3], N) / Z0) @ np.linalg.inv(K)
    img_b = cv2.warpPerspective(img_a, Hab, (W, H), flags=cv2.INTER_LINEAR)
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
    depth_a = (Z0 / (rays @ N)).astype(np.float32)  # z of the plane along each pixel of a
    return img_a, img_b, T_a, T_b, depth_a


def _exact_rect_depth(pair):
    u, v = np.meshgrid(np.arange(pair.size_px[0], dtype=float), np.arange(pair.size_px[1], dtype=float))
    rays_rect = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(pair.K_rect).T
    rays_cam = rays_rect @ pair.R_rect_a  # R_rect^T r for each row vector r
    return Z0 / (rays_cam @ N)


@pytest.mark.parametrize("side", [+1, -1])
def test_motion_depth_matches_the_plane(side):
    """Partner 0.6 m to the right (or left) and turned 3 deg towards the plane: depth within 0.3 %."""
    img_a, img_b, T_a, T_b, depth_a = _scene([side * 0.6, 0.02, 0.05], -side * 3.0)
    rng = np.random.default_rng(1)
    rig = depth_a * (1 + 0.02 * rng.standard_normal(depth_a.shape)).astype(np.float32)  # noisy rig depth
    rig[:, :100] = rig[:, -100:] = np.nan  # the rig sees only where b does (b is black past a's edges)
    cfg = MotionStereoConfig()
    assert partner_ok(T_a, T_b, Z0, cfg)
    pair = rectify_motion_pair(K, T_a, T_b, (W, H), (W, H))
    assert pair.partner_left == (side < 0)
    z, counts = motion_depth(img_a, img_b, rig, pair, preset("balanced"), cfg, RIG_FB, 20.0)
    exact = _exact_rect_depth(pair)
    inner = np.zeros(z.shape, bool)
    inner[40:-40, 100:-100] = True
    ok = inner & np.isfinite(z)
    assert ok.sum() > 0.8 * inner.sum()
    rel = z[ok] / exact[ok] - 1
    assert abs(np.median(rel)) < 0.001
    assert np.median(np.abs(rel)) < 0.003
    # The ratio odometry would be rescaled by: the rig's depth over the wide pair's, ~1 here.
    assert abs(counts["rig_ratio_median"] - 1) < 0.003


@pytest.mark.parametrize("short", [0.98, 0.90])
def test_a_short_step_shows_in_the_rig_ratio(short):
    """Odometry reporting the step 2 or 10 % short makes the wide depth as short; the rig's depth says so,
    and the run corrects both (within ``max_rescale``)."""
    img_a, img_b, T_a, T_b, depth_a = _scene([0.6, 0.0, 0.0], -3.0)
    T_short = T_b.copy()
    T_short[:3, 3] *= short
    pair = rectify_motion_pair(K, T_a, T_short, (W, H), (W, H))
    _, counts = motion_depth(img_a, img_b, depth_a, pair, preset("balanced"), MotionStereoConfig(), RIG_FB, 20.0)
    assert counts["rig_ratio_median"] == pytest.approx(1 / short, rel=0.003)
    assert abs(counts["rig_ratio_median"] - 1) <= MotionStereoConfig().max_rescale


def _far_views(z0: float, centres, seed: int = 0, noise: float = 2.0):
    """A textured slanted plane z0 m away (camera a's frame) seen from camera a and from cameras at the given
    centres (same orientation, m): their images (uint8, pixel noise noise DN) and a's exact depth (m)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(size=(H, W)).astype(np.float32), (0, 0), 1.2)
    img_a = np.clip(128 + 50 * tex / tex.std(), 0, 255).astype(np.float32)
    n = np.array([-0.2, 0.25, 1.0])  # n . X = z0: farther up the image, like a far view's ground
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
    depth_a = (z0 / (rays @ n)).astype(np.float32)
    out = []
    for c in centres:
        Hab = K @ (np.eye(3) + np.outer(-np.asarray(c, float), n) / z0) @ np.linalg.inv(K)
        img = cv2.warpPerspective(img_a, Hab, (W, H), flags=cv2.INTER_CUBIC)
        out.append(np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8))
    img_a = np.clip(img_a + rng.normal(0, noise, img_a.shape), 0, 255).astype(np.uint8)
    return img_a, out, depth_a


@pytest.mark.parametrize("seed", [0, 1])
def test_tracked_corners_measure_a_far_scenes_scale(seed):
    """A far view (the rig's disparity 2.4-4 px, as a full-scale orbit's): odometry's step 3 % long shows as
    a rig/wide ratio of 1/1.03 within 0.2 % from the tracked corners (``sparse_rig_ratios``), which have no
    pull towards whole pixels."""
    z0, baseline, step = 20.0, RIG_FB / F, 2.2
    img_a, (right, img_b), depth_a = _far_views(z0, [(baseline, 0, 0), (step, 0, 0)], seed)
    T_b_long = _pose(np.eye(3), [1.03 * step, 0, 0])
    ratios = sparse_rig_ratios(img_a, right, img_b, K, np.eye(4), T_b_long, RIG_FB, depth_a * 1.02,
                               MotionStereoConfig())
    assert len(ratios) > 300
    assert np.median(ratios) * 1.03 == pytest.approx(1.0, abs=0.002)


def test_tracked_corners_need_a_textured_view():
    """A plain view gives no corners, hence no ratio (the run then uses the other views)."""
    flat = np.full((H, W), 120, np.uint8)
    ratios = sparse_rig_ratios(flat, flat, flat, K, np.eye(4), _pose(np.eye(3), [2.0, 0, 0]), RIG_FB,
                               np.full((H, W), 20.0, np.float32), MotionStereoConfig())
    assert len(ratios) == 0


def test_partner_choice():
    cfg = MotionStereoConfig(baseline_rel=0.1, max_rotation_deg=20)
    T_a = np.eye(4)
    assert partner_ok(T_a, _pose(np.eye(3), [0.6, 0, 0]), 5.0, cfg)
    assert not partner_ok(T_a, _pose(np.eye(3), [0.3, 0, 0]), 5.0, cfg)  # too short for 5 m
    assert not partner_ok(T_a, _pose(np.eye(3), [0.2, 0, 0.6]), 5.0, cfg)  # mostly forward
    assert not partner_ok(T_a, _pose(np.eye(3), [0.1, 0.6, 0]), 5.0, cfg)  # mostly vertical
    assert not partner_ok(T_a, _pose(_yaw(25), [0.6, 0, 0]), 5.0, cfg)  # turned too far
    assert not partner_ok(T_a, _pose(np.eye(3), [0.6, 0, 0]), float("nan"), cfg)


def test_config_is_checked():
    with pytest.raises(ConfigError):
        MotionStereoConfig(baseline_rel=0)
    with pytest.raises(ConfigError):
        MotionStereoConfig(check_px=-1)
    with pytest.raises(ConfigError):
        MotionStereoConfig(scale_views=-1)
    with pytest.raises(ConfigError):
        MotionStereoConfig(scale_mode="census")


def _weak_ground_pair(seed: int, d0: float = 20.0, gy: float = 0.05, h: int = 360, w: int = 480):
    """A rig pair of weakly textured (2 % contrast, 3 DN noise) ground whose disparity grows down the image (px)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0, 1, (h, 2 * w)).astype(np.float32), (0, 0), 2.0)
    tex = 128 + 0.02 * 128 * tex / tex.std()
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    d = d0 + gy * (y - h / 2)
    left = cv2.remap(tex, x + w / 2, y, cv2.INTER_CUBIC)
    right = cv2.remap(tex, x + d + w / 2, y, cv2.INTER_CUBIC)
    left, right = (np.clip(im + rng.normal(0, 3.0, im.shape), 0, 255).astype(np.uint8) for im in (left, right))
    return left, right, d


def test_rematched_rig_depth_of_weak_ground_is_not_far():
    """The trajectory's scale is the rig's depth over the wide pairs': on ground like a far view's, the fused
    3-path depth reads 0.6-1.1 % far (what made far scenes' clouds too large); re-matched with 8 paths, < 0.3 %."""
    fb = 20.0  # px m: depth 1 m at the image's middle row
    cfg = preset("balanced", num_disparities_px=64)
    far3, far8 = [], []
    for seed in range(3):
        left, right, d = _weak_ground_pair(seed)
        z3 = depth_from_disparity(disparity_map(left, right, cfg), fb, 1.0, 1e-3, 1e6)
        z8 = rig_depth_for_scale(left, right, z3, cfg, MotionStereoConfig(scale_mode="hh"), fb)
        ok = np.isfinite(z3) & np.isfinite(z8)
        ok[:, :80] = False  # the band the right eye does not see
        assert ok.mean() > 0.6
        far3.append(np.median(z3[ok] * d[ok] / fb) - 1)
        far8.append(np.median(z8[ok] * d[ok] / fb) - 1)
    assert np.mean(far3) > 0.005
    assert abs(np.mean(far8)) < 0.003


def test_rig_scale_takes_the_rematched_views_when_there_are_enough():
    cfg = MotionStereoConfig()
    nan = float("nan")
    counts = [{"rig_ratio_median": 1.005, "rig_scale_ratio_median": r} for r in (1.0, 1.001, 0.999, nan, nan)]
    assert rig_scale(counts, cfg) == pytest.approx(1.0)
    # Fewer than 3 re-matched views: every pair's fused-depth ratio, as before.
    assert rig_scale(counts[2:], cfg) == pytest.approx(1.005)
    assert rig_scale(counts, MotionStereoConfig(rescale_trajectory=False)) is None
    assert scale_view_indices(list(range(20, 40)), cfg) == set(range(20, 40))   # "lk": every paired view
    hh = MotionStereoConfig(scale_mode="hh")
    assert scale_view_indices(list(range(20, 40)), hh) == {20, 23, 25, 28, 31, 34, 36, 39}
    assert scale_view_indices([5, 6], hh) == {5, 6} and scale_view_indices([5, 6], MotionStereoConfig(scale_mode="hh", scale_views=0)) == set()


def test_motion_stereo_needs_streaming_poses():
    from stereo_recon.reconstruct import ReconstructConfig

    with pytest.raises(ConfigError):
        ReconstructConfig(poses="sfm", motion_stereo=MotionStereoConfig())
    with pytest.raises(ConfigError):
        ReconstructConfig(keyframes=None, motion_stereo=MotionStereoConfig())
    ReconstructConfig(poses="vo", motion_stereo=MotionStereoConfig())


def test_pose_refinement_is_for_visual_odometry_only():
    from stereo_recon.reconstruct import ReconstructConfig

    for poses in ("sfm", "gt:poses.txt"):
        with pytest.raises(ConfigError, match="refine-poses"):
            ReconstructConfig(poses=poses, refine_poses_sfm=True)
        ReconstructConfig(poses=poses, refine_poses_sfm=False)
    ReconstructConfig(poses="vo", refine_poses_sfm=True)


def test_a_view_without_rig_depth_gives_no_wide_depth():
    """No rig depth to set the search range from: nothing is fused from the pair, and the counts stay complete."""
    img_a, img_b, T_a, T_b, depth_a = _scene([0.6, 0.0, 0.0], -3.0)
    pair = rectify_motion_pair(K, T_a, T_b, (W, H), (W, H))
    z, counts = motion_depth(img_a, img_b, np.full_like(depth_a, np.nan), pair, preset("balanced"),
                             MotionStereoConfig(), RIG_FB, 20.0)
    assert not np.isfinite(z).any()
    assert np.isnan(counts["rig_ratio_median"]) and counts["wide_valid"] == 0.0


def test_a_search_range_as_wide_as_the_rectified_image_falls_back_to_the_rig():
    """A partner 6 m away at 5 m depth, rectified to 160 px: the disparity range (~200 px) is wider than the
    image, which OpenCV's SGBM refuses with an error (a wrong pose makes such pairs: seen on a full-scale
    draw whose views SfM had turned 22 deg). The view gets no wide depth (or the rig's, when the wide depth
    is filled from it), and says so."""
    from dataclasses import replace

    img_a, img_b, T_a, T_b, depth_a = _scene([6.0, 0.0, 0.0], -3.0)
    pair = rectify_motion_pair(K, T_a, T_b, (W, H), (160, 90))
    z, counts = motion_depth(img_a, img_b, depth_a, pair, preset("balanced"), MotionStereoConfig(), RIG_FB, 20.0)
    assert counts["wide_skipped"] == 1.0 and counts["wide_valid"] == 0.0
    assert not np.isfinite(z).any() or MotionStereoConfig().fill_from_rig
    z, _ = motion_depth(img_a, img_b, depth_a, pair, preset("balanced"), replace(MotionStereoConfig(), fill_from_rig=True), RIG_FB, 20.0)
    ok = np.isfinite(z)
    assert ok.mean() > 0.5
    assert np.median(np.abs(z[ok] / _exact_rect_depth(pair)[ok] - 1)) < 0.01   # the rig's (here exact) depth
    with pytest.raises(cv2.error):   # what the guard keeps from the run
        disparity_map(img_a[:90, :160], img_b[:90, :160], replace(preset("balanced"), min_disparity_px=16, num_disparities_px=192))
