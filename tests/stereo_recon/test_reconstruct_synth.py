"""``reconstruct`` on the project's rendered ZED-like video (raw distorted eyes, known poses and depth)."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stereo_recon.synthetic.sequence")
o3d = pytest.importorskip("open3d")
cv2 = pytest.importorskip("cv2")

from calib.io import load_rig  # noqa: E402
from stereo_recon.reconstruct import ReconstructConfig, reconstruct  # noqa: E402
from stereo_recon.trajectory import read_tum  # noqa: E402


# Every test here renders or reconstructs a sequence (module fixture ~10-15 s on 2 cores).
pytestmark = pytest.mark.slow

@pytest.fixture(scope="module")
def synth_vga(tmp_path_factory):
    from stereo_recon.synthetic.sequence import render_sequence

    out = tmp_path_factory.mktemp("synth") / "vga"
    render_sequence("model-truck", out, seed=0, frames=12, resolution="VGA", depth=True)
    return out


def _gt_cloud(d, rig, gt, max_depth_m=4.0, stride_px=1, every=1):
    """World points of the GT depth maps (raw left camera, distorted pixels) with the GT poses.

    stride_px: every n-th pixel in both directions; every: every n-th frame.
    """
    w, h = rig.image_size
    u, v = np.meshgrid(np.arange(0, w, stride_px, dtype=np.float64), np.arange(0, h, stride_px, dtype=np.float64))
    uv = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(uv, rig.K1, rig.D1).reshape(-1, 2)
    pts = []
    for i, T in list(zip(gt.indices, gt.T_wc))[::every]:
        z = np.load(d / "depth" / f"{int(i):06d}.npy")[::stride_px, ::stride_px].ravel().astype(np.float64)
        ok = np.isfinite(z) & (z > 0) & (z < max_depth_m)
        X = np.stack([xy[ok, 0] * z[ok], xy[ok, 1] * z[ok], z[ok]], 1)
        pts.append(X @ T[:3, :3].T + T[:3, 3])
    return np.vstack(pts)


def _in_truck(p, truth, margin=0.02):
    """Points inside the truck's true box grown by ``margin`` m, above the ground (world frame, m)."""
    T_wt = np.asarray(truth["truck"]["T_world_truck"])
    q = (p - T_wt[:3, 3]) @ T_wt[:3, :3]
    return ((np.abs(q[:, 0]) < truth["length_m"] / 2 + margin) & (np.abs(q[:, 1]) < truth["width_m"] / 2 + margin)
            & (q[:, 2] > 0.01) & (q[:, 2] < truth["height_m"] + margin))


def _surface_distance(points, ref):
    """Point-to-plane distance (m) of each point to the reference cloud (local normals of 20 neighbours),
    so the discrete sampling of the reference does not count as error."""
    from scipy.spatial import cKDTree

    ref_pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(ref))
    ref_pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    normals = np.asarray(ref_pcd.normals)
    _, nn = cKDTree(ref).query(points)
    return np.abs(np.sum((points - ref[nn]) * normals[nn], axis=1))


def test_synthetic_truck_cloud_accuracy_and_coverage(synth_vga, tmp_path):
    from scipy.spatial import cKDTree

    d = synth_vga
    truth = json.loads((d / "truth.json").read_text())
    rig = load_rig(d / "rig.yaml")
    assert not rig.rectified  # raw distorted eyes: the rectification path is exercised
    cfg = ReconstructConfig(poses=f"gt:{d / 'poses_gt.txt'}", depth_min_m=0.5, depth_max_m=4.0, keyframes=None)
    man = reconstruct(d / "video.avi", rig, tmp_path / "out", cfg)
    gt = read_tum(d / "poses_gt.txt", fps=truth["fps"])
    # poses.txt describes the physical left camera again (rectifying rotation undone).
    est = read_tum(tmp_path / "out" / "poses.txt", fps=truth["fps"])
    np.testing.assert_allclose(est.T_wc, gt.T_wc, atol=1e-6)
    assert np.dot(man["up"], [0, 0, 1]) > 0.99

    cloud = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "out" / "cloud.ply")).points)
    ref = _gt_cloud(d, rig, gt)
    # The truck's region: its true box (truth corners) grown by 2 cm, above the ground.
    corners = np.asarray(truth["truck_corners_world_m"])
    L = truth["length_m"]

    assert corners.shape[-1] == 3
    ours_truck = cloud[_in_truck(cloud, truth)]
    ref_truck = ref[_in_truck(ref, truth)]
    assert len(ours_truck) > 5000
    # Point-to-plane distance to the reference surface (local normals of the reference cloud), so the
    # discrete sampling of the reference (~6 mm at VGA) does not count as error.
    acc = _surface_distance(ours_truck, ref)
    cov, _ = cKDTree(cloud).query(ref_truck)
    # Issue 5 item 8: median distance to the true surface <= 0.5 % of the truck length, coverage >= 90 %
    # of the visible surface (the reference points seen by the 12 views). Measured at VGA (depth noise
    # ~1.8 cm per view at 1.7 m): 8.5 mm = 0.41 % of L, coverage 95 %; HD720, 120 frames, VO: 0.26 %.
    assert np.median(acc) < 0.005 * L
    assert (cov < 0.01 * L).mean() >= 0.90


