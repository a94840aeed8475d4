"""The one side-by-side frame reader: a ZED frame holds the left eye in its left half (core.conventions)."""

from __future__ import annotations

import numpy as np

from stereo_recon.core.errors import InputError

# Width/height of one eye of a side-by-side frame: ZED modes are 16:9 (1.78); a frame whose halves fall
# outside this range is not side-by-side (a mono video, a top-bottom pair).
EYE_ASPECT_RANGE = (1.0, 2.5)


def split_side_by_side(frame: np.ndarray, source: str = "frame", check_aspect: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Split a side-by-side image (H, 2W[, C]) into (left, right) eye images (views, not copies).

    source: the file or frame named in errors. check_aspect: refuse halves whose width/height lies outside
    EYE_ASPECT_RANGE (off for calibration images of any shape). Raises InputError for an empty image,
    an odd width, or (check_aspect) halves of the wrong shape.
    """
    if frame is None or frame.ndim < 2:
        raise InputError(f"{source}: empty image")
    h, w = frame.shape[:2]
    if w % 2:
        raise InputError(f"{source}: frame width {w} is odd, so it is not a side-by-side stereo frame")
    eye_aspect = (w // 2) / h
    if check_aspect and not EYE_ASPECT_RANGE[0] <= eye_aspect <= EYE_ASPECT_RANGE[1]:
        raise InputError(f"{source}: {w}x{h} frame is not side-by-side (each half would be {w // 2}x{h}, "
                         f"aspect {eye_aspect:.2f}; expected e.g. 2560x720 for ZED HD720)")
    return frame[:, : w // 2], frame[:, w // 2:]
