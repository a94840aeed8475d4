"""The report's keyframe (stereo_recon/app/evidence.py): a frame of the run's video with the measured box."""

from __future__ import annotations

import json

import cv2
import numpy as np

from stereo_recon.app.evidence import keyframe_with_box


def _measurement(R, t, rect, h):
    return {"height_m": h, "axes": {"rectangle_xy_m": rect.tolist()},
            "frame": {"rotation": R.tolist(), "translation_m": t.tolist()}}


def test_keyframe_draws_the_box_where_the_camera_sees_it(tmp_path):
    w, h, f = 320, 240, 200.0
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (2 * w, h))
    for _ in range(4):
        writer.write(np.full((h, 2 * w, 3), 128, np.uint8))
    writer.release()
    # camera 0 is 5 m in front of the box and sees all of it; camera 1 stands inside it (not usable)
    poses = ["# t tx ty tz qx qy qz qw", "0.0 0 0 -5 0 0 0 1", "0.1 0 0 0.2 0 0 0 1"]
    (tmp_path / "poses.txt").write_text("\n".join(poses) + "\n")
    (tmp_path / "run.json").write_text(json.dumps({
        "rig": {"K1": K.tolist(), "D1": [0, 0, 0, 0, 0], "image_size": [w, h]},
        "source": {"path": str(video), "fps": 10.0}}))
    rect = np.array([[-0.5, -0.3], [0.5, -0.3], [0.5, 0.3], [-0.5, 0.3]])
    m = _measurement(np.eye(3), np.zeros(3), rect, 0.4)
    kf = keyframe_with_box(tmp_path, m, tmp_path / "kf.jpg")
    assert kf is not None and kf["frame"] == 0
    img = cv2.imread(str(tmp_path / "kf.jpg")).astype(int)
    # corner (-0.5, -0.3, 0) at 5 m: pixel (160 - 20, 120 - 12); drawn in red over the grey frame
    u, v = int(round(w / 2 - f * 0.5 / 5)), int(round(h / 2 - f * 0.3 / 5))
    patch = img[v - 2:v + 3, u - 2:u + 3]
    assert (patch[..., 2] - patch[..., 1] > 60).any()
    assert abs(img[5, 5] - 128).max() < 10  # the rest of the frame untouched
    assert keyframe_with_box(tmp_path / "nowhere", m, tmp_path / "x.jpg") is None
