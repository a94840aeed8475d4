"""Evidence for the report: the recording's own date/time, and a frame of the video with the measured box drawn on it.

Both read what the reconstruction left in the run folder (``run.json``: source video, rig intrinsics and
distortion; ``poses.txt``: TUM world-from-left-camera poses) and the measurement (its ground frame and
fitted rectangle), so they work for any run folder, and say "not available" rather than guess.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

log = logging.getLogger(__name__)

# The 12 edges of a box whose corners are ordered bottom 0-3 (rectangle order), top 4-7 above them.
_BOX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def recording_time(video: str | os.PathLike) -> dict:
    """When the video was recorded, from its container (MP4 'mvhd', AVI 'IDIT', MKV 'DateUTC') via hachoir.

    Returns {"recorded": ISO text or None, "source": where it came from, "file_modified_utc": ISO text or None}.
    The file's modification time is reported separately: copying a file changes it, so it is no recording time.
    """
    path = Path(video)
    out: dict[str, Any] = {"recorded": None, "source": "not in the container", "file_modified_utc": None}
    try:
        out["file_modified_utc"] = _dt.datetime.fromtimestamp(path.stat().st_mtime, _dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    except OSError:
        return dict(out, source="file not found")
    if not path.is_file():
        return dict(out, source="a folder of images (no container)")
    try:
        from hachoir.core import config as hachoir_config
        from hachoir.metadata import extractMetadata
        from hachoir.parser import createParser

        hachoir_config.quiet = True  # its parser warnings are not the user's concern
        parser = createParser(str(path))
        if parser is None:
            return dict(out, source="container not recognised")
        with parser:
            meta = extractMetadata(parser)
        when = meta.get("creation_date", None) if meta is not None and meta.has("creation_date") else None
    except Exception as err:  # a damaged or odd container only loses the date
        log.debug("recording time of %s: %s", path, err)
        return dict(out, source=f"container not readable ({type(err).__name__})")
    # MP4 writers that know no date store 0, i.e. 1904-01-01: not a recording time.
    if isinstance(when, _dt.datetime) and when.year > 1970:
        out.update(recorded=when.isoformat(sep=" "), source="container metadata (creation date)")
    return out


def box_corners_world(measurement: Mapping[str, Any]) -> np.ndarray | None:
    """The measured box's 8 corners (8, 3) in the cloud's frame, metres; None when the record lacks the frame.

    Bottom corners are the fitted rectangle (``axes.rectangle_xy_m``, ground frame) at height 0, top corners the
    same at ``height_m``; the ground frame is ``frame.rotation @ p + frame.translation_m`` (Eqs. 5-6), inverted here.
    """
    try:
        rect = np.asarray(measurement["axes"]["rectangle_xy_m"], float).reshape(4, 2)
        R = np.asarray(measurement["frame"]["rotation"], float).reshape(3, 3)
        t = np.asarray(measurement["frame"]["translation_m"], float).reshape(3)
        h = float(measurement["height_m"])
    except (KeyError, TypeError, ValueError):
        return None
    ground = np.vstack([np.c_[rect, np.zeros(4)], np.c_[rect, np.full(4, h)]])
    return (ground - t) @ R  # R is orthonormal: p = R^T (g - t)


def _project(corners_w: np.ndarray, T_wc: np.ndarray, K: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (8, 2) of world points in a camera and their depths (8,), with OpenCV's lens model."""
    import cv2

    R_cw = T_wc[:3, :3].T
    t_cw = -R_cw @ T_wc[:3, 3]
    z = (corners_w @ R_cw.T + t_cw)[:, 2]
    px, _ = cv2.projectPoints(corners_w.astype(np.float64), cv2.Rodrigues(R_cw)[0], t_cw, K, D)
    return px.reshape(-1, 2), z


def best_view(corners_w: np.ndarray, poses: list[tuple[float, np.ndarray]], K: np.ndarray, D: np.ndarray,
              size: tuple[int, int], margin_px: float = 8.0) -> int | None:
    """Index of the pose that sees the whole box largest (all corners in front and inside the image), or None."""
    best, best_area = None, 0.0
    w, h = size
    for i, (_, T) in enumerate(poses):
        px, z = _project(corners_w, T, K, D)
        if (z <= 0).any():
            continue
        inside = (px[:, 0] >= margin_px) & (px[:, 0] <= w - margin_px) & (px[:, 1] >= margin_px) & (px[:, 1] <= h - margin_px)
        if not inside.all():
            continue
        area = float(np.ptp(px[:, 0]) * np.ptp(px[:, 1]))
        if area > best_area:
            best, best_area = i, area
    return best


def keyframe_with_box(run_dir: str | os.PathLike, measurement: Mapping[str, Any], out_path: str | os.PathLike) -> dict | None:
    """Draw the measured box on the video frame that shows it largest; write a JPEG. None when not possible.

    run_dir: the run folder (``run.json`` with the source and the rig, ``poses.txt``). The box is projected into
    the physical left camera's raw frame with its intrinsics K1 and distortion D1 (run.json ``rig``), at the pose
    poses.txt gives for that frame. Returns {"frame": index, "time_s": t, "path": out_path}.
    """
    import cv2

    from stereo_recon.errors import StereoReconError
    from stereo_recon.trajectory import read_tum
    from stereo_recon.video import open_stereo_source

    run_dir = Path(run_dir)
    corners = box_corners_world(measurement)
    try:
        run = json.loads((run_dir / "run.json").read_text(encoding="utf-8"))
        rig = run["rig"]
        K, D = np.asarray(rig["K1"], float), np.asarray(rig["D1"], float).reshape(-1)
        size = tuple(int(v) for v in rig["image_size"])
        fps = float(run["source"]["fps"])
        video = Path(run["source"]["path"])
        traj = read_tum(run_dir / "poses.txt", fps=fps)
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
    px, _ = _project(corners, T, K, D)
    thick = max(2, size[0] // 400)
    for a, b in _BOX_EDGES:
        colour = (0, 215, 255) if a >= 4 and b >= 4 else (40, 40, 230)  # roof amber, the rest red (BGR)
        p0, p1 = (int(round(v)) for v in px[a]), (int(round(v)) for v in px[b])
        cv2.line(img, tuple(p0), tuple(p1), colour, thick, cv2.LINE_AA)
    out_path = Path(out_path)
    if not cv2.imwrite(str(out_path), img, [cv2.IMWRITE_JPEG_QUALITY, 85]):
        return None
    return {"frame": index, "time_s": t, "path": str(out_path)}
