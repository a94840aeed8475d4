"""Trajectory container, TUM I/O, Umeyama alignment, ATE/RPE and the 'up' estimate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stereo_recon.core.errors import InputError
from stereo_recon.trajectory import (
    Trajectory,
    absolute_trajectory_error,
    align_umeyama,
    graft_poses,
    orbit_centre,
    read_tum,
    relative_pose_error,
    scale_error,
    up_from_trajectory,
    write_tum,
)


def _orbit(n=36, radius=5.0, height=3.0, tilt_deg=0.0):
    """Cameras on a circle around the world z axis, looking at the origin (OpenCV axes, y down)."""
    T = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        th = 2 * np.pi * k / n
        c = np.array([radius * np.cos(th), radius * np.sin(th), height])
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        T[k, :3, :3] = np.column_stack([x, np.cross(z, x), z])
        T[k, :3, 3] = c
    if tilt_deg:
        R = Rotation.from_euler("x", tilt_deg, degrees=True).as_matrix()
        T[:, :3, :3] = R @ T[:, :3, :3]
        T[:, :3, 3] = T[:, :3, 3] @ R.T
    return Trajectory(np.arange(n), np.arange(n) / 15.0, T)


def test_tum_round_trip(tmp_path):
    tr = _orbit()
    path = write_tum(tmp_path / "poses.txt", tr)
    back = read_tum(path, fps=15.0)
    np.testing.assert_array_equal(back.indices, tr.indices)
    np.testing.assert_allclose(back.timestamps_s, tr.timestamps_s, atol=1e-6)
    np.testing.assert_allclose(back.T_wc, tr.T_wc, atol=1e-8)
    first = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")][0].split()
    # TUM order: timestamp tx ty tz qx qy qz qw (scalar last)
    q = Rotation.from_matrix(tr.T_wc[0, :3, :3]).as_quat()
    assert np.allclose([float(v) for v in first[4:]], q, atol=1e-8) or np.allclose(
        [float(v) for v in first[4:]], -q, atol=1e-8
    )


@pytest.mark.parametrize(
    "text, fragment",
    [("0 1 2 3 0 0 0\n", "expected 8"), ("0 1 2 x 0 0 0 1\n", "not a number"), ("# only\n", "no poses"),
     ("0 1 2 3 0 0 0 0\n", "zero quaternion")],
)
def test_read_tum_rejects_bad_files(tmp_path, text, fragment):
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(InputError, match=fragment):
        read_tum(p)
    with pytest.raises(InputError, match="cannot read"):
        read_tum(tmp_path / "missing.txt")


def test_umeyama_recovers_similarity(rng):
    src = rng.normal(size=(200, 3))
    R = Rotation.random(random_state=3).as_matrix()
    s, t = 2.5, np.array([1.0, -2.0, 0.5])
    noise = 1e-3
    dst = s * src @ R.T + t + rng.normal(scale=noise, size=src.shape)
    s_e, R_e, t_e = align_umeyama(src, dst, with_scale=True)
    assert abs(s_e - s) < 5 * noise
    assert np.degrees(Rotation.from_matrix(R_e.T @ R).magnitude()) < 0.05
    assert np.linalg.norm(t_e - t) < 5 * noise * s
    s1, R1, _ = align_umeyama(src, src @ R.T + t, with_scale=False)
    assert s1 == 1.0 and np.allclose(R1, R, atol=1e-9)


def test_ate_and_rpe_of_transformed_and_perturbed_copies(rng):
    gt = _orbit()
    R = Rotation.from_euler("zyx", [30, 10, -5], degrees=True).as_matrix()
    est = gt.transformed(0.5, R, np.array([3.0, 1.0, -2.0]))
    ate = absolute_trajectory_error(est, gt, with_scale=True)
    assert ate["rmse_m"] < 1e-9 and abs(ate["scale"] - 2.0) < 1e-9 and ate["rot_max_deg"] < 1e-6
    assert abs(scale_error(est, gt) - (0.5 - 1.0)) < 1e-9
    # A rigid copy has no relative pose error; without scale the ATE sees the halved orbit.
    rigid = gt.transformed(1.0, R, np.array([3.0, 1.0, -2.0]))
    rpe = relative_pose_error(rigid, gt)
    assert rpe["trans_rmse_m"] < 1e-9 and rpe["rot_rmse_deg"] < 1e-6
    assert absolute_trajectory_error(est, gt, with_scale=False)["rmse_m"] > 1.0
    # Centre noise of sigma per axis gives an ATE of about sqrt(3) sigma.
    sigma = 0.01
    noisy = Trajectory(gt.indices, gt.timestamps_s, gt.T_wc.copy())
    noisy.T_wc[:, :3, 3] += rng.normal(scale=sigma, size=(len(gt), 3))
    ate = absolute_trajectory_error(noisy, gt, with_scale=False)
    assert 0.5 * np.sqrt(3) * sigma < ate["rmse_m"] < 1.5 * np.sqrt(3) * sigma
    assert abs(ate["rmse_rel_path"] - ate["rmse_m"] / gt.path_length_m()) < 1e-12


def test_ate_matches_frames_by_index():
    gt = _orbit()
    est = gt.subset(np.arange(0, len(gt), 2))
    assert absolute_trajectory_error(est, gt)["n"] == len(est)
    with pytest.raises(ValueError):
        absolute_trajectory_error(gt.subset([0, 1]), gt)


@pytest.mark.parametrize("tilt_deg", [0.0, 25.0])
def test_up_from_orbit_plane(tilt_deg):
    tr = _orbit(tilt_deg=tilt_deg)
    up_true = Rotation.from_euler("x", tilt_deg, degrees=True).as_matrix() @ np.array([0, 0, 1.0])
    up = up_from_trajectory(tr)
    assert np.isclose(np.linalg.norm(up), 1.0)
    assert np.degrees(np.arccos(np.clip(up @ up_true, -1, 1))) < 1e-6


def test_up_falls_back_to_camera_y_when_collinear():
    tr = _orbit()
    line = Trajectory(tr.indices, tr.timestamps_s, tr.T_wc.copy())
    line.T_wc[:, :3, 3] = np.outer(np.arange(len(tr)), [1.0, 0.0, 0.0])  # straight pass
    up = up_from_trajectory(line)
    expected = -line.T_wc[:, :3, 1].mean(0)
    assert np.allclose(up, expected / np.linalg.norm(expected))
    assert up @ np.array([0, 0, 1.0]) > 0.5


def test_graft_poses_puts_refined_frames_in_base_world_and_carries_corrections():
    gt = _orbit(n=36)
    # base: the truth with a wobble (rotations in step with sideways shifts, as VO's at full scale)
    base = Trajectory(gt.indices, gt.timestamps_s, gt.T_wc.copy())
    for k in range(len(gt)):
        a = 0.004 * np.sin(2 * np.pi * k / 18)
        base.T_wc[k, :3, :3] = base.T_wc[k, :3, :3] @ Rotation.from_rotvec([0, a, 0]).as_matrix()
        base.T_wc[k, :3, 3] += base.T_wc[k, :3, :3] @ np.array([-5.0 * a, 0, 0])
    # refined: every other frame exactly, but in its own world frame and scale (as SfM returns them)
    sel = np.arange(0, 36, 2)
    R = Rotation.from_euler("zyx", [40, -8, 3], degrees=True).as_matrix()
    refined = gt.subset(sel).transformed(0.37, R, np.array([1.0, -2.0, 0.5]))
    out, stats = graft_poses(base, refined)
    assert stats["grafted_frames"] == len(sel) and abs(stats["similarity_scale"] - 1 / 0.37) < 1e-3
    assert np.array_equal(out.indices, base.indices)
    # the refined frames are the truth, in base's world (the wobble averages out of the similarity)
    ate = absolute_trajectory_error(out.subset(sel), gt.subset(sel), with_scale=False)
    assert ate["rmse_m"] < 2e-3 and ate["rot_max_deg"] < 0.05
    # the others take their neighbour's correction: closer to the truth than base was
    odd = np.arange(1, 36, 2)
    before = absolute_trajectory_error(base.subset(odd), gt.subset(odd), with_scale=False)
    after = absolute_trajectory_error(out.subset(odd), gt.subset(odd), with_scale=False)
    assert after["rot_rmse_deg"] < 0.5 * before["rot_rmse_deg"]
    with pytest.raises(ValueError, match="common frames|share only"):
        graft_poses(base, gt.subset(np.array([0, 1])))


def test_graft_poses_can_keep_the_refined_trajectory_s_metric_scale():
    # base: the truth's shape at 0.75 of its scale (VO short, as on far scenes); refined: the truth exactly, in
    # another world frame (a metric bundle adjustment's)
    gt = _orbit(n=36)
    base = Trajectory(gt.indices, gt.timestamps_s, gt.T_wc.copy())
    base.T_wc[:, :3, 3] *= 0.75
    sel = np.arange(0, 36, 3)
    R = Rotation.from_euler("zyx", [-25, 4, 10], degrees=True).as_matrix()
    refined = gt.subset(sel).transformed(1.0, R, np.array([3.0, 1.0, -0.5]))
    kept, stats = graft_poses(base, refined)
    metric, stats_m = graft_poses(base, refined, keep_refined_scale=True)
    assert stats == stats_m and abs(stats["similarity_scale"] - 0.75) < 1e-9
    assert abs(absolute_trajectory_error(kept, gt)["scale"] - 1 / 0.75) < 1e-6   # base's scale: 25 % short
    ate = absolute_trajectory_error(metric, gt, with_scale=False)                 # the truth, in base's world
    assert ate["rmse_m"] < 1e-6 and ate["rot_max_deg"] < 1e-6


def test_orbit_centre_of_a_partial_arc_is_the_circle_s_not_the_mean(rng):
    """Cameras on a 240 deg arc of radius 2 m round (3, -1), 1.5 m up, with 2 cm of jitter, in a world whose up
    is tilted 10 deg: the fitted centre is within 3 cm of the truth, where the mean of the centres lies
    0.8 m off towards the arc's middle; a straight pass and a handful of cameras fall back to the mean."""
    up = Rotation.from_euler("x", 10, degrees=True).apply([0.0, 0.0, 1.0])
    R = Rotation.from_euler("x", 10, degrees=True).as_matrix()
    th = np.linspace(0.0, np.radians(240.0), 60)
    local = np.c_[2.0 * np.cos(th), 2.0 * np.sin(th), np.full(60, 1.5)] + rng.normal(0.0, 0.02, (60, 3))
    centre = np.array([3.0, -1.0, 0.0])
    cams = local @ R.T + centre
    truth = centre + R @ [0.0, 0.0, 1.5]
    fitted = orbit_centre(cams, up)
    assert np.linalg.norm(fitted - truth) < 0.03, fitted
    assert np.linalg.norm(cams.mean(axis=0) - truth) > 0.7
    line = np.c_[np.linspace(0.0, 10.0, 30), np.zeros(30), np.ones(30)] + rng.normal(0.0, 0.01, (30, 3))
    assert np.allclose(orbit_centre(line), line.mean(axis=0))
    assert np.allclose(orbit_centre(cams[:4], up), cams[:4].mean(axis=0))

