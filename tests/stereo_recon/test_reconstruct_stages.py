"""The reconstruction's stages one by one (``stereo_recon.stages``), on small scenes with known truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereo_recon.core.errors import ConfigError, StageError
from stereo_recon.fusion import FusionConfig
from stereo_recon.core.manifest import Stopwatch
from stereo_recon.motion_stereo import MotionStereoConfig
from stereo_recon.reconstruct_config import ReconstructConfig
from stereo_recon.stages.fuse import fuse_views
from stereo_recon.stages.motion import rig_scale
from stereo_recon.stages.plan import plan_fusion, size_block_map
from stereo_recon.stages.poses import refine_poses, solve_poses
from stereo_recon.stages.state import RunContext, Setup, Streamed, WideDepth
from stereo_recon.stages.stream import far_scene, view_selector
from stereo_recon.synthetic.flight import look_at
from stereo_recon.trajectory import Trajectory
from stereo_recon.views import KeyframeConfig, ViewSelector

# A small pinhole camera: 160 x 120 px, f = 150 px.
W, H, F = 160, 120, 150.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])
RADIUS_M = 0.5  # the scene: a sphere of this radius at the world origin


def _ctx(tmp_path) -> RunContext:
    work = tmp_path / "work"
    (work / "images").mkdir(parents=True)
    (work / "depth").mkdir()
    return RunContext(tmp_path, work, Stopwatch(), lambda stage, done, total: None, {})


def _sphere_depth(T_wc: np.ndarray) -> np.ndarray:
    """Exact z-depth (m) of the sphere seen by a camera at T_wc (world-from-camera), NaN off the sphere."""
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays_c = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)], -1)  # z = 1
    d_w = rays_c @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    # |o + t d|^2 = r^2, the near root; t is the z-depth because the camera-frame ray has z = 1.
    a = np.einsum("hwi,hwi->hw", d_w, d_w)
    b = 2 * d_w @ o
    c = o @ o - RADIUS_M ** 2
    disc = b * b - 4 * a * c
    t = (-b - np.sqrt(np.where(disc >= 0, disc, np.nan))) / (2 * a)
    return np.where(disc >= 0, t, np.nan).astype(np.float32)


def _orbit(n: int, distance_m: float = 2.0, height_m: float = 0.6) -> list[np.ndarray]:
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return [look_at([distance_m * np.cos(a), distance_m * np.sin(a), height_m], [0.0, 0.0, 0.0]) for a in angles]


def _write_views(ctx: RunContext, poses: list[np.ndarray]) -> list[float]:
    """The views' grey images and exact depth maps in the work folder; their median depths (m)."""
    medians = []
    for idx, T in enumerate(poses):
        z = _sphere_depth(T)
        cv2.imwrite(str(ctx.work / "images" / f"{idx:06d}.png"), np.full((H, W, 3), 128, np.uint8))
        np.save(ctx.work / "depth" / f"{idx:06d}.npy", z)
        medians.append(float(np.nanmedian(z)))
    return medians


def test_plan_fusion_cuts_at_the_region_of_interest_and_sizes_the_voxel_from_the_first_view():
    config = ReconstructConfig(fusion_min_width_px=640, fusion_depth_max_rel=2.0)
    fusion = FusionConfig(depth_min_m=0.3, depth_max_m=60.0)
    plan = plan_fusion(fusion, (2.0, 2.5, 3.0), (1280, 720), 700.0, config)
    assert plan.subsample == 2                                   # 1280 // 640
    assert plan.fusion.depth_max_m == pytest.approx(2.0 * 2.5)   # 2 x the views' median depth
    assert plan.fusion.voxel_m == pytest.approx(2.0 * 2.0 / 700.0)  # 2 px footprints at the first view's 2 m
    # Motion-stereo pairs bring their own (finer) footprint; a set voxel and an ROI box are left alone.
    assert plan_fusion(fusion, (2.0,), (1280, 720), 700.0, config, 1.0).fusion.voxel_m == pytest.approx(2.0 / 700.0)
    fixed = plan_fusion(FusionConfig(voxel_m=0.01, roi_min_m=(0, 0, 0), roi_max_m=(1, 1, 1)), (2.0,), (640, 480), 700.0,
                        ReconstructConfig(fusion_min_width_px=None))
    assert (fixed.subsample, fixed.fusion.voxel_m, fixed.fusion.depth_max_m) == (1, 0.01, FusionConfig().depth_max_m)
    # Never below 1.01 x the near limit, whatever the views' depth.
    assert plan_fusion(fusion, (0.1,), (640, 480), 700.0, config).fusion.depth_max_m == pytest.approx(0.303)


