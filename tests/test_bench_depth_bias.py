"""benchmarks/bench_depth_bias.py: the per-surface depth error recovers known biases against rendered depth."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np


def test_depth_errors_per_surface_class(tmp_path, benchmark_module):
    """A camera 3 m over a 2 x 0.6 x 0.5 m box on the ground: depth 1 % too far on the roof, exact on the
    ground; the classes and the signed relative errors come back as built."""
    mod = benchmark_module("bench_depth_bias")
    w, h, f = 320, 240, 200.0
    K = np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]])
    rig = SimpleNamespace(K1=K, D1=np.zeros(5))
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down (camera z = world -z)
    T[:3, 3] = [0.0, 0.0, 3.0]
    L, W, H = 2.0, 0.6, 0.5
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    x, y = (u - K[0, 2]) / f, (v - K[1, 2]) / f          # camera-frame ray per unit z
    xw, yw = x * 3.0, -y * 3.0                           # where the ray meets z = 0
    on_roof = (np.abs(xw * (3.0 - H) / 3.0) < L / 2) & (np.abs(yw * (3.0 - H) / 3.0) < W / 2)
    z_gt = np.where(on_roof, 3.0 - H, 3.0)
    (tmp_path / "depth").mkdir()
    np.save(tmp_path / "depth" / "000000.npy", z_gt.astype(np.float32))
    truth = {"height_m": H, "length_m": L, "truck_corners_world_m": [[-1, -0.3, 0], [1, -0.3, 0], [1, 0.3, 0], [-1, 0.3, 0]]}
    z_est = z_gt * np.where(on_roof, 1.01, 1.0)
    X = np.stack([x, y, np.ones_like(x)], -1).reshape(-1, 3) * z_est.reshape(-1, 1)
    res = mod._errors(X, 0, mod._rendered_depth(tmp_path, truth), rig, T, truth)
    assert abs(res["roof"][0] - 0.01) < 1e-4, res
    assert abs(res["ground<1L"][0]) < 1e-4, res
    assert "sides" not in res  # seen from straight above: no side wall


def test_side_errors_split_by_distance_to_the_nearest_hole(tmp_path, benchmark_module):
    """A camera 1 m in front of a 2 m tall side wall (every pixel on it), a 40 x 30 px hole in the depth
    map and the depth 2 % too far within 3 px of the hole: the split puts +2 % in the 0-3 px band and
    nothing beyond 10 px."""
    mod = benchmark_module("bench_depth_bias")
    w, h, f = 320, 240, 200.0
    K = np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]])
    rig = SimpleNamespace(K1=K, D1=np.zeros(5))
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # camera z = world +y, camera y = world -z
    T[:3, 3] = [0.0, -1.3, 1.0]                                    # the wall is the plane y = -0.3
    L, W, H = 4.0, 0.6, 2.0
    z_gt = np.full((h, w), 1.0)
    (tmp_path / "depth").mkdir()
    np.save(tmp_path / "depth" / "000000.npy", z_gt.astype(np.float32))
    truth = {"height_m": H, "length_m": L, "truck_corners_world_m": [[-2, -0.3, 0], [2, -0.3, 0], [2, 0.3, 0], [-2, 0.3, 0]]}
    z_est = z_gt.copy()
    z_est[100:130, 140:180] = np.nan                               # the hole
    near = np.zeros((h, w), bool)
    near[97:133, 137:183] = True
    z_est[near & np.isfinite(z_est)] *= 1.02
    X = mod._pixels(z_est, K)
    res = mod._errors(X, 0, mod._rendered_depth(tmp_path, truth), rig, T, truth, mod._hole_distance(z_est))
    assert abs(res["sides 0-3px"][0] - 0.02) < 1e-3, res
    assert abs(res["sides 10-px"][0]) < 1e-4, res
    assert abs(res["sides"][0]) < 1e-4, res                        # the near band is a small share


def test_walls_and_a_flatbed_deck_edge_are_their_own_classes(tmp_path, benchmark_module):
    """A camera 1 m beside a truck's side plane (y = -W/2 in its own frame, turned 90 deg in the world), the depth
    0.5 % too far: a box's side plane reads as ``walls`` (20-80 % of H), a flatbed's as ``deck edge`` (its deck
    is the only part reaching that plane), each with the bias as built and without the other class."""
    mod = benchmark_module("bench_depth_bias")
    w, h, f = 320, 240, 200.0
    K = np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]])
    rig = SimpleNamespace(K1=K, D1=np.zeros(5))
    L, W, H = 4.0, 0.6, 2.0
    # The truck's x axis is the world's y axis: its side plane y_truck = -W/2 is the world plane x = +W/2.
    T_truck = np.eye(4)
    T_truck[:3, :3] = np.array([[0.0, -1.0, 0], [1.0, 0, 0], [0, 0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, 0, -1.0], [-1.0, 0, 0], [0, -1.0, 0]])  # camera z = world -x, camera y = world -z
    T[:3, 3] = [W / 2 + 1.0, 0.0, 1.0]
    z_gt = np.full((h, w), 1.0)
    (tmp_path / "depth").mkdir()
    np.save(tmp_path / "depth" / "000000.npy", z_gt.astype(np.float32))
    X = mod._pixels(z_gt * 1.005, K)
    corners = [[-W / 2, -L / 2, 0], [W / 2, -L / 2, 0], [W / 2, L / 2, 0], [-W / 2, L / 2, 0]]
    for body, cls, other in (("box", "walls", "deck edge"), ("flatbed", "deck edge", "walls")):
        truth = {"height_m": H, "length_m": L, "width_m": W, "truck_corners_world_m": corners,
                 "truck": {"body": body, "T_world_truck": T_truck.tolist()}}
        res = mod._errors(X, 0, mod._rendered_depth(tmp_path, truth), rig, T, truth)
        assert other not in res, (body, res)
        assert abs(res[cls][0] - 0.005) < 1e-4, (body, res)


def test_a_random_draw_without_depth_maps_is_rendered_again(tmp_path, benchmark_module):
    """A ``bench --random`` draw keeps no depth maps: its truth's spec renders the same scene and poses again, and
    the depth comes out as ``synth --depth`` wrote it."""
    import json
    import shutil

    from stereo_recon.app.cli import main

    mod = benchmark_module("bench_depth_bias")
    out = tmp_path / "d"
    assert main(["synth", "--random", "1", "--seed", "3", "--max-frames", "2", "--resolution", "VGA", "--depth",
                 "--out", str(out)]) == 0
    draw = next(p for p in out.iterdir() if (p / "truth.json").is_file())
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(draw / "truth.json", bare / "truth.json")
    truth = json.loads((bare / "truth.json").read_text())
    depth_of = mod._rendered_depth(bare, truth)
    for idx in (0, 1):
        again, saved = depth_of(idx), np.load(draw / "depth" / f"{idx:06d}.npy")
        assert again.shape == saved.shape
        assert np.array_equal(np.isfinite(again), np.isfinite(saved))
        ok = np.isfinite(saved)
        assert np.max(np.abs(again[ok] - saved[ok])) < 1e-6


def test_rendered_depth_resampled_into_a_rotated_view_frame(benchmark_module):
    """A tilted plane's rendered depth in the raw left eye, looked up from a view frame turned 3 deg from the
    rectified camera (itself 1 deg from the raw one): each pixel's z is the plane's along that pixel's own ray
    (within the nearest-pixel lookup), and rays that leave the rendered image are NaN."""
    from scipy.spatial.transform import Rotation

    mod = benchmark_module("bench_depth_bias")
    w, h, f = 640, 480, 500.0
    K1 = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    rig = SimpleNamespace(K1=K1, D1=np.zeros(5))
    R1 = Rotation.from_euler("y", 1.0, degrees=True).as_matrix()         # raw left -> rectified left
    R_view = Rotation.from_euler("xy", [2.0, -2.2], degrees=True).as_matrix()  # rectified left -> view
    n_raw, d = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0]), 6.0  # plane n . X = d (raw frame)
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays_raw = np.stack([(u - w / 2) / f, (v - h / 2) / f, np.ones_like(u)], -1)
    rendered = d / (rays_raw @ n_raw)                                    # z-depth: the ray has z = 1
    K_view = np.array([[250.0, 0, 160], [0, 250.0, 120], [0, 0, 1.0]])  # a half-size view
    z = mod.resample_rendered((240, 320), K_view, R_view, R1, rig, rendered)
    uv, vv = np.meshgrid(np.arange(320, dtype=float), np.arange(240, dtype=float))
    rays_view = np.stack([(uv - 160) / 250.0, (vv - 120) / 250.0, np.ones_like(uv)], -1)
    n_view = R_view @ R1 @ n_raw
    expected = d / (rays_view @ n_view)
    ok = np.isfinite(z)
    assert ok.mean() > 0.9
    assert np.nanmax(np.abs(z / expected - 1.0)) < 2e-3            # a pixel's step on a plane ~6 m out
    big = mod.resample_rendered((240, 320), np.array([[60.0, 0, 160], [0, 60.0, 120], [0, 0, 1]]), R_view, R1, rig,
                                rendered)                          # a wide view sees past the rendered image
    assert np.isnan(big[0, 0]) and np.isfinite(big[120, 160])
