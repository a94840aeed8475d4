"""Evidence for the report (measure/evidence.py): the box's corners and the recording time."""

from __future__ import annotations


import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from measure.evidence import box_corners_world, recording_time


def _measurement(R, t, rect, h):
    return {"height_m": h, "axes": {"rectangle_xy_m": rect.tolist()},
            "frame": {"rotation": R.tolist(), "translation_m": t.tolist()}}


def test_box_corners_go_back_to_the_ground_frame():
    R = Rotation.from_euler("xyz", [20, -35, 70], degrees=True).as_matrix()
    t = np.array([0.3, -1.2, 2.0])
    rect = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 2.0], [0.0, 2.0]]) + [1.5, -0.5]
    corners = box_corners_world(_measurement(R, t, rect, 3.2))
    ground = corners @ R.T + t  # the measurement's own frame: rotation @ p + translation
    assert np.allclose(ground[:4, :2], rect) and np.allclose(ground[4:, :2], rect)
    assert np.allclose(ground[:4, 2], 0.0) and np.allclose(ground[4:, 2], 3.2)
    assert box_corners_world({"height_m": 1.0}) is None  # an older record without the frame


def test_recording_time_says_when_the_container_has_none(tmp_path):
    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 32))
    writer.write(np.zeros((32, 64, 3), np.uint8))
    writer.release()
    r = recording_time(video)
    assert r["recorded"] is None and r["source"] == "not in the container" and r["file_modified_utc"].endswith("Z")
    assert recording_time(tmp_path / "absent.avi")["source"] == "file not found"
