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


def _gt_cloud(d, rig, gt):
    """World points of every GT depth map (raw left camera, distorted pixels) with the GT poses."""
    w, h = rig.image_size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    uv = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(uv, rig.K1, rig.D1).reshape(-1, 2)
    pts = []
    for i, T in zip(gt.indices, gt.T_wc):
        z = np.load(d / "depth" / f"{int(i):06d}.npy").ravel().astype(np.float64)
        ok = np.isfinite(z) & (z > 0) & (z < 4.0)
        X = np.stack([xy[ok, 0] * z[ok], xy[ok, 1] * z[ok], z[ok]], 1)
        pts.append(X @ T[:3, :3].T + T[:3, 3])
    return np.vstack(pts)


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
    T_wt = np.asarray(truth["truck"]["T_world_truck"])
    L, W, H = truth["length_m"], truth["width_m"], truth["height_m"]

    def in_truck(p, margin=0.02):
        q = (p - T_wt[:3, 3]) @ T_wt[:3, :3]
        return ((np.abs(q[:, 0]) < L / 2 + margin) & (np.abs(q[:, 1]) < W / 2 + margin)
                & (q[:, 2] > 0.01) & (q[:, 2] < H + margin))

    assert corners.shape[-1] == 3
    ours_truck = cloud[in_truck(cloud)]
    ref_truck = ref[in_truck(ref)]
    assert len(ours_truck) > 5000
    # Point-to-plane distance to the reference surface (local normals of the reference cloud), so the
    # discrete sampling of the reference (~6 mm at VGA) does not count as error.
    ref_pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(ref))
    ref_pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    normals = np.asarray(ref_pcd.normals)
    _, nn = cKDTree(ref).query(ours_truck)
    acc = np.abs(np.sum((ours_truck - ref[nn]) * normals[nn], axis=1))
    cov, _ = cKDTree(cloud).query(ref_truck)
    # Issue 5 item 8: median distance to the true surface <= 0.5 % of the truck length, coverage >= 90 %
    # of the visible surface (the reference points seen by the 12 views). Measured at VGA (depth noise
    # ~1.8 cm per view at 1.7 m): 8.5 mm = 0.41 % of L, coverage 95 %; HD720, 120 frames, VO: 0.26 %.
    assert np.median(acc) < 0.005 * L
    assert (cov < 0.01 * L).mean() >= 0.90


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
