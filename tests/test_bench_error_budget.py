"""benchmarks/bench_error_budget.py: the error split recovers known scale and wall offsets."""

from __future__ import annotations

import json

import numpy as np

from stereo_recon.core.cloud_io import write_cloud
from stereo_recon.trajectory import Trajectory, write_tum


def _box_surface(L, W, H, left_mm, right_mm, roof_mm, rng, n=20_000):
    """Points on a box's two side walls and roof (truck frame), each face moved by a known offset."""
    x = rng.uniform(-L / 2, L / 2, 3 * n)
    zw = rng.uniform(0.1 * H, H, n)
    yr = rng.uniform(-W / 2, W / 2, n)
    left = np.c_[x[:n], np.full(n, W / 2 + left_mm / 1000), zw]
    right = np.c_[x[n:2 * n], np.full(n, -W / 2 - right_mm / 1000), zw]
    roof = np.c_[x[2 * n:], yr, np.full(n, H + roof_mm / 1000)]
    return np.vstack([left, right, roof]) + rng.normal(0, 0.0005, (3 * n, 3))


def test_budget_recovers_scale_walls_and_measurement_share(tmp_path, rng, benchmark_module):
    L, W, H = 2.0, 0.4, 0.4
    yaw = np.radians(30)
    T_wt = np.eye(4)
    T_wt[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T_wt[:3, 3] = [0.3, -0.2, 0.0]
    # Ground-truth orbit; the run's trajectory and cloud are the truth shrunk by 0.5 % about the origin.
    n = 24
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    T_gt = np.repeat(np.eye(4)[None], n, 0)
    T_gt[:, :3, 3] = np.c_[2 * np.cos(a), 2 * np.sin(a), np.full(n, 1.0)]
    k = 0.995
    T_est = T_gt.copy()
    T_est[:, :3, 3] *= k
    idx = np.arange(n)
    scene, run = tmp_path / "scenes" / "t", tmp_path / "runs" / "t"
    scene.mkdir(parents=True)
    run.mkdir(parents=True)
    write_tum(scene / "poses_gt.txt", Trajectory(idx, idx / 15.0, T_gt))
    write_tum(run / "poses.txt", Trajectory(idx, idx / 15.0, T_est))
    pts_truck = _box_surface(L, W, H, left_mm=2.0, right_mm=-3.0, roof_mm=-1.0, rng=rng)
    world = pts_truck @ T_wt[:3, :3].T + T_wt[:3, 3]
    write_cloud(run / "cloud.ply", k * world)
    truth = {"fps": 15.0, "length_m": L, "width_m": W, "height_m": H,
             "truck": {"body": "box", "T_world_truck": T_wt.tolist()}}
    (scene / "truth.json").write_text(json.dumps(truth))
    measured_w = k * (W - 0.001) - 0.002  # walls' net -1 mm, then a measurement 2 mm narrower still
    (run / "measurement.json").write_text(json.dumps({"width_m": measured_w, "height_m": k * H}))

    r = benchmark_module("bench_error_budget").budget(run, scene)
    assert abs(r["scale_pct"] - (100 * (k - 1))) < 0.01
    assert abs(r["wall_left_mm"] - 2.0) < 0.2
    assert abs(r["wall_right_mm"] + 3.0) < 0.2
    assert abs(r["roof_mm"] + 1.0) < 0.2
    assert abs(r["width_err_pct"] - 100 * (measured_w / W - 1)) < 1e-9
    # The measurement's share is what scale and walls leave: -2 mm of 0.4 m (x k) = -0.50 %.
    assert abs(r["width_measurement_pct"] - (-0.5)) < 0.06


def test_budget_reads_a_tankers_flanks_against_its_elliptic_shell_and_in_voxels(tmp_path, rng, benchmark_module):
    from stereo_recon.synthetic.scene import TruckSpec, truck_layout

    L, W, H = 2.0, 0.40, 0.50
    lay = truck_layout(TruckSpec(length_m=L, width_m=W, height_m=H, body="tanker", cab_length_frac=0.2, cab_height_frac=0.8))
    zc, b, a = 0.5 * (lay.z_floor_m + H), 0.5 * (H - lay.z_floor_m), W / 2
    # The shell's upper flanks, each moved horizontally by a known offset (left -4 mm, right -2 mm), and its crest.
    n = 30_000
    x = rng.uniform(-0.45 * L, 0.3 * L, n)
    th = rng.uniform(-0.5 * np.pi, 0.5 * np.pi, n)  # from the underside up over the widest line to the crest
    side = np.where(rng.random(n) < 0.5, 1.0, -1.0)
    offset = np.where(side > 0, -0.004, -0.002)
    y = side * (a * np.cos(th) + offset)
    z = zc + b * np.sin(th)
    pts = np.c_[x, y, z] + rng.normal(0, 0.0003, (n, 3))
    idx = np.arange(8)
    T = np.repeat(np.eye(4)[None], 8, 0)
    T[:, :3, 3] = np.c_[3 * np.cos(idx), 3 * np.sin(idx), np.full(8, 1.5)]
    scene, run = tmp_path / "draws" / "d", tmp_path / "runs" / "d"
    scene.mkdir(parents=True)
    run.mkdir(parents=True)
    write_tum(scene / "poses_gt.txt", Trajectory(idx, idx / 15.0, T))
    write_tum(run / "poses.txt", Trajectory(idx, idx / 15.0, T))
    write_cloud(run / "cloud.ply", pts)
    (scene / "truth.json").write_text(json.dumps({
        "fps": 15.0, "length_m": L, "width_m": W, "height_m": H,
        "truck": {"body": "tanker", "T_world_truck": np.eye(4).tolist(), "cab_length_frac": 0.2, "cab_height_frac": 0.8}}))
    (run / "measurement.json").write_text(json.dumps({"width_m": W - 0.006, "height_m": H}))
    (run / "run.json").write_text(json.dumps({"voxel_m": 0.002}))

    r = benchmark_module("bench_error_budget").budget(run, scene)
    assert abs(r["wall_left_mm"] + 4.0) < 0.3 and abs(r["wall_right_mm"] + 2.0) < 0.3, r
    assert abs(r["walls_voxels"] + 1.5) < 0.15, r   # (-4 - 2) / 2 mm = -3 mm = -1.5 voxels of 2 mm
    assert abs(r["width_measurement_pct"]) < 0.2, r  # the measured width is the flanks' own
