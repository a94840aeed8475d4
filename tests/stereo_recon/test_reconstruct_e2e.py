"""``reconstruct`` end to end on a rendered stereo orbit of a textured box (known poses and geometry)."""

from __future__ import annotations

import hashlib

import json

import numpy as np
import pytest

o3d = pytest.importorskip("open3d")
cv2 = pytest.importorskip("cv2")
pytest.importorskip("calib.rig")

from calib.rig import StereoRig  # noqa: E402
from stereo_recon.app.cli import main as cli_main  # noqa: E402
from stereo_recon.core.errors import InputError, StageError  # noqa: E402
from stereo_recon.reconstruct import ReconstructConfig, reconstruct  # noqa: E402
from stereo_recon.trajectory import Trajectory, write_tum  # noqa: E402
from stereo_recon.synthetic.flight import look_at  # noqa: E402

# Every test here renders or reconstructs a sequence (module fixture ~10-15 s on 2 cores).
pytestmark = pytest.mark.slow

W, H = 320, 240
F, B = 300.0, 0.12
K = np.array([[F, 0, W / 2 - 0.5], [0, F, H / 2 - 0.5], [0, 0, 1.0]])
BOX_MIN = np.array([-0.6013, -0.4021, 0.0])
BOX_MAX = np.array([0.6013, 0.4021, 0.5037])
FPS = 10.0


def _texture(p):
    """Procedural grey texture on world points (N, 3): blocky value noise at 2 cm plus stripes."""
    q = np.floor(p / 0.02).astype(np.int64)
    h = (q[:, 0] * 73856093) ^ (q[:, 1] * 19349663) ^ (q[:, 2] * 83492791)
    noise = (h % 251) / 250.0
    stripes = 0.5 + 0.5 * np.sin(p @ np.array([37.0, 53.0, 41.0]))
    return np.clip(40 + 150 * noise + 50 * stripes, 0, 255)


def _render(scene, T_wc):
    u, v = np.meshgrid(np.arange(W) + 0.0, np.arange(H) + 0.0)
    d = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)], -1).reshape(-1, 3) @ T_wc[:3, :3].T
    rays = np.hstack([np.repeat(T_wc[:3, 3][None], len(d), 0), d]).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    hit = np.isfinite(t)
    p = T_wc[:3, 3] + d * np.where(hit, t, 0)[:, None]
    g = np.where(hit, _texture(p), 0).reshape(H, W).astype(np.uint8)
    return cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)


@pytest.fixture(scope="module")
def orbit(box_on_ground, tmp_path_factory):
    """Folder of side-by-side frames of a rectified rig orbiting the box (7.5 deg per frame), and the true poses."""
    root = tmp_path_factory.mktemp("orbit")
    scene = box_on_ground(BOX_MIN, BOX_MAX)
    frames = root / "frames"
    frames.mkdir()
    poses = []
    n = 48
    for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False)):
        T = look_at(np.array([2.4 * np.cos(a), 2.4 * np.sin(a), 1.5]), np.array([0, 0, 0.2]))
        Tr = T.copy()
        Tr[:3, 3] = T[:3, 3] + T[:3, 0] * B  # right eye: +B along the left camera's x
        cv2.imwrite(str(frames / f"{i:04d}.png"), np.hstack([_render(scene, T), _render(scene, Tr)]))
        poses.append(T)
    traj = Trajectory(np.arange(n), np.arange(n) / FPS, np.stack(poses))
    write_tum(root / "poses_gt.txt", traj)
    return root, traj, scene


def _rig():
    return StereoRig.from_rectified(F, F, K[0, 2], K[1, 2], B, (W, H))


