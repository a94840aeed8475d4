"""Awkward variants of the bundled sample video (swapped or identical eyes, a static camera, an
SDK-style rectified export, a cut file), written as small MJPG AVIs for the bad-input tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SAMPLE_VIDEO = REPO / "sample_data" / "video.avi"
SAMPLE_CONF = REPO / "sample_data" / "SN28000001.conf"


def read_pairs(n: int | None = None, step: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """(left, right) BGR frames of the sample video: every ``step``-th, at most ``n``."""
    import cv2

    cap = cv2.VideoCapture(str(SAMPLE_VIDEO))
    pairs, i = [], 0
    while n is None or len(pairs) < n:
        ok, frame = cap.read()
        if not ok:
            break
        if i % step == 0:
            w = frame.shape[1] // 2
            pairs.append((frame[:, :w].copy(), frame[:, w:].copy()))
        i += 1
    cap.release()
    return pairs


def write_video(path: Path, pairs, fps: float = 15.0) -> Path:
    """Side-by-side MJPG AVI of (left, right) pairs."""
    import cv2

    h, w = pairs[0][0].shape[:2]
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (2 * w, h))
    for left, right in pairs:
        out.write(np.hstack([left, right]))
    out.release()
    return path


def rectified_pairs(pairs):
    """The pairs rectified with the sample's calibration (what the ZED SDK's SVO export gives), and the
    rectified camera's ``fx,fy,cx,cy,baseline_m``."""
    from calib.io import load_rig
    from calib.rig import rectify_pair

    rig = load_rig(SAMPLE_CONF, image_size=(pairs[0][0].shape[1], pairs[0][0].shape[0]))
    rect = rig.rectification(alpha=0.0)
    out = []
    for left, right in pairs:
        out.append(rectify_pair(left, right, rect))
    K = rect.K_rect
    return out, f"{K[0, 0]:.4f},{K[1, 1]:.4f},{K[0, 2]:.4f},{K[1, 2]:.4f},{rect.baseline_m:.6f}"