def test_motion_stereo_views_are_fused_and_accurate(tmp_path_factory, tmp_path):
    """Opt-in motion stereo on a 24-frame VGA orbit (15 deg, 0.44 m between frames) with known poses."""
    from scipy.spatial import cKDTree

    from stereo_recon.motion_stereo import MotionStereoConfig
    from stereo_recon.synthetic.sequence import render_sequence

    d = tmp_path_factory.mktemp("synth") / "vga24"
    render_sequence("model-truck", d, seed=1, frames=24, resolution="VGA", depth=True)
    truth = json.loads((d / "truth.json").read_text())
    rig = load_rig(d / "rig.yaml")
    cfg = ReconstructConfig(poses=f"gt:{d / 'poses_gt.txt'}", depth_min_m=0.5, depth_max_m=4.0,
                            motion_stereo=MotionStereoConfig())
    man = reconstruct(d / "video.avi", rig, tmp_path / "out", cfg)
    counts = man["counts"]
    assert counts["motion_stereo_views"] >= counts["keyframes_fused"] - 2  # the last views find no later partner
    assert counts["motion_stereo_depth_scale"] == 1.0  # known poses are never rescaled
    gt = read_tum(d / "poses_gt.txt", fps=truth["fps"])
    cloud = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "out" / "cloud.ply")).points)
    ref = _gt_cloud(d, rig, gt)
    L = truth["length_m"]

    ours = cloud[_in_truck(cloud, truth)]
    acc = _surface_distance(ours, ref)
    cov, _ = cKDTree(cloud).query(ref[_in_truck(ref, truth)])
    print(f"motion stereo: median distance {1000 * np.median(acc):.1f} mm, coverage {(cov < 0.01 * L).mean():.2f}")
    # Accuracy: the same target as the rig's depth above (issue 5 item 8). Coverage is lower (measured
    # 82 %): where the wide pair is occluded the view keeps a hole rather than the rig's biased depth.
    assert len(ours) > 5000
    assert np.median(acc) < 0.005 * L
    assert (cov < 0.01 * L).mean() >= 0.75