def test_reconstruct_with_known_poses_recovers_box(orbit, tmp_path):
    root, traj, scene = orbit
    cfg = ReconstructConfig(poses=f"gt:{root / 'poses_gt.txt'}", fps=FPS, depth_min_m=1.0, depth_max_m=4.0,
                            voxel_m=0.02, keyframes=None, mesh=True, step=3)
    man = reconstruct(root / "frames", _rig(), tmp_path / "out", cfg)
    out = tmp_path / "out"
    assert sorted(p.name for p in out.iterdir()) == ["cloud.ply", "mesh.ply", "poses.txt", "run.json"]
    pcd = o3d.io.read_point_cloud(str(out / "cloud.ply"))
    pts = np.asarray(pcd.points)
    assert len(pts) == man["counts"]["cloud_points"] > 5000
    dist = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    # Stereo depth error at 2.4 m: Z^2/(f B) * ~0.2 px = 3 cm per frame, averaged over ~10 views
    # by the TSDF: the median point lies within half a voxel (2 cm voxels) of the true surface
    # (measured: median 3.4 mm, 90th percentile 18 mm).
    assert np.median(dist) < 0.01
    assert np.quantile(dist, 0.9) < 0.04
    # The box top is found at its height (points above the ground in the box footprint).
    top = pts[(np.abs(pts[:, 0]) < 0.4) & (np.abs(pts[:, 1]) < 0.25) & (pts[:, 2] > 0.3)]
    assert len(top) > 100 and abs(np.median(top[:, 2]) - BOX_MAX[2]) < 0.03
    run = json.loads((out / "run.json").read_text())
    assert run["counts"]["frames_read"] == 16 and run["counts"]["keyframes_fused"] == 16
    assert run["poses"]["backend"] == "gt"
    # Up from the orbit plane: world +z.
    assert np.dot(run["up"], [0, 0, 1]) > 0.999
    assert run["inputs"]["poses_gt"]["sha256"] and run["parameters"]["disparity"]["mode"] == "sgbm3way"
    assert set(run["timings_s"]) >= {"rectify", "disparity", "fusion", "total"}


def test_same_input_gives_the_same_cloud_bytes(orbit, tmp_path):
    """Reproducible runs: the fused volume's thread-dependent block order must not reach cloud.ply."""
    root, _, _ = orbit
    cfg = ReconstructConfig(poses=f"gt:{root / 'poses_gt.txt'}", fps=FPS, depth_min_m=1.0, depth_max_m=4.0,
                            voxel_m=0.02, keyframes=None, step=4)
    digests = []
    for name in ("a", "b"):
        reconstruct(root / "frames", _rig(), tmp_path / name, cfg)
        digests.append(hashlib.sha256((tmp_path / name / "cloud.ply").read_bytes()).hexdigest())
    assert digests[0] == digests[1]


def test_consistency_filter_keeps_an_accurate_subset(orbit, tmp_path):
    """With the multi-view consistency filter the cloud is a subset in size and stays on the surface."""
    root, _, scene = orbit
    counts = {}
    for name, views in (("all", None), ("consistent", 3)):
        cfg = ReconstructConfig(poses=f"gt:{root / 'poses_gt.txt'}", fps=FPS, depth_min_m=1.0, depth_max_m=4.0,
                                voxel_m=0.02, keyframes=None, step=4, consistency_views=views)
        man = reconstruct(root / "frames", _rig(), tmp_path / name, cfg)
        counts[name] = man["counts"]["cloud_points"]
        pts = np.asarray(o3d.io.read_point_cloud(str(tmp_path / name / "cloud.ply")).points)
        dist = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
        assert np.median(dist) < 0.01, name
    assert 0 < counts["consistent"] <= counts["all"], counts


def test_reconstruct_errors_leave_nothing(orbit, tmp_path):
    root, traj, _ = orbit
    out = tmp_path / "out"
    # Too few frames.
    with pytest.raises(StageError, match="input: .*only 2 frames"):
        reconstruct(root / "frames", _rig(), out, ReconstructConfig(poses=f"gt:{root / 'poses_gt.txt'}",
                                                                     frame_range=(0, 4), step=2))
    # Rig of a different aspect.
    bad_rig = StereoRig.from_rectified(F, F, 160, 160, B, (320, 320))
    with pytest.raises(InputError, match="calibration"):
        reconstruct(root / "frames", bad_rig, out, ReconstructConfig(poses=f"gt:{root / 'poses_gt.txt'}"))
    # Poses that cover no frame -> a pose-stage error, not a crash.
    write_tum(tmp_path / "far.txt", Trajectory([0], [1000.0], np.eye(4)[None]))
    with pytest.raises(StageError, match="poses: "):
        reconstruct(root / "frames", _rig(), out, ReconstructConfig(poses=f"gt:{tmp_path / 'far.txt'}", fps=FPS,
                                                                     depth_min_m=1.0, depth_max_m=4.0))
    assert not out.exists() or not any(out.iterdir())
    assert not any(p.name.startswith(".out.tmp") for p in tmp_path.iterdir())