def test_size_block_map_caps_the_hash_map_and_keeps_a_set_count():
    z = np.full((120, 160), 2.0, np.float32)
    sized = size_block_map(FusionConfig(voxel_m=0.01, depth_max_m=10.0), z, K, 20)
    assert sized.block_count is not None and sized.block_count > 0
    cap = int(1.5 * 2**30 // (8 ** 3 * 20))
    assert size_block_map(FusionConfig(voxel_m=1e-4, depth_max_m=10.0), z, K, 1000).block_count == cap
    assert size_block_map(FusionConfig(voxel_m=0.01, block_count=77), z, K, 20).block_count == 77
    # No depth in range: nothing to size from.
    assert size_block_map(FusionConfig(voxel_m=0.01, depth_max_m=1.0), z, K, 20).block_count is None


def test_far_scene_decision_follows_the_depth_in_baselines():
    """The switch to motion stereo depends on the depth in rig baselines, not on the image size."""
    z_b = ReconstructConfig().far_scene_depth_baselines
    close = far_scene(1.4, 520.0, 0.12, z_b)     # a Table 2 orbit (0.8 L): 11.7 baselines, 44.6 px at HD720
    wide = far_scene(2.3, 520.0, 0.12, z_b)      # a model truck flown at 2 L: 19.2 baselines, 27.1 px
    full = far_scene(10.0, 520.0, 0.12, z_b)     # a full-scale truck: 83 baselines, 6.2 px
    assert close.disparity_px == pytest.approx(520 * 0.12 / 1.4) and not close.far
    assert wide.depth_baselines == pytest.approx(2.3 / 0.12) and wide.far
    assert full.far
    # The same orbit at VGA (half the focal, half the disparity) decides the same way.
    assert far_scene(1.4, 260.0, 0.12, z_b).far is False and far_scene(2.3, 260.0, 0.12, z_b).far is True
    assert far_scene(float("nan"), 520.0, 0.12, z_b) is None


def test_far_scene_threshold_is_a_command_line_option(capsys):
    """--far-scene-baselines Z|off sets ReconstructConfig.far_scene_depth_baselines; anything else is a usage error."""
    import argparse

    from stereo_recon.app.options import add_pose_options, reconstruct_overrides

    p = argparse.ArgumentParser(prog="run")
    add_pose_options(p)
    assert "far_scene_depth_baselines" not in reconstruct_overrides(p.parse_args([]))
    assert reconstruct_overrides(p.parse_args(["--far-scene-baselines", "off"]))["far_scene_depth_baselines"] is None
    assert reconstruct_overrides(p.parse_args(["--far-scene-baselines", "20"]))["far_scene_depth_baselines"] == 20.0
    with pytest.raises(ConfigError, match="far-scene-baselines"):
        ReconstructConfig(far_scene_depth_baselines=0.0)
    for bad in ("0", "-3", "far"):
        with pytest.raises(SystemExit):
            p.parse_args(["--far-scene-baselines", bad])
        assert "a positive number of rig baselines" in capsys.readouterr().err


def test_plain_paint_option_sets_the_disparity_rules():
    """--plain-paint turns on the texture test and the occlusion-wide fill (off by default) and reaches SGBM's config."""
    import argparse

    from stereo_recon.app.options import add_frame_options, reconstruct_overrides
    from stereo_recon.disparity import preset

    p = argparse.ArgumentParser(prog="run")
    add_frame_options(p)
    assert "disparity_overrides" not in reconstruct_overrides(p.parse_args([]))
    default = preset(ReconstructConfig().disparity_preset, **ReconstructConfig().disparity_overrides)
    assert default.min_texture_snr is None and default.fill_occlusion_slack_px is None and default.fill_same_surface_px == 1.0
    rc = ReconstructConfig(**reconstruct_overrides(p.parse_args(["--plain-paint"])))
    d = preset(rc.disparity_preset, **rc.disparity_overrides)
    assert d.min_texture_snr == 2.0 and d.fill_occlusion_slack_px == 3.0 and d.fill_same_surface_px is None


def test_view_selector_choice_by_back_end():
    sel, by_pose = view_selector(ReconstructConfig(), "vo")
    assert by_pose and sel.config is None and sel.rotation_deg == 18.0
    sel, by_pose = view_selector(ReconstructConfig(poses="sfm"), "sfm")
    assert not by_pose and sel.config == ReconstructConfig().keyframes
    assert view_selector(ReconstructConfig(poses="sfm", keyframes=None), "sfm") == (None, False)


def test_one_selector_two_forms_of_the_image_motion_criterion(rng):
    big = cv2.resize(rng.integers(0, 256, (120, 200), dtype=np.uint8), (800, 480), interpolation=cv2.INTER_CUBIC)
    frames = [np.ascontiguousarray(big[40:400, 100 + 3 * i:500 + 3 * i]) for i in range(12)]
    cfg = KeyframeConfig(min_flow_frac=0.02, max_gap_frames=None, work_width_px=400)
    one_call = ViewSelector(cfg)
    two_calls = ViewSelector(cfg)
    a, b = [], []
    for i, img in enumerate(frames):
        if one_call.is_keyframe(i, img):
            a.append(i)
        if two_calls.is_view(None, i, img):
            two_calls.set_view(None, i, img)
            b.append(i)
    assert a == b and len(a) >= 3


def test_solve_poses_with_known_trajectory_keeps_the_views_and_their_partners(tmp_path):
    poses = _orbit(10)
    gt = Trajectory(np.arange(10), np.arange(10) / 15.0, np.stack(poses))
    setup = Setup(source=None, rig=None, rect=None, depth_max_m=10.0, disparity=None, fusion=FusionConfig(),
                  mode="gt", gt=gt)
    streamed = Streamed(keyframes=(0, 3, 6, 9), view_depths_m=(2.0,), partners={3: 5}, motion=MotionStereoConfig())
    config = ReconstructConfig(poses="gt:unused.txt")
    traj = solve_poses(setup, streamed, config, _ctx(tmp_path))
    assert list(traj.indices) == [0, 3, 5, 6, 9]
    np.testing.assert_array_equal(traj.T_wc, np.stack(poses)[[0, 3, 5, 6, 9]])
    # Too few posed frames for fusion: refused with the stage's message.
    with pytest.raises(StageError, match="only 2 frames have a pose"):
        refine_poses(traj.subset(np.array([0, 1])), setup, streamed, config, _ctx(tmp_path / "b"))


def test_rig_scale_is_the_median_ratio_of_enough_pairs():
    counts = [{"rig_ratio_median": r} for r in (1.01, 0.99, 1.003, float("nan"))]
    assert rig_scale(counts, MotionStereoConfig()) == pytest.approx(1.003)
    assert rig_scale(counts[:2], MotionStereoConfig()) is None          # fewer than 3 pairs
    assert rig_scale(counts, MotionStereoConfig(rescale_trajectory=False)) is None


def test_fuse_views_recovers_a_sphere_from_exact_depth(tmp_path):
    # 12 views on a 2 m orbit around a 0.5 m sphere, exact depth: the fused surface lies on the sphere
    # to within a fraction of the voxel (TSDF zero crossings are interpolated; measured: median 0.09,
    # 95th percentile 0.32 voxel, bias +0.07 voxel), all round.
    ctx = _ctx(tmp_path)
    poses = _orbit(12)
    medians = _write_views(ctx, poses)
    config = ReconstructConfig(fusion_min_width_px=None)
    plan = plan_fusion(FusionConfig(depth_min_m=0.3, depth_max_m=10.0), tuple(medians), (W, H), F, config)
    voxel = plan.fusion.voxel_m
    assert voxel == pytest.approx(2.0 * medians[0] / F)  # about 2 cm
    traj = Trajectory(np.arange(12), np.arange(12) / 15.0, np.stack(poses))
    cloud = fuse_views(traj, tuple(range(12)), plan, WideDepth(), K, config, ctx)
    r = np.linalg.norm(cloud.points, axis=1)
    err = np.abs(r - RADIUS_M)
    assert np.median(err) < 0.15 * voxel
    assert np.percentile(err, 95) < 0.5 * voxel
    assert abs(np.median(r - RADIUS_M)) < 0.15 * voxel
    assert cloud.views == tuple(range(12)) and ctx.counts["keyframes_fused"] == 12
    assert ctx.counts["cloud_points"] == len(cloud.points) > 500
    assert cloud.fusion.block_count is not None  # the hash map was sized up front
    # Seen all round: every 30 deg sector of azimuth holds points of the sphere's visible band.
    az = np.degrees(np.arctan2(cloud.points[:, 1], cloud.points[:, 0])) % 360
    assert len(np.unique((az // 30).astype(int))) == 12