def test_far_scene_switches_to_motion_stereo(tmp_path_factory, tmp_path):
    """A full-scale truck (5-8 px of rig disparity), end to end: VO on dense depth, SfM bundle adjustment
    of the fused views, motion stereo, trajectory rescaled, measurement and verdict."""
    from measure.schema import read_measurement
    from stereo_recon.app.bench import verdict_matches
    from stereo_recon.app.pipeline import RunConfig, run_video
    from stereo_recon.synthetic.sequence import render_sequence
    from stereo_recon.trajectory import absolute_trajectory_error, align_umeyama

    d = tmp_path_factory.mktemp("synth") / "full"
    render_sequence("full-truck", d, seed=0, depth=True)  # the preset: 60 HD720 frames, 6 deg apart
    truth = json.loads((d / "truth.json").read_text())
    rig = load_rig(d / "rig.yaml")
    out = tmp_path / "out"
    summary = run_video(d / "video.avi", d / "SN28000001.conf", out, RunConfig(quiet=True))
    read_measurement(out)  # measurement.json against its JSON Schema
    counts = json.loads((out / "run.json").read_text())["counts"]
    assert counts["far_scene"] and counts["first_view_disparity_px"] < 16
    assert counts["frames_depth"] >= counts["frames_read"] - 2  # dense depth for VO from the second frame on
    assert counts["motion_stereo_views"] >= counts["keyframes_fused"] - 2
    assert abs(counts["trajectory_scale_from_rig"] - 1) < 0.02
    refine = counts["sfm_refine"]
    assert isinstance(refine, dict) and refine["registered"] >= 0.9 * refine["images"], refine
    gt = read_tum(d / "poses_gt.txt", fps=truth["fps"])
    est = read_tum(out / "poses.txt", fps=truth["fps"])
    ate = absolute_trajectory_error(est, gt)
    # VO alone turns the views by 0.29 deg rms here (0.43 on the over-height preset), in step with
    # sideways shifts of ~4 cm; bundle-adjusted: 0.07 deg, ATE 13 mm.
    assert ate["rot_rmse_deg"] < 0.15 and ate["rmse_m"] < 0.03, ate
    cloud = np.asarray(o3d.io.read_point_cloud(str(out / "cloud.ply")).points)
    # VO's frame -> the true world, rigidly (a scale error must show), before comparing with the truth.
    gt_at = {int(i): T for i, T in zip(gt.indices, gt.T_wc)}
    _, R, t = align_umeyama(est.T_wc[:, :3, 3], np.array([gt_at[int(i)][:3, 3] for i in est.indices]), with_scale=False)
    cloud = cloud @ R.T + t
    ref = _gt_cloud(d, rig, gt, max_depth_m=30.0, stride_px=2, every=3)
    L = truth["length_m"]
    ours = cloud[_in_truck(cloud, truth, 0.1)]
    acc = _surface_distance(ours, ref)
    print(f"far scene: ATE {ate['rmse_m']:.3f} m, scale {ate['scale']:.4f}, median distance {np.median(acc):.3f} m")
    assert len(ours) > 5000
    assert np.median(acc) < 0.005 * L
    # The target is 1 % per dimension (`stereo-recon bench` measured L -0.01, W -0.69, H -0.05 %
    # on this scene); the margin here is for other library builds.
    err = {k: 100 * (summary[f"{k}_m"] / truth[f"{k}_m"] - 1) for k in ("length", "width", "height")}
    assert abs(err["length"]) < 0.5 and abs(err["height"]) < 0.5 and abs(err["width"]) < 1.2, err
    # Built exactly to the 2.55 m / 4.00 m limits: "within" or, within the measurement's 2 sigma of a
    # limit, "undecided" - never "over".
    assert summary["verdict"]["overall"] != "over"
    assert verdict_matches("within-limits", summary["verdict"], {k: truth[f"{k}_m"] for k in ("length", "width", "height")})


def test_synthetic_depth_maps_match_ground_truth(synth_vga):
    """Rectified SGBM depth vs rendered depth, re-expressed in the rectified left camera."""
    from calib.rig import rectify_pair
    from stereo_recon.disparity import depth_from_disparity, disparity_map, disparity_range_for_depth, preset
    from stereo_recon.video import open_stereo_source

    d = synth_vga
    rig = load_rig(d / "rig.yaml")
    rect = rig.rectification(alpha=0.0)
    lo, num = disparity_range_for_depth(rect.focal_px, rect.baseline_m, 0.5, 4.0)
    cfg = preset("balanced", min_disparity_px=lo, num_disparities_px=num, fill_max_px=32)
    mx, my = rect.map_left
    for frame in open_stereo_source(d / "video.avi", (0, 12), 4):
        lr, rr = rectify_pair(frame.left, frame.right, rect)
        z = depth_from_disparity(disparity_map(lr, rr, cfg), rect.focal_px, rect.baseline_m, 0.5, 4.0)
        # GT: raw depth sampled where each rectified pixel comes from, rotated into the rectified frame.
        z_raw = np.load(d / "depth" / f"{frame.index:06d}.npy").astype(np.float32)
        zr = cv2.remap(z_raw, mx, my, cv2.INTER_NEAREST, borderValue=np.nan)
        xy = cv2.undistortPoints(np.stack([mx.ravel(), my.ravel()], 1).reshape(-1, 1, 2).astype(np.float64),
                                 rig.K1, rig.D1).reshape(-1, 2)
        X = np.stack([xy[:, 0], xy[:, 1], np.ones(len(xy))], 1) * zr.reshape(-1, 1)
        with np.errstate(invalid="ignore"):
            z_gt = (X @ rect.R1.T)[:, 2].reshape(zr.shape)
        ok = np.isfinite(z) & np.isfinite(z_gt)
        rel = np.abs(z[ok] - z_gt[ok]) / z_gt[ok]
        assert ok.mean() > 0.5
        # Depth noise of stereo: dZ/Z = Z * dd / (f B); at ~1.7 m, f B ~ 32 px m (VGA) and 0.25 px -> ~1.3 %.
        # Measured: median 0.56-0.60 %, 90-96 % of pixels within 5 %, 55-58 % of pixels valid.
        assert np.median(rel) < 0.015
        assert np.mean(rel < 0.05) > 0.85
