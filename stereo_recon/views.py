"""Which frames become views (keyframes): a new view when the camera moved enough since the last one.

One selector, two measures of "moved enough": by pose (turned by ``rotation_deg`` or travelled
``translation_rel`` x the last view's median depth; for back-ends whose poses are known while
streaming) or by image motion (median Lucas-Kanade flow from the last view, ``KeyframeConfig``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereo_recon.trajectory import rotation_angle_deg


@dataclass(frozen=True)
class KeyframeConfig:
    """When to take a new keyframe by image motion (any criterion triggers)."""

    # Median optical-flow magnitude since the last keyframe, as a fraction of the image width.
    min_flow_frac: float = 0.02
    # Always take a keyframe after this many frames (None = never forced).
    max_gap_frames: int | None = 15
    # Tracked corners; fewer surviving than this fraction of the last keyframe's -> new keyframe.
    max_corners: int = 300
    min_tracked_frac: float = 0.5
    # Images are downscaled to this width for flow (speed; the flow is scaled back).
    work_width_px: int = 640


class ViewSelector:
    """Views of a frame stream, spread by pose or by image motion; the first frame is always a view.

    flow: image-motion criterion (``KeyframeConfig``); None = by pose, with rotation_deg (deg, angle
    between orientations) and translation_rel (centre distance relative to the median depth, m, of the
    last view, ``set_depth``). Poses are world-from-camera 4x4, metres; images grey or BGR.
    Per frame: ``is_view(T_wc, index, gray)``, then ``set_view`` with the same arguments when it is taken.
    """

    def __init__(self, flow: KeyframeConfig | None = None, rotation_deg: float = 15.0, translation_rel: float = 0.25):
        self.config = flow
        self.rotation_deg = float(rotation_deg)
        self.translation_rel = float(translation_rel)
        self._T_last: np.ndarray | None = None
        self._depth_last_m = 0.0
        self._key_gray: np.ndarray | None = None
        self._key_pts: np.ndarray | None = None
        self._key_index = -1
        self._small_of: tuple[int, np.ndarray] | None = None  # the last frame's downscaled image, reused by set_view
        self.last_flow_px = 0.0

    def is_view(self, T_wc: np.ndarray | None = None, index: int = -1, gray: np.ndarray | None = None) -> bool:
        """True when this frame (pose T_wc, or frame ``index`` with image ``gray``) moved enough from the last view."""
        if self.config is not None:
            return self._moved_in_image(index, gray)
        if T_wc is None:  # a lost frame (no pose) is never a view
            return False
        if self._T_last is None:
            return True
        rel = np.linalg.inv(self._T_last) @ T_wc
        angle = rotation_angle_deg(rel[:3, :3])
        return bool(angle >= self.rotation_deg
                    or np.linalg.norm(rel[:3, 3]) >= self.translation_rel * self._depth_last_m)

    def set_view(self, T_wc: np.ndarray | None = None, index: int = -1, gray: np.ndarray | None = None) -> None:
        """Record the selected view: its pose (by pose) or its image's corners (by image motion)."""
        if self.config is None:
            self._T_last = np.array(T_wc, dtype=np.float64)
            return
        small = self._small_of[1] if self._small_of is not None and self._small_of[0] == index else self._small(gray)[0]
        self._set_key(index, small)

    def set_depth(self, median_depth_m: float) -> None:
        """Median depth (m) of the last selected view's depth map (may arrive later, from a worker)."""
        if np.isfinite(median_depth_m) and median_depth_m > 0:
            self._depth_last_m = float(median_depth_m)

    def is_keyframe(self, index: int, gray: np.ndarray) -> bool:
        """``is_view`` by image motion, taking the frame as the new view when it is one."""
        if self.is_view(None, index, gray):
            self.set_view(None, index, gray)
            return True
        return False

    def _small(self, gray: np.ndarray) -> tuple[np.ndarray, float]:
        """(grey image downscaled to ``work_width_px``, the scale factor applied)."""
        import cv2

        if gray.ndim == 3:
            gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
        s = min(1.0, self.config.work_width_px / gray.shape[1])
        if s < 1.0:
            gray = cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        return gray, s

    def _set_key(self, index: int, small: np.ndarray) -> None:
        """Make frame ``index`` (its downscaled image) the reference of the flow: its corners to track."""
        import cv2

        self._key_gray = small
        self._key_pts = cv2.goodFeaturesToTrack(small, self.config.max_corners, 0.01, 7)
        self._key_index = index

    def _moved_in_image(self, index: int, gray: np.ndarray) -> bool:
        """Median LK flow (px) from the last view at least ``min_flow_frac`` x width, too few corners tracked, or
        ``max_gap_frames`` since it (the first frame always moved)."""
        import cv2

        small, s = self._small(gray)
        self._small_of = (index, small)
        c = self.config
        if self._key_gray is None or self._key_pts is None or len(self._key_pts) < 8:
            return True
        if c.max_gap_frames is not None and index - self._key_index >= c.max_gap_frames:
            return True
        pts, st, _ = cv2.calcOpticalFlowPyrLK(self._key_gray, small, self._key_pts, None)
        ok = st.reshape(-1) == 1
        if ok.sum() < c.min_tracked_frac * len(self._key_pts):
            return True
        flow = np.linalg.norm((pts - self._key_pts).reshape(-1, 2)[ok], axis=1)
        self.last_flow_px = float(np.median(flow)) / s
        return bool(self.last_flow_px >= c.min_flow_frac * gray.shape[1])


# The two selectors this one replaces, by their earlier names: by pose, and by image motion (flow config first).
PoseViewSelector = ViewSelector
KeyframeSelector = ViewSelector
