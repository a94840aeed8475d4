"""Stereo visual odometry on a ray-cast textured orbit with exact poses, and the pose graph."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stereo_recon.odometry import StereoVO, VOConfig, optimise_pose_graph, sparse_stereo_depth
from stereo_recon.trajectory import Trajectory, absolute_trajectory_error, scale_error

_spec = importlib.util.spec_from_file_location("vo_scene", Path(__file__).with_name("vo_scene.py"))
vo_scene = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(vo_scene)

N_FRAMES = 60  # a full 360-degree orbit, 6 degrees per frame
# 320x240 test images: corner spacing and LK window scaled down from the HD720 defaults.
SMALL = dict(feature_min_distance_px=6.0, lk_window_px=11)


BASELINE_M = 0.3  # the right eye of the rendered pair


@pytest.fixture(scope="module")
def orbit():
    K, imgs, depths, T, rights = vo_scene.render_orbit(N_FRAMES, size=(320, 240), supersample=1, baseline_m=BASELINE_M)
    return K, imgs, depths, Trajectory(np.arange(N_FRAMES), np.arange(N_FRAMES) / 15.0, T), rights


def _run(orbit, config, frames=None):
    K, imgs, depths, gt, _ = orbit
    vo = StereoVO(K, BASELINE_M, config, fps=15.0)
    out = [vo.track(i, imgs[i], depths[i]) for i in (range(len(imgs)) if frames is None else frames)]
    return vo.finish(), out


def _end_to_start_error_m(est: Trajectory, gt: Trajectory) -> float:
    """Error of the last frame's position relative to the first (the loop-closing residual)."""
    rel_e = np.linalg.inv(est.T_wc[0]) @ est.T_wc[-1]
    rel_g = np.linalg.inv(gt.T_wc[est.indices[0]]) @ gt.T_wc[est.indices[-1]]
    return float(np.linalg.norm(rel_e[:3, 3] - rel_g[:3, 3]))


@pytest.mark.slow
def test_vo_metric_accuracy_and_loop_closure(orbit):
    gt = orbit[3]
    open_loop, poses = _run(orbit, VOConfig(loop_closure=False, **SMALL))
    assert all(p is not None for p in poses)
    assert open_loop.stats["tracking_gaps"] == [] and open_loop.stats["loop_closures"] == 0
    np.testing.assert_allclose(open_loop.T_wc[0], np.eye(4))  # world = first camera
    ate = absolute_trajectory_error(open_loop, gt, with_scale=True)
    assert ate["rmse_rel_path"] <= 0.01, ate
    assert abs(scale_error(open_loop, gt)) <= 0.005  # metric from depth, no scale fitted
    assert np.allclose(open_loop.timestamps_s, np.arange(N_FRAMES) / 15.0)

    closed, _ = _run(orbit, VOConfig(**SMALL))
    assert closed.stats["loop_closures"] >= 1
    assert min(i for i, _ in closed.stats["loop_pairs_frames"]) < 10  # closed against the start
    ate_c = absolute_trajectory_error(closed, gt, with_scale=True)
    assert ate_c["rmse_rel_path"] <= 0.01 and abs(scale_error(closed, gt)) <= 0.005
    drift_open, drift_closed = _end_to_start_error_m(open_loop, gt), _end_to_start_error_m(closed, gt)
    assert drift_closed < 0.5 * drift_open, (drift_open, drift_closed)
    assert ate_c["rmse_m"] < ate["rmse_m"]


@pytest.mark.slow
def test_vo_tracking_loss_is_recorded_and_recovered(orbit):
    K, imgs, depths, gt, _ = orbit
    vo = StereoVO(K, BASELINE_M, VOConfig(loop_closure=False, **SMALL))
    poses = []
    for i in range(25):
        if i == 12:  # a dropped, black frame: nothing to track
            poses.append(vo.track(i, np.zeros_like(imgs[i]), np.full_like(depths[i], np.nan)))
        else:
            poses.append(vo.track(i, imgs[i], depths[i]))
    tr = vo.finish()
    assert poses[12] is None and all(p is not None for k, p in enumerate(poses) if k != 12)
    assert tr.stats["tracking_gaps"] == [[11, 12]]
    assert tr.stats["relocalisations"] >= 1  # frame 13 found again against a keyframe before the gap
    assert 12 not in tr.indices and len(tr) == 24
    ate = absolute_trajectory_error(tr, gt, with_scale=False)
    assert ate["rmse_rel_path"] <= 0.01, ate


