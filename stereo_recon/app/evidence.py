"""The report's keyframe: a frame of the run's own video with the measured box drawn on it.

It reads what the reconstruction left in the run folder (``run.json``: source video, rig intrinsics and
distortion; ``poses.txt``: TUM world-from-left-camera poses), so it lives above both the reconstruction
and the measure layer; ``measure_cloud_file(keyframe=keyframe_with_box)`` calls it.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from measure.evidence import best_view, box_corners_world, draw_box
from stereo_recon.core.errors import StereoReconError
from stereo_recon.core.paths import RunPaths

log = logging.getLogger(__name__)


def keyframe_with_box(run_dir: str | os.PathLike, measurement: Mapping[str, Any], out_path: str | os.PathLike) -> dict | None:
    """Draw the measured box on the video frame that shows it largest; write a JPEG. None when not possible.

    run_dir: the run folder (``run.json`` with the source and the rig, ``poses.txt``). The box is projected into
    the physical left camera's raw frame with its intrinsics K1 and distortion D1 (run.json ``rig``), at the pose
    poses.txt gives for that frame. Returns {"frame": index, "time_s": t, "path": out_path}.
    """
    import cv2

    from stereo_recon.trajectory import read_tum
    from stereo_recon.video import open_stereo_source

    paths = RunPaths(Path(run_dir))
    corners = box_corners_world(measurement)
    try:
        run = json.loads(paths.run_json.read_text(encoding="utf-8"))
        rig = run["rig"]
        K, D = np.asarray(rig["K1"], float), np.asarray(rig["D1"], float).reshape(-1)
        size = tuple(int(v) for v in rig["image_size"])
        fps = float(run["source"]["fps"])
        video = Path(run["source"]["path"])
        traj = read_tum(paths.poses, fps=fps)
    except (OSError, KeyError, TypeError, ValueError, json.JSONDecodeError, StereoReconError) as err:
        log.info("keyframe: no run folder to take a frame from (%s)", err)
        return None
    poses = list(zip(traj.timestamps_s, traj.T_wc))
    if corners is None or not poses or not video.exists():
        return None
    i = best_view(corners, poses, K, D, size)
    if i is None:
        log.info("keyframe: no frame shows the whole box")
        return None
    t, T = poses[i]
    index = int(traj.indices[i])
    try:
        frame = next(iter(open_stereo_source(video, (index, index + 1), 1)))
    except Exception as err:  # the video moved or cannot be decoded there: the report goes without the picture
        log.warning("keyframe: cannot read frame %d of %s (%s)", index, video, err)
        return None
    img = np.ascontiguousarray(frame.left)
    if (img.shape[1], img.shape[0]) != size:
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    draw_box(img, corners, T, K, D)
    out_path = Path(out_path)
    if not cv2.imwrite(str(out_path), img, [cv2.IMWRITE_JPEG_QUALITY, 85]):
        return None
    return {"frame": index, "time_s": t, "path": str(out_path)}
