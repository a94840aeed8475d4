"""Evidence for the report: the recording's own date/time, and the measured box drawn into a camera's image.

Pure geometry over the measurement (its ground frame and fitted rectangle) and given poses and intrinsics:
the measure layer never reads a reconstruction. Taking a frame of the run's video at the best pose is the
application's (:mod:`stereo_recon.app.evidence`), which hands the result to ``measure_cloud_file``.
"""

from __future__ import annotations

import datetime as _dt
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


def draw_box(img: np.ndarray, corners_w: np.ndarray, T_wc: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Draw the box's 12 edges on a BGR image (in place; returned): roof amber, the rest red.

    corners_w: (8, 3) from :func:`box_corners_world`, metres. T_wc: (4, 4) world-from-camera pose.
    K, D: the camera's OpenCV intrinsics (3, 3) and distortion, pixels of ``img``.
    """
    import cv2

    px, _ = _project(corners_w, T_wc, K, D)
    thick = max(2, img.shape[1] // 400)
    for a, b in _BOX_EDGES:
        colour = (0, 215, 255) if a >= 4 and b >= 4 else (40, 40, 230)  # roof amber, the rest red (BGR)
        p0, p1 = (int(round(v)) for v in px[a]), (int(round(v)) for v in px[b])
        cv2.line(img, tuple(p0), tuple(p1), colour, thick, cv2.LINE_AA)
    return img