@pytest.mark.slow
def test_vo_with_sparse_stereo_instead_of_depth_maps(orbit):
    """No dense depth: corners are matched in the right image at keyframes only."""
    K, imgs, _, gt, rights = orbit
    vo = StereoVO(K, BASELINE_M, VOConfig(**SMALL))
    poses = [vo.track(i, imgs[i], None, right_rect_gray=rights[i]) for i in range(N_FRAMES)]
    tr = vo.finish()
    assert all(p is not None for p in poses) and tr.stats["loop_closures"] >= 1
    assert absolute_trajectory_error(tr, gt, with_scale=True)["rmse_rel_path"] <= 0.01
    assert abs(scale_error(tr, gt)) <= 0.005


def test_sparse_stereo_depth_matches_rendered_depth(orbit):
    import cv2

    K, imgs, depths, _, rights = orbit
    k = 7
    uv = cv2.goodFeaturesToTrack(imgs[k], 400, 0.005, 6).reshape(-1, 2).astype(float)
    z = sparse_stereo_depth(imgs[k], rights[k], uv, K[0, 0], BASELINE_M, 0.3, 20.0)
    z_true = depths[k][np.rint(uv[:, 1]).astype(int), np.rint(uv[:, 0]).astype(int)]
    ok = np.isfinite(z) & np.isfinite(z_true)
    assert ok.mean() > 0.6
    rel = np.abs(z[ok] / z_true[ok] - 1)
    # Disparities here are 10-40 px; a 0.1 px sub-pixel error is 0.25-1 % of depth.
    assert np.median(rel) < 0.01 and np.mean(rel < 0.05) > 0.9


def test_vo_rejects_mismatched_depth():
    vo = StereoVO(np.array([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]]), 0.12)
    with pytest.raises(ValueError, match="sizes differ"):
        vo.track(0, np.zeros((80, 100), np.uint8), np.ones((40, 50), np.float32))
    with pytest.raises(ValueError, match="sizes differ"):
        vo.track(0, np.zeros((80, 100), np.uint8), None, right_rect_gray=np.zeros((40, 50), np.uint8))
    with pytest.raises(ValueError, match="depth_m or right_rect_gray"):
        vo.track(0, np.zeros((80, 100), np.uint8), None)


def test_vo_finish_without_frames_is_empty():
    tr = StereoVO(np.eye(3), 0.1).finish()
    assert len(tr) == 0 and tr.stats["frames_tracked"] == 0


def test_pose_graph_spreads_loop_error(rng):
    """Odometry with a yaw bias drifts; one exact loop edge pulls the chain back onto the circle."""
    gt = vo_scene.orbit_poses(40, wobble_m=0.0)
    n = len(gt)
    rel = [np.linalg.inv(gt[k]) @ gt[k + 1] for k in range(n - 1)]
    bias = np.eye(4)
    bias[:3, :3] = Rotation.from_euler("y", 0.1, degrees=True).as_matrix()
    odo = [r @ bias for r in rel]
    chain = [gt[0]]
    for r in odo:
        chain.append(chain[-1] @ r)
    chain = np.stack(chain)
    edges = [(k, k + 1, odo[k], 1.0) for k in range(n - 1)]
    edges.append((0, n - 1, np.linalg.inv(gt[0]) @ gt[n - 1], 1.0))
    opt, info = optimise_pose_graph(chain, edges)
    assert info["cost_after"] < 0.01 * info["cost_before"]
    np.testing.assert_allclose(opt[0], chain[0])  # gauge: node 0 held
    err_before = np.linalg.norm(chain[:, :3, 3] - gt[:, :3, 3], axis=1).max()
    err_after = np.linalg.norm(opt[:, :3, 3] - gt[:, :3, 3], axis=1).max()
    assert err_after < 0.25 * err_before, (err_before, err_after)


@pytest.mark.parametrize("kw", [dict(min_inliers=4), dict(max_features=0), dict(min_depth_m=5.0, max_depth_m=1.0)])
def test_vo_config_rejects_bad_values(kw):
    from stereo_recon.core.errors import ConfigError

    with pytest.raises(ConfigError):
        VOConfig(**kw)