def test_cli_one_line_errors(orbit, tmp_path, capsys):
    root, _, _ = orbit
    calib = f"{F},{F},{K[0, 2]},{K[1, 2]},{B}"
    (tmp_path / "junk.avi").write_bytes(b"\x00" * 1000)
    rc = cli_main(["reconstruct", str(tmp_path / "junk.avi"), "--calib", calib, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0 and len(err) == 1 and "junk.avi" in err[0]
    rc = cli_main(["reconstruct", str(root / "frames"), "--calib", calib, "--out", str(tmp_path / "o"),
                   "--poses", "magic"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0 and len(err) == 1 and "--poses" in err[0]
    assert not (tmp_path / "o").exists()


def test_cli_reconstruct_gt_poses(orbit, tmp_path, capsys):
    root, _, _ = orbit
    calib = f"{F},{F},{K[0, 2]},{K[1, 2]},{B}"
    rc = cli_main(["reconstruct", str(root / "frames"), "--calib", calib, "--out", str(tmp_path / "o"),
                   "--poses", f"gt:{root / 'poses_gt.txt'}", "--fps", str(FPS), "--depth-min-m", "1",
                   "--depth-max-m", "4", "--step", "6", "--preset", "fast"])
    assert rc == 0
    assert "cloud:" in capsys.readouterr().out
    run = json.loads((tmp_path / "o" / "run.json").read_text())
    assert run["source"]["step"] == 6 and run["counts"]["frames_read"] == 8


def test_reconstruct_with_visual_odometry(orbit, tmp_path):
    pytest.importorskip("stereo_recon.odometry")
    from stereo_recon.trajectory import absolute_trajectory_error, read_tum

    root, gt, scene = orbit
    # This small low-resolution scene has ~10 px of disparity, a "far scene" by the default threshold;
    # the fast path on sparse stereo is what is tested here (far scenes: test_reconstruct_synth.py).
    cfg = ReconstructConfig(poses="vo", fps=FPS, depth_min_m=1.0, depth_max_m=4.0, voxel_m=0.02,
                            far_scene_depth_baselines=None)
    man = reconstruct(root / "frames", _rig(), tmp_path / "out", cfg)
    est = read_tum(tmp_path / "out" / "poses.txt", fps=FPS)
    assert len(est) == 48 and man["poses"]["tracking_gaps"] == []
    # The fast path: VO tracks on sparse stereo, SGBM runs only for the fused views, spread by pose
    # (7.5 deg per frame, a view every 18 deg -> every 3rd frame: 16, plus frame 1, chosen before any view's
    # depth is used by the selector, so that the choice never depends on the depth worker's speed).
    cnt = man["counts"]
    assert cnt["frames_depth"] == cnt["keyframes"] == cnt["keyframes_fused"] == 17
    ate = absolute_trajectory_error(est, gt, with_scale=False)
    # Metric VO on a closed 15 m orbit (measured 0.8 % of the path); the bound is 1 %.
    assert ate["rmse_m"] < 0.015 * gt.path_length_m()
    # The VO world frame is the first camera's (its pose stays the identity): map the cloud with the true first pose.
    assert np.allclose(est.T_wc[0], np.eye(4), atol=1e-6)
    T0 = gt.T_wc[0]
    pts = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "out" / "cloud.ply")).points) @ T0[:3, :3].T + T0[:3, 3]
    dist = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    # Measured 2.3 cm (the VO drift of ~1 % of the path dominates; with exact poses it is 3 mm).
    assert np.median(dist) < 0.04
    # "up" from the orbit is the world z axis, expressed in the VO frame.
    assert np.dot(T0[:3, :3] @ np.asarray(man["up"]), [0, 0, 1]) > 0.99


def test_raw_rig_goes_through_rectification(orbit, tmp_path):
    # An unrectified rig description of the same ideal cameras (D = 0, R = I): stereoRectify + remap
    # must give (nearly) the identity, so the fused surface is as accurate as with the rectified rig.
    root, _, scene = orbit
    raw = StereoRig(K1=K, D1=np.zeros(5), K2=K.copy(), D2=np.zeros(5), R=np.eye(3), T=np.array([-B, 0.0, 0.0]),
                    image_size=(W, H))
    cfg = ReconstructConfig(poses=f"gt:{root / 'poses_gt.txt'}", fps=FPS, depth_min_m=1.0, depth_max_m=4.0,
                            voxel_m=0.02, keyframes=None, step=4)
    man = reconstruct(root / "frames", raw, tmp_path / "out", cfg)
    assert man["rig"]["rectified_input"] is False
    assert np.allclose(np.asarray(man["rig"]["rectified"]["K_rect"]), K, atol=1.0)
    pts = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "out" / "cloud.ply")).points)
    dist = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    assert np.median(dist) < 0.01


