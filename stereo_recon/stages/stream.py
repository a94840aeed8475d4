"""Stage ``stream_views``: one pass over the video - decode, rectify, track (VO), pick fusion views, their depth.

Only the fusion views' rectified left images and depth maps are kept, on disk in the work folder,
for the fusion pass after the poses are final (VO's loop closure moves earlier poses); memory stays
flat in video length. Two threads: this one decodes (prefetched), rectifies and tracks; a worker
computes SGBM depth of the fusion views and writes them (OpenCV releases the GIL), at most one view
in flight. Far scenes (``far_scene``) switch motion stereo and dense-depth VO on after the first view.
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from stereo_recon.disparity import depth_from_disparity, disparity_map
from stereo_recon.core.errors import StageError
from stereo_recon.motion_stereo import MotionStereoConfig, partner_ok
from stereo_recon.reconstruct_config import ReconstructConfig
from stereo_recon.rectifier import Rectifier
from stereo_recon.stages.state import RunContext, Setup, Streamed
from stereo_recon.threads import prefetch
from stereo_recon.views import ViewSelector

log = logging.getLogger(__name__)



@dataclass(frozen=True)
class FarScene:
    """The far-scene decision on the first view: its median disparity (px), its median depth in rig
    baselines, and whether that depth is beyond the threshold."""

    disparity_px: float
    depth_baselines: float
    far: bool


def far_scene(median_depth_m: float, focal_px: float, baseline_m: float, threshold_baselines: float) -> FarScene | None:
    """Is the scene far for this rig? median_depth_m: the first view's median depth (m); focal_px (px),
    baseline_m (m): the rectified rig; threshold_baselines: ``far_scene_depth_baselines``. None when the
    depth is unknown."""
    if not np.isfinite(median_depth_m):
        return None
    disp_px = focal_px * baseline_m / median_depth_m
    z_b = median_depth_m / baseline_m
    return FarScene(disp_px, z_b, bool(z_b > threshold_baselines))


def view_selector(config: ReconstructConfig, mode: str) -> tuple[ViewSelector | None, bool]:
    """The fusion views' selector and whether it selects by pose (vo and gt back-ends: poses known while
    streaming), else by image motion; (None, False) = every processed frame is a view."""
    c = config
    by_pose = c.fuse_by_pose and c.keyframes is not None and mode in ("vo", "gt")
    if by_pose:
        return ViewSelector(None, c.fuse_rotation_deg, c.fuse_translation_rel), True
    return (ViewSelector(c.keyframes) if c.keyframes is not None else None), False


def _make_vo(setup: Setup):
    """Stereo VO on the rectified rig of ``setup`` (K px, baseline m); StageError when this build lacks it."""
    try:
        from stereo_recon.odometry import StereoVO
    except ImportError as err:
        raise StageError("poses", f"visual odometry is not available in this build ({err}); use --poses sfm or gt:PATH") from err
    return StereoVO(setup.K, setup.baseline_m, fps=setup.source.fps)


class _StreamPass:
    """The streaming pass's running state (one instance per run; see ``stream_views``)."""

    def __init__(self, setup: Setup, config: ReconstructConfig, ctx: RunContext):
        self.s, self.c, self.ctx = setup, config, ctx
        self.rectifier = Rectifier(setup.rig, config.gpu)
        self.vo = _make_vo(setup) if setup.mode == "vo" else None
        self.gt_by_index = ({int(i): T for i, T in zip(setup.gt.indices, setup.gt.T_wc)}
                            if setup.mode == "gt" else {})
        self.selector, self.by_pose = view_selector(config, setup.mode)
        self.dense_vo = self.vo is not None and config.vo_dense_depth
        self.keyframes: list[int] = []
        self.view_depths_m: list[float] = []
        self.depth_by_view: dict[int, float] = {}  # median depth (m) of each fusion view, filled by the worker
        self.motion = config.motion_stereo if self.by_pose else None
        self.partners: dict[int, int] = {}  # fusion view -> the frame it is matched with (motion stereo)
        self.waiting: dict[int, np.ndarray] = {}  # fusion views still looking for a partner -> their pose
        self.valid_sum = 0.0
        self.pending = None
        self.n_expected = len(setup.source)
        for sub in ("images", "depth", "partner", "right"):
            (ctx.work / sub).mkdir(parents=True, exist_ok=sub != "images")

    def depth_of(self, left_g, right_g):
        """SGBM depth (m) of a rectified grey pair, NaN outside [depth_min_m, depth_max_m]."""
        s, c = self.s, self.c
        with self.ctx.clock.stage("disparity"):
            disp = disparity_map(left_g, right_g, s.disparity)
            d = depth_from_disparity(disp, s.focal_px, s.baseline_m, c.depth_min_m, s.depth_max_m)
        self.ctx.counts["frames_depth"] += 1
        self.valid_sum += float(np.isfinite(d).mean())
        return d

    def store_view(self, index, left_r, left_g, right_g, depth, keep_right: bool = False):
        """Depth (when not computed yet) of a fusion view, written to the work folder (with the right eye's grey
        image when ``keep_right``); its median depth."""
        import cv2

        if depth is None:
            depth = self.depth_of(left_g, right_g)
        ok = np.isfinite(depth)
        work = self.ctx.work
        with self.ctx.clock.stage("write_keyframes"):
            name = f"{index:06d}"
            cv2.imwrite(str(work / "images" / f"{name}.png"), left_r, [cv2.IMWRITE_PNG_COMPRESSION, 1])
            np.save(work / "depth" / f"{name}.npy", depth.astype(np.float32))
            if keep_right:
                cv2.imwrite(str(work / "right" / f"{name}.png"), right_g, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        med = float(np.median(depth[ok])) if ok.any() else float("nan")
        self.depth_by_view[index] = med
        return med

    def find_partners(self, index, T_now, left_g) -> None:
        """This frame becomes the motion-stereo partner of the waiting views it is far enough from."""
        import cv2

        for kf in list(self.waiting):
            if index - kf > self.motion.max_partner_gap_frames:
                del self.waiting[kf]
                continue
            # The median depth of the view before (the first view: its own), known whatever the worker's speed.
            pos = self.keyframes.index(kf)
            depth_m = self.depth_by_view.get(self.keyframes[pos - 1] if pos > 0 else kf, float("nan"))
            if T_now is not None and partner_ok(self.waiting[kf], T_now, depth_m, self.motion):
                with self.ctx.clock.stage("write_keyframes"):
                    cv2.imwrite(str(self.ctx.work / "partner" / f"{kf:06d}.png"), left_g,
                                [cv2.IMWRITE_PNG_COMPRESSION, 1])
                self.partners[kf] = index
                del self.waiting[kf]

    def collect(self, fut) -> None:
        """The finished depth worker's median view depth (re-raises the worker's error here)."""
        med = fut.result()
        if np.isfinite(med):
            self.view_depths_m.append(med)

    def switch_far_scene(self) -> None:
        """Far scene: motion stereo and dense-depth VO from here on (decided on the first view's depth).

        The first view's disparity is recorded whether or not far scenes are switched on: the depth term of
        the uncertainty (``stereo_recon.app.uncertainty``) reads the working distance from it."""
        med = self.depth_by_view.get(self.keyframes[0], float("nan"))
        threshold = self.c.far_scene_depth_baselines
        decision = far_scene(med, self.s.focal_px, self.s.baseline_m, float("inf") if threshold is None else threshold)
        if decision is None:
            return
        counts = self.ctx.counts
        counts["first_view_disparity_px"] = decision.disparity_px
        counts["first_view_depth_baselines"] = decision.depth_baselines
        counts["far_scene"] = decision.far
        if decision.far:
            log.info("far scene (median depth %.1f baselines, %.1f px of disparity): motion stereo and dense-depth VO",
                     decision.depth_baselines, decision.disparity_px)
            self.dense_vo = self.vo is not None
            if self.by_pose and self.motion is None:
                self.motion = MotionStereoConfig()

    def pose_of(self, frame, left_g, right_g, depth):
        """The frame's pose (rectified left camera, world-from-camera) while streaming: VO's or the known one."""
        if self.vo is not None:
            with self.ctx.clock.stage("poses"):
                # Without dense depth, VO lifts its keyframe corners by sparse stereo matching.
                return self.vo.track(frame.index, left_g, depth, timestamp_s=frame.timestamp_s, right_rect_gray=right_g)
        if self.s.mode == "gt":
            return self.gt_by_index.get(frame.index)
        return None

    def is_view(self, index: int, left_g, T_now) -> bool:
        """Is this frame a fusion view? (taken by the selector when it is)"""
        sel = self.selector
        if sel is None:
            is_key = True
        else:
            if self.by_pose and len(self.keyframes) >= 2:
                sel.set_depth(self.depth_by_view[self.keyframes[-2]])
            is_key = sel.is_view(T_now, index, left_g)
            if is_key:
                sel.set_view(T_now, index, left_g)
        if self.s.mode == "gt" and index not in self.gt_by_index:
            is_key = False
        return is_key

    def on_frame(self, frame, pool) -> None:
        """One decoded frame: rectify, track, and hand it to the depth worker when it is a fusion view."""
        import cv2

        ctx, counts = self.ctx, self.ctx.counts
        counts["frames_read"] += 1
        if counts["frames_read"] == 2 and self.pending is not None and self.by_pose:
            # Every decision below must not depend on how fast the depth worker is (same input, same
            # views and result): the first view's depth is waited for once, here (far-scene check,
            # partners); the view selector uses the depth of the view before the latest, which is always
            # collected by then - none before the second view, so the frame after the first view is
            # always fused too (what usually happened when the selector took whatever depth was ready).
            with ctx.clock.stage("wait_depth"):
                self.collect(self.pending)
            self.pending = None
            if self.s.mode in ("vo", "gt"):
                self.switch_far_scene()
        with ctx.clock.stage("rectify"):
            # Colour is only needed for the left eye (fusion); the right eye is matched in grey.
            left_r, right_g = self.rectifier(frame.left, cv2.cvtColor(frame.right, cv2.COLOR_BGR2GRAY))
            left_g = cv2.cvtColor(left_r, cv2.COLOR_BGR2GRAY)
        depth = self.depth_of(left_g, right_g) if self.dense_vo else None
        T_now = self.pose_of(frame, left_g, right_g, depth)
        if self.pending is not None and self.pending.done():
            self.collect(self.pending)
            self.pending = None
        if self.waiting and self.motion is not None:
            self.find_partners(frame.index, T_now, left_g)
        if self.is_view(frame.index, left_g, T_now):
            if self.pending is not None:
                with ctx.clock.stage("wait_depth"):
                    self.collect(self.pending)
            # Motion stereo re-matches a few views' rig pairs with 8 paths for the trajectory's scale
            # (``stages.motion``): their right eyes are kept (not the first view's, stored before the far-scene
            # switch: a near scene writes nothing more than before).
            keep_right = self.motion is not None
            self.pending = pool.submit(self.store_view, frame.index, left_r, left_g, right_g, depth, keep_right)
            self.keyframes.append(frame.index)
            if self.motion is not None or (self.by_pose and len(self.keyframes) == 1):
                # The first view waits too: the far-scene check may switch motion stereo on.
                self.waiting[frame.index] = np.array(T_now, dtype=np.float64)
        ctx.report("depth", counts["frames_read"], self.n_expected or None)

    def finish(self) -> Streamed:
        """Counts and checks after the last frame; the stage's output."""
        counts, c = self.ctx.counts, self.c
        counts["bad_frames"] = list(self.s.source.bad_frames)
        counts["keyframes"] = len(self.keyframes)
        counts["valid_depth_fraction_mean"] = self.valid_sum / max(counts["frames_depth"], 1)
        if counts["frames_read"] < c.min_frames:
            raise StageError("input", f"{self.s.source.path}: only {counts['frames_read']} decodable frames in the "
                                      f"selected range; at least {c.min_frames} are needed")
        if counts["valid_depth_fraction_mean"] < 0.01:
            log.warning("almost no valid depth (%.1f%% of pixels): check the calibration, --rectified and the depth range",
                        100 * counts["valid_depth_fraction_mean"])
        return Streamed(tuple(self.keyframes), tuple(self.view_depths_m), dict(self.partners), self.motion, self.vo)


def stream_views(setup: Setup, config: ReconstructConfig, ctx: RunContext) -> Streamed:
    """Stream the video once: rectify and track every frame, store the fusion views' images and depth.

    setup: ``open_input``'s output; writes work/images/<index>.png (rectified left BGR),
    work/depth/<index>.npy (float32 m, rectified left camera) and work/partner/<view>.png (motion-stereo
    partner, grey). Raises StageError when fewer than ``config.min_frames`` frames decode.
    """
    state = _StreamPass(setup, config, ctx)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="depth") as pool:
        for frame in prefetch(setup.source, 2):
            state.on_frame(frame, pool)
        if state.pending is not None:
            with ctx.clock.stage("wait_depth"):
                state.collect(state.pending)
    return state.finish()
