"""stereo-recon synth outputs: calibration files agree, determinism, truth matches the mesh, CLI errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from stereo_recon.synthetic.camera import SYNTH_SERIAL, zed2_rig
from stereo_recon.synthetic.presets import get_preset
from stereo_recon.synthetic.sequence import render_sequence
from stereo_recon.synthetic.scene import truck_scene


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "model"
    truth = render_sequence("model-truck", out, seed=7, frames=3, resolution="VGA", depth=True)
    return out, truth


def test_output_folder_has_every_file(seq):
    out, truth = seq
    names = {p.name for p in out.iterdir()}
    assert {"video.avi", f"SN{SYNTH_SERIAL}.conf", "rig.yaml", "truth.json", "poses_gt.txt", "depth", "synth_run.json"} <= names
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["000000.npy", "000001.npy", "000002.npy"]
    cap = cv2.VideoCapture(str(out / "video.avi"))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    assert len(frames) == 3 and frames[0].shape == (376, 2 * 672, 3)
    # Side by side, left eye on the left: the two halves differ but look alike.
    left, right = frames[0][:, :672], frames[0][:, 672:]
    assert 1.0 < np.abs(left.astype(float) - right.astype(float)).mean() < 60.0
    d = np.load(out / "depth" / "000000.npy")
    assert d.dtype == np.float32 and d.shape == (376, 672)
    assert np.isfinite(d).mean() > 0.5 and np.nanmin(d[np.isfinite(d)]) > 0.3
    on_disk = json.loads((out / "truth.json").read_text())
    assert on_disk["length_m"] == 2.1 and on_disk["over_limit_expectation"]["verdict"] == "not-applicable"
    assert on_disk == json.loads(json.dumps(truth))
    corners = np.array(on_disk["truck_corners_world_m"])
    T = np.array(on_disk["truck"]["T_world_truck"])
    q = (corners - T[:3, 3]) @ T[:3, :3]
    np.testing.assert_allclose(q.max(axis=0) - q.min(axis=0), [2.1, 0.38, 0.38], atol=1e-12)


def test_conf_and_rig_yaml_describe_the_same_rig(seq):
    from calib.io import load_rig

    out, _ = seq
    a = load_rig(out / f"SN{SYNTH_SERIAL}.conf", image_size=(672, 376))
    b = load_rig(out / "rig.yaml")
    ref = zed2_rig("VGA")
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-9, err_msg=name)
        np.testing.assert_allclose(getattr(b, name), getattr(ref, name), atol=1e-9, err_msg=name)
    assert a.image_size == b.image_size == (672, 376) and not b.rectified
    # The ZED-like misalignment is really there: mrad rotations, sub-mm TY/TZ, 120 mm baseline.
    rv = cv2.Rodrigues(b.R)[0].ravel()
    assert 0.0003 < np.abs(rv).max() < 0.005 and 0 < np.abs(b.T[1:]).max() < 0.001 and abs(b.baseline_m - 0.12) < 0.001


def test_poses_are_world_from_left_camera_looking_at_the_truck(seq):
    from stereo_recon.trajectory import read_tum

    out, truth = seq
    traj = read_tum(out / "poses_gt.txt", fps=truth["fps"])
    assert len(traj) == 3 and np.allclose(traj.timestamps_s, np.arange(3) / 15.0)
    for T in traj.T_wc:
        c = T[:3, 3]
        assert abs(c[2] - truth["flight"]["altitude_m"]) < 0.1  # flying ~1 m above the ground (z up)
        z_axis = T[:3, 2]
        to_truck = -c / np.linalg.norm(c)
        assert np.dot(z_axis, to_truck) > 0.95  # optical axis at the truck (up to the gimbal jitter)
    # The GT depth agrees with the poses: the centre pixel's ray hits the ground or the truck.
    d = np.load(out / "depth" / "000000.npy")
    assert 1.0 < d[188, 336] < 3.0


def test_same_seed_same_bytes_other_seed_other_video(tmp_path, seq):
    out1, _ = seq
    out2 = tmp_path / "again"
    out3 = tmp_path / "other"
    render_sequence("model-truck", out2, seed=7, frames=3, resolution="VGA", depth=True)
    render_sequence("model-truck", out3, seed=8, frames=3, resolution="VGA")
    for name in ("video.avi", f"SN{SYNTH_SERIAL}.conf", "rig.yaml", "truth.json", "poses_gt.txt", "depth/000002.npy"):
        assert (out1 / name).read_bytes() == (out2 / name).read_bytes(), name
    assert (out1 / "video.avi").read_bytes() != (out3 / "video.avi").read_bytes()


@pytest.mark.parametrize("preset", ["model-truck", "full-truck", "over-height", "two-vehicles", "table2:1", "table2:9", "table2:16"])
def test_truth_matches_the_mesh_bounding_box_in_the_truck_frame(preset):
    from stereo_recon.synthetic.presets import over_limit_expectation

    p = get_preset(preset)
    scene = truck_scene(p.truck, truck_yaw_rad=np.deg2rad(p.truck_yaw_deg), texel_m=p.texel_m, n_distractors=p.n_distractors,
                        second_truck=p.second_truck, second_offset_m=p.second_gap_m, rng=0)
    T = scene.info["truck_T_world"]
    sel = np.array([m.startswith("truck.") for m in scene.mesh.materials])
    v = scene.mesh.vertices[np.unique(scene.mesh.triangles[sel])]
    q = (v - T[:3, 3]) @ T[:3, :3]
    t = p.truck
    np.testing.assert_allclose(q.min(axis=0), [-t.length_m / 2, -t.width_m / 2, 0.0], atol=1e-9)
    np.testing.assert_allclose(q.max(axis=0), [t.length_m / 2, t.width_m / 2, t.height_m], atol=1e-9)
    # Nothing else in the scene intrudes into the truck's box (distractors and the second truck keep clear).
    others = scene.mesh.vertices[np.unique(scene.mesh.triangles[~sel & np.array([m != "ground" for m in scene.mesh.materials])])]
    qo = (others - T[:3, 3]) @ T[:3, :3]
    inside = (np.abs(qo[:, 0]) <= t.length_m / 2) & (np.abs(qo[:, 1]) <= t.width_m / 2) & (qo[:, 2] <= t.height_m)
    assert not inside.any()
    exp = over_limit_expectation(p)
    assert exp["verdict"] == {"full-truck": "within-limits", "over-height": "over-limit"}.get(preset, "not-applicable")


def test_distractors_do_not_overlap():
    p = get_preset("model-truck")
    scene = truck_scene(p.truck, n_distractors=12, rng=5)
    ds = scene.info["distractors"]
    assert len(ds) >= 8
    for i, a in enumerate(ds):
        for b in ds[i + 1:]:
            assert np.hypot(a["x_m"] - b["x_m"], a["y_m"] - b["y_m"]) >= a["radius_m"] + b["radius_m"]


def test_table2_presets_carry_the_paper_sizes():
    p = get_preset("table2:14")
    assert (p.truck.length_m, p.truck.width_m, p.truck.height_m) == (2.384, 0.352, 0.42)
    assert get_preset("table2:1").truck.length_m == 1.157 and get_preset("table2:20").truck.height_m == 0.415


def test_cli_synth_and_its_one_line_errors(tmp_path, capsys):
    from stereo_recon.app.cli import main

    out = tmp_path / "cli"
    assert main(["synth", "--preset", "table2:3", "--out", str(out), "--frames", "1", "--resolution", "VGA", "--rectified", "--no-shadows"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["camera"]["rectified"] and truth["table2_subject"] == 3 and not list(out.glob("SN*.conf"))
    from calib.io import load_rig

    assert load_rig(out / "rig.yaml").rectified
    mp4 = tmp_path / "mp4"
    assert main(["synth", "--preset", "model-truck", "--out", str(mp4), "--frames", "2", "--resolution", "VGA", "--format", "mp4", "--flight", "pass"]) == 0
    assert json.loads((mp4 / "truth.json").read_text())["flight"]["type"] == "pass"
    cap = cv2.VideoCapture(str(mp4 / "video.mp4"))
    ok, frame = cap.read()
    assert ok and frame.shape == (376, 1344, 3)
    capsys.readouterr()
    for argv in (["--preset", "nope"], ["--preset", "table2:0"], ["--preset", "model-truck", "--resolution", "8K"],
                 ["--preset", "model-truck", "--frames", "0"], ["--preset", "model-truck", "--quality", "0"]):
        bad = tmp_path / "bad"
        assert main(["synth", "--out", str(bad), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("stereo-recon synth: error:") and "\n" not in err
        assert not bad.exists()  # nothing half-written


def test_calibration_board_is_detectable_in_both_eyes(tmp_path):
    truth = render_sequence("calibration-board", tmp_path / "cb", seed=0, frames=3, resolution="VGA", video_format="avi")
    assert truth["board"]["inner_corners"] == [9, 6]
    cap = cv2.VideoCapture(str(tmp_path / "cb" / "video.avi"))
    found = 0
    for _ in range(3):
        ok, f = cap.read()
        assert ok
        for eye in (f[:, :672], f[:, 672:]):
            found += cv2.findChessboardCorners(cv2.cvtColor(eye, cv2.COLOR_BGR2GRAY), (9, 6))[0]
    assert found >= 4