def test_cli_export_colmap_and_cloud_normals(orbit, tmp_path, capsys):
    """--export-colmap: a COLMAP model whose poses are poses.txt's fused views; cloud.ply normals face outward."""
    pycolmap = pytest.importorskip("pycolmap")
    from stereo_recon.trajectory import read_tum

    root, _, _ = orbit
    calib = f"{F},{F},{K[0, 2]},{K[1, 2]},{B},{W},{H}"
    out, colmap = tmp_path / "o", tmp_path / "colmap"
    rc = cli_main(["reconstruct", str(root / "frames"), "--calib", calib, "--out", str(out),
                   "--poses", f"gt:{root / 'poses_gt.txt'}", "--fps", str(FPS), "--depth-min-m", "1",
                   "--depth-max-m", "4", "--step", "6", "--preset", "fast", "--export-colmap", str(colmap)])
    assert rc == 0 and "COLMAP model" in capsys.readouterr().out
    run = json.loads((out / "run.json").read_text())
    rec = pycolmap.Reconstruction(str(colmap / "sparse" / "0"))
    traj = read_tum(out / "poses.txt", fps=FPS)
    pose_of = {int(i): T for i, T in zip(traj.indices, traj.T_wc)}
    assert rec.num_images() == len(run["fused_views"]) == run["counts"]["keyframes_fused"] > 0
    cam = rec.cameras[1]
    assert (cam.width, cam.height) == (W, H) and np.allclose(cam.params[:4], [F, F, K[0, 2], K[1, 2]])
    for image in rec.images.values():
        idx = int(image.name.removeprefix("frame_").removesuffix(".png"))
        T_cw = np.vstack([image.cam_from_world().matrix(), [0, 0, 0, 1]])
        assert np.allclose(np.linalg.inv(T_cw), pose_of[idx], atol=1e-6)
        assert (colmap / "images" / image.name).is_file()
    # normals: unit length, and on the box's top they point up (toward the cameras above), not into the box
    pcd = o3d.io.read_point_cloud(str(out / "cloud.ply"))
    pts, nrm = np.asarray(pcd.points), np.asarray(pcd.normals)
    assert nrm.shape == pts.shape and np.allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-6)
    top = (np.abs(pts[:, 0]) < 0.4) & (np.abs(pts[:, 1]) < 0.25) & (pts[:, 2] > BOX_MAX[2] - 0.03)
    assert top.sum() > 50 and np.median(nrm[top, 2]) > 0.9
    side = (pts[:, 0] > BOX_MAX[0] - 0.03) & (np.abs(pts[:, 1]) < 0.3) & (pts[:, 2] > 0.1) & (pts[:, 2] < 0.4)
    assert side.sum() > 20 and np.median(nrm[side, 0]) > 0.8
