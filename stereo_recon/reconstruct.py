"""The reconstruction pipeline: side-by-side video -> rectified depth -> metric poses -> TSDF cloud.

Stages (one module each): ``video`` (frames) -> ``calib.rig`` (rectification) -> ``disparity``
(SGBM depth) -> poses (``odometry.StereoVO``, ``sfm.sfm_poses``, or a known trajectory) ->
``fusion`` (TSDF) -> outputs; far scenes (a full-scale truck) add a bundle adjustment of VO's fused
views by ``sfm`` (grafted onto VO's trajectory) and ``motion_stereo`` (wide-baseline depth from pairs
of frames) before fusion. The video is read once, streaming; only keyframes' rectified left
images and depth maps are kept, on disk in a work folder, for the fusion pass after the poses
are final (VO's loop closure moves earlier poses). Memory therefore stays flat in video length.

Speed (the VO path): VO tracks every frame on sparse stereo (corners matched in the right image
at its own keyframes), so SGBM runs only on the fusion views, which are chosen by pose (a new one
per ``fuse_rotation_deg`` of turn or ``fuse_translation_rel`` x scene depth of travel) and
computed in a worker thread while tracking goes on (decoding is prefetched in another). Fusion
integrates every n-th pixel (``fusion_min_width_px``), up to ``fusion_depth_max_rel`` x the views'
median depth, into a hash map sized once for all views. On the 120-frame HD720 model-truck orbit
(2 cores, ``benchmarks/bench_depth.py --reconstruct DIR --compare-legacy``): 8.6 processed
frames/s and 23 CPU-s instead of 2.2 frames/s and 86 CPU-s with SGBM on every frame, at the same
ATE (0.034 vs 0.045 % of the path), truck accuracy (0.17 vs 0.22 % of L) and coverage (98.8 vs 99.5 %).

Output folder (written through ``staged_output_dir``: complete or untouched):
    cloud.ply   fused coloured point cloud, world frame, metres
    poses.txt   TUM, world-from-left-camera (the physical, unrectified left eye), timestamp = index / fps
    run.json    inputs (sha256), rig, every parameter, versions, timings, counts, "up", tracking gaps
    mesh.ply    (with ``mesh=True``) marching-cubes surface
"""

from __future__ import annotations

import functools
import logging
import queue
import shutil
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from stereo_recon.disparity import DisparityConfig, depth_from_disparity, disparity_map, disparity_range_for_depth, preset
from stereo_recon.core.errors import ConfigError, StageError
from stereo_recon.core.cloud_io import write_cloud as write_cloud_ply
from stereo_recon.fusion import FusionConfig, TSDFFusion, consistent_depth_mask, estimate_block_count, voxel_size_from_depth
from stereo_recon.motion_stereo import MotionStereoConfig, motion_depth, partner_ok, rectify_motion_pair
from stereo_recon.core.atomic import staged_output_dir, write_json_atomic
from stereo_recon.core.manifest import Stopwatch, run_manifest
from stereo_recon.trajectory import rotation_angle_deg
from stereo_recon.video import KeyframeConfig, KeyframeSelector, open_stereo_source, validate_against_rig

log = logging.getLogger(__name__)

ProgressFn = Callable[[str, int, "int | None"], None]


@dataclass(frozen=True)
class ReconstructConfig:
    """Every parameter of ``reconstruct`` (the CLI maps its options onto these fields)."""

    # Pose back-end: "vo" (stereo visual odometry), "sfm" (pycolmap), or "gt:PATH" (known TUM trajectory).
    poses: str = "vo"
    # Half-open frame range (start, stop) of the source; None = all. step: every step-th frame.
    frame_range: tuple[int, int | None] | None = None
    step: int = 1
    # Override the video's frame rate (timestamps = index / fps).
    fps: float | None = None
    # Frames are already rectified (ZED SDK exports are): skip rectification. None = as the rig says.
    rectified: bool | None = None
    # Depth range (m): sets the SGBM disparity range and what is fused. depth_max_m None = derived from
    # the rig: the depth of ``min_disparity_px`` of disparity (f*B/1 px: 63 m for a ZED2 at HD720). Why not a
    # fixed 20 m: a full-scale truck flown at 2 x its length is 25-40 m away; a fixed cap left nothing of it
    # (a random envelope draw at 21 m radius fused 126 points). The fused region is bounded by
    # fusion_depth_max_rel instead, which follows the scene.
    depth_min_m: float = 0.3
    depth_max_m: float | None = None
    min_disparity_px: float = 1.0
    # Disparity preset ("fast", "balanced", "quality", "wls") and field overrides (disparity range is derived).
    disparity_preset: str = "balanced"
    disparity_overrides: dict = field(default_factory=dict)
    # Upper bound of the SGBM disparity search (px); the near depth limit is raised to fit.
    max_num_disparities: int = 256
    # Gaps wider than this (px) stay holes: background filling is right for occlusions, not for wide untextured areas.
    fill_max_px: int | None = 32
    # Keyframes (fused, and the images given to SfM) by image motion, for sfm (vo and gt: by pose, below);
    # None = every processed frame is fused, whatever the back-end.
    # 6 % of the width between keyframes: on the 120-frame synthetic HD720 orbit, 23 keyframes gave the
    # same truck accuracy (0.27 % of L) and coverage (99.5 %) as 43 at 3 %, with 30 % less fusion time.
    keyframes: KeyframeConfig | None = KeyframeConfig(min_flow_frac=0.06, max_gap_frames=20)
    # Fusion views by pose (vo and gt back-ends, whose poses are known while streaming; sfm uses
    # ``keyframes``): a frame is fused when the camera turned by fuse_rotation_deg, or moved by
    # fuse_translation_rel x the median depth of the last fused view, since the last fused view.
    # SGBM runs on these frames only; VO matches its corners sparsely in the right image instead.
    # An orbit needs 16-24 views for full coverage; 18 deg gives 20 on a full circle. fuse_by_pose False:
    # image-motion keyframes (``keyframes``) for every back-end.
    fuse_by_pose: bool = True
    fuse_rotation_deg: float = 18.0
    fuse_translation_rel: float = 0.4
    # Feed VO with dense SGBM depth of every frame (the slow path: SGBM on every frame) instead of
    # sparse stereo at its keyframes.
    vo_dense_depth: bool = False
    # Integrate every n-th pixel of depth and colour (K scaled accordingly), n the largest integer
    # keeping at least this width (HD720: n = 2; VGA: 1); None = full resolution. The voxel (2 px
    # footprints at full resolution) stays the same.
    fusion_min_width_px: int | None = 640
    # Fused depth is cut at this multiple of the median depth of the fused views (the region of
    # interest around the object; far ground costs blocks and adds Z^2 noise); None = depth_max_m only.
    fusion_depth_max_rel: float | None = 2.0
    # Geometric consistency before fusion (as MVS fusion does): a depth pixel is fused only when at
    # least ``consistency_min_views`` of the ``consistency_views`` nearest fused views (by camera
    # position) see the same point within ``consistency_rel_tol`` x depth. None = fuse every pixel
    # (the default: on the sample truck it brings the side walls' median to within 1 mm of the truth
    # but keeps only 10-50 % of their points, so the cab, not the box, then sets the width).
    consistency_views: int | None = None
    consistency_min_views: int = 1
    consistency_rel_tol: float = 0.01
    # Motion stereo (``motion_stereo``): each fusion view is also matched with a later frame about
    # 0.11 x the scene depth away, that wide-baseline depth is fused instead of the rig's, and VO's
    # trajectory is rescaled to the rig's depth. Needs poses while streaming (vo and gt back-ends).
    # None = only for far scenes (below). Forced on for the 20 model trucks (``bench --motion-stereo``)
    # their widths got worse (2.42 % mean error instead of 1.35 %: the narrow walls come out 1-2 mm
    # inside), heights better (0.17 % instead of 0.48 %).
    motion_stereo: MotionStereoConfig | None = None
    # Far scenes: when the first frame's median disparity is below this (px; the rig then resolves
    # its depth to worse than 1/16 per pixel - a full-scale truck from 8-15 m with the ZED2 gives 5-8 px,
    # a model truck from 1.5-2 m 30-45 px) the run uses motion stereo (the default config unless
    # motion_stereo is set) and feeds VO the dense depth of every frame (sparse stereo on 5-8 px of
    # disparity left VO's scale 0.28 % short, dense 0.18 %). vo and gt back-ends; None = never.
    # Measured (``stereo-recon bench``, the two rendered full-scale presets, VO): width -0.97 % / -3.04 %,
    # length and height within 0.14 %, instead of +2.85 % / -3.56 % and 0.5-0.8 % with the rig's depth.
    far_scene_disparity_px: float | None = 16.0
    # Bundle-adjusted poses for the fused views (vo back-end): pycolmap SfM on the fused views and
    # their motion-stereo partners, grafted onto VO's trajectory by a similarity (``graft_poses``).
    # Why: at full scale VO's rotations wander by 0.43 deg rms (over-height preset) in step with
    # its sideways position, which puts points 10 m away several cm off and skews the wide pairs;
    # grafted, the trajectory is within 0.065 deg rms (ATE 60 -> 12 mm; width -3.03 -> -1.03 %
    # before the finer voxel), for ~25 s of SfM (one thread) on 35 HD720 images. None = with motion stereo (far
    # scenes) only; if SfM fails, VO's poses are kept (logged, counts["sfm_refine"]).
    refine_poses_sfm: bool | None = None
    # TSDF settings; voxel_m None = derived from the first keyframe's depth.
    fusion: FusionConfig = FusionConfig()
    voxel_m: float | None = None
    # Also write mesh.ply.
    mesh: bool = False
    # Rectification and back-projection on a CUDA device through torch/kornia (stereo_recon.gpu).
    gpu: bool = False
    # Fewer processed frames (or posed frames) than this is an error.
    min_frames: int = 3
    # Keep the work folder (keyframe images and depth maps, SfM database) in the output as work/.
    keep_work: bool = False
    # Undecodable frames in a row that end the video.
    max_consecutive_bad: int = 10

    def __post_init__(self) -> None:
        if not (self.poses in ("vo", "sfm") or self.poses.startswith("gt:")):
            raise ConfigError(f"--poses {self.poses!r}: expected vo, sfm or gt:PATH (a TUM trajectory)")
        if not 0 < self.depth_min_m or (self.depth_max_m is not None and not self.depth_min_m < self.depth_max_m):
            raise ConfigError(f"depth range [{self.depth_min_m}, {self.depth_max_m}] m: need 0 < min < max")
        if not self.min_disparity_px > 0:
            raise ConfigError(f"min_disparity_px={self.min_disparity_px}: must be > 0")
        if self.step < 1:
            raise ConfigError(f"--step {self.step}: must be >= 1")
        if self.voxel_m is not None and not self.voxel_m > 0:
            raise ConfigError(f"--voxel-m {self.voxel_m}: must be > 0")
        if not (self.fuse_rotation_deg > 0 and self.fuse_translation_rel > 0):
            raise ConfigError("fuse_rotation_deg and fuse_translation_rel must be > 0")
        if self.fusion_min_width_px is not None and self.fusion_min_width_px < 16:
            raise ConfigError(f"fusion_min_width_px={self.fusion_min_width_px}: must be >= 16 or None")
        if self.fusion_depth_max_rel is not None and not self.fusion_depth_max_rel > 1.0:
            raise ConfigError(f"fusion_depth_max_rel={self.fusion_depth_max_rel}: must be > 1 or None")
        if self.refine_poses_sfm and self.poses != "vo":
            raise ConfigError(f"--refine-poses on: bundle adjustment refines visual odometry's poses (--poses vo), "
                              f"not --poses {self.poses}")
        if self.motion_stereo is not None and (self.poses == "sfm" or not self.fuse_by_pose or self.keyframes is None):
            raise ConfigError("motion stereo needs poses while streaming and views chosen by pose: --poses vo or "
                              "gt:PATH, without --all-frames")
        if self.consistency_views is not None and not (
                self.consistency_views >= 1 and 1 <= self.consistency_min_views <= self.consistency_views
                and self.consistency_rel_tol > 0):
            raise ConfigError(f"consistency: need views >= 1, 1 <= min_views <= views, rel_tol > 0 (got "
                              f"{self.consistency_views}, {self.consistency_min_views}, {self.consistency_rel_tol})")


def _rig_summary(rig, rect) -> dict:
    return {"K1": rig.K1, "D1": rig.D1, "K2": rig.K2, "D2": rig.D2, "R": rig.R, "T": rig.T,
            "image_size": list(rig.image_size), "rectified_input": bool(rig.rectified), "baseline_m": rig.baseline_m,
            "metadata": dict(rig.metadata),
            "rectified": {"K_rect": rect.K_rect, "focal_px": rect.focal_px, "baseline_m": rect.baseline_m,
                          "roi_left": list(rect.roi_left)}}


def _refine_with_sfm(traj, keyframes: list[int], partners: dict[int, int], work: Path, K: np.ndarray, baseline_m: float,
                     fps: float | None, counts: dict):
    """VO's trajectory with the fused views' and partners' poses replaced by pycolmap SfM's (same world, scale)."""
    import os

    from stereo_recon.sfm import SfMConfig, sfm_poses
    from stereo_recon.trajectory import graft_poses

    folder = work / "sfm_images"
    folder.mkdir()
    sources = {idx: work / "images" / f"{idx:06d}.png" for idx in keyframes}
    for view, j in partners.items():  # partner images are stored under their view's index
        sources.setdefault(j, work / "partner" / f"{view:06d}.png")
    names = []
    for idx in sorted(sources):
        if sources[idx].is_file():
            os.link(sources[idx], folder / f"{idx:06d}.png")
            names.append(f"{idx:06d}.png")
    if len(names) < 3:
        counts["sfm_refine"] = "skipped: fewer than 3 images"
        return traj
    try:
        refined = sfm_poses(folder, K, work / "sfm", baseline_m=baseline_m, depth_dir=work / "depth",
                            config=SfMConfig(), fps=fps, image_names=names)
        out, stats = graft_poses(traj, refined)
    except (StageError, ValueError) as err:
        log.warning("pose refinement by SfM failed (%s); keeping visual odometry's poses", err)
        counts["sfm_refine"] = f"failed: {err}"
        return traj
    counts["sfm_refine"] = {"images": len(names), "registered": int(refined.stats.get("registered", len(refined))),
                            **stats}
    log.info("poses: %d of %d frames bundle-adjusted by SfM (median change %.1f mm, %.3f deg)",
             stats["grafted_frames"], len(names), 1000 * stats["moved_m_median"], stats["turned_deg_median"])
    return out


def _rot4(R: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform of a rotation."""
    T = np.eye(4)
    T[:3, :3] = R
    return T


class PoseViewSelector:
    """Fusion views spread by pose: a new view when the camera turned or moved enough since the last one.

    rotation_deg: angle between the orientations (deg). translation_rel: centre distance relative to
    the median depth (m) of the last selected view. Poses are world-from-camera 4x4, metres.
    """

    def __init__(self, rotation_deg: float = 15.0, translation_rel: float = 0.25):
        self.rotation_deg = float(rotation_deg)
        self.translation_rel = float(translation_rel)
        self._T_last: np.ndarray | None = None
        self._depth_last_m = 0.0

    def is_view(self, T_wc: np.ndarray | None) -> bool:
        """True when this pose is far enough from the last selected view (the first pose always is)."""
        if T_wc is None:
            return False
        if self._T_last is None:
            return True
        rel = np.linalg.inv(self._T_last) @ T_wc
        angle = rotation_angle_deg(rel[:3, :3])
        return bool(angle >= self.rotation_deg
                    or np.linalg.norm(rel[:3, 3]) >= self.translation_rel * self._depth_last_m)

    def set_view(self, T_wc: np.ndarray) -> None:
        """Record the pose of the selected view."""
        self._T_last = np.array(T_wc, dtype=np.float64)

    def set_depth(self, median_depth_m: float) -> None:
        """Median depth (m) of the last selected view's depth map (may arrive later, from a worker)."""
        if np.isfinite(median_depth_m) and median_depth_m > 0:
            self._depth_last_m = float(median_depth_m)


def _prefetch(iterable, depth: int = 2):
    """Iterate in a background thread, at most ``depth`` items ahead (video decoding overlaps the work)."""
    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def run():
        try:
            for item in iterable:
                if stop.is_set():
                    return
                q.put((item, None))
            q.put((done, None))
        except BaseException as err:  # handed to the consumer, raised there
            q.put((done, err))

    t = threading.Thread(target=run, name="decode", daemon=True)
    t.start()
    try:
        while True:
            item, err = q.get()
            if err is not None:
                raise err
            if item is done:
                return
            yield item
    finally:
        stop.set()
        while t.is_alive():  # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                t.join(0.05)


def subsample_for_fusion(color: np.ndarray, depth_m: np.ndarray, K: np.ndarray, n: int):
    """Every n-th pixel of colour and depth, and the matching intrinsics.

    Pixel u' of the result is pixel n*u' of the input, so K' = diag(1/n, 1/n, 1) K exactly (no
    half-pixel shift) and no depth is mixed across depth edges. color (H,W,3), depth_m (H,W), K (3,3) px.
    """
    if n <= 1:
        return color, depth_m, K
    S = np.diag([1.0 / n, 1.0 / n, 1.0])
    return (np.ascontiguousarray(color[::n, ::n]), np.ascontiguousarray(depth_m[::n, ::n]),
            S @ np.asarray(K, dtype=np.float64))


class _Rectifier:
    """Rectify a raw pair (left BGR, right grey): CPU cv2.remap with fixed-point maps, or the GPU path."""

    def __init__(self, rig, use_gpu: bool):
        self.gpu = None
        if use_gpu and not rig.rectified:
            from stereo_recon import gpu

            self.gpu = gpu.GpuRectifier(rig.rectification(alpha=0.0))  # float maps: exact positions
        # 16SC2 maps: OpenCV's fixed-point remap, ~1/32 px position steps, faster than float maps.
        self.rect = rig.rectification(alpha=0.0, map_type="16SC2")

    def __call__(self, left_bgr, right_gray):
        if self.gpu is not None:
            return self.gpu.rectify_pair(left_bgr, right_gray)
        from calib.rig import rectify_pair

        return rectify_pair(left_bgr, right_gray, self.rect)


def resolved_depth_max_m(config: ReconstructConfig, focal_px: float, baseline_m: float) -> float:
    """Farthest depth matched and fused (m): ``config.depth_max_m``, or the depth of ``config.min_disparity_px``
    of disparity for this rig (focal_px, px; baseline_m, m) when it is None."""
    if config.depth_max_m is not None:
        return float(config.depth_max_m)
    return float(max(focal_px * baseline_m / config.min_disparity_px, 1.01 * config.depth_min_m))


def reconstruct(source_path, rig, out_dir, config: ReconstructConfig = ReconstructConfig(),
                calib_path=None, progress: ProgressFn | None = None) -> dict:
    """Reconstruct a coloured point cloud and camera trajectory from a stereo video.

    source_path: side-by-side video or image folder (``video.open_stereo_source``).
    rig: ``calib.rig.StereoRig`` (scaled to the frames when the aspect matches).
    out_dir: output folder (cloud.ply, poses.txt, run.json[, mesh.ply]); written atomically.
    calib_path: the calibration file, recorded with its sha256 in run.json.
    progress: optional callback (stage, done, total or None) for a terminal display.
    Returns the run.json dict. Raises InputError / StageError with one-line messages.
    """
    import cv2

    from calib.rig import StereoRig

    c = config
    sw = Stopwatch()
    report = progress or (lambda stage, done, total: None)
    t_start = time.perf_counter()

    with sw.stage("open"):
        source = open_stereo_source(source_path, c.frame_range, c.step, c.fps, c.max_consecutive_bad)
        rig = validate_against_rig(source, rig)
        if c.rectified and not rig.rectified:
            # Already-rectified frames: the rectified pinhole is approximated by the left eye's intrinsics.
            log.warning("frames marked rectified: using the left intrinsics and baseline of %s as the rectified camera",
                        calib_path or "the rig")
            rig = StereoRig.from_rectified(rig.K1[0, 0], rig.K1[1, 1], rig.K1[0, 2], rig.K1[1, 2], rig.baseline_m,
                                           rig.image_size, source="rectified flag", **{"from": dict(rig.metadata)})
        rect = rig.rectification(alpha=0.0)
        K = rect.K_rect
        f_px, B = rect.focal_px, rect.baseline_m
    n_expected = len(source)
    if n_expected and n_expected < c.min_frames:
        raise StageError("input", f"{source.path}: only {n_expected} frames selected (range/step); "
                                  f"at least {c.min_frames} are needed")

    depth_max_m = resolved_depth_max_m(c, f_px, B)
    d_min, d_num = disparity_range_for_depth(f_px, B, c.depth_min_m, depth_max_m, c.max_num_disparities)
    dcfg: DisparityConfig = preset(c.disparity_preset, min_disparity_px=d_min, num_disparities_px=d_num,
                                   fill_max_px=c.fill_max_px, **c.disparity_overrides)
    fcfg = replace(c.fusion, depth_min_m=max(c.fusion.depth_min_m, c.depth_min_m),
                   depth_max_m=min(c.fusion.depth_max_m, depth_max_m),
                   voxel_m=c.voxel_m if c.voxel_m is not None else c.fusion.voxel_m)
    log.info("rectified f=%.1f px, B=%.4f m; disparities %d..%d px for %.2f-%.1f m", f_px, B, d_min, d_min + d_num,
             c.depth_min_m, depth_max_m)

    mode = "gt" if c.poses.startswith("gt:") else c.poses
    gt_traj = None
    if mode == "gt":
        from stereo_recon.trajectory import read_tum

        gt_traj = read_tum(Path(c.poses[3:]), fps=source.fps)
        # The file describes the physical left camera; depth lives in the rectified left camera (X_rect = R1 X_raw).
        gt_traj.T_wc = gt_traj.T_wc @ _rot4(rect.R1.T)
        gt_by_index = {int(i): T for i, T in zip(gt_traj.indices, gt_traj.T_wc)}

    rectifier = _Rectifier(rig, c.gpu)
    counts = {"frames_read": 0, "frames_depth": 0, "keyframes": 0, "valid_depth_fraction_mean": 0.0}
    vo = None
    if mode == "vo":
        try:
            from stereo_recon.odometry import StereoVO
        except ImportError as err:
            raise StageError("poses", f"visual odometry is not available in this build ({err}); use --poses sfm or gt:PATH") from err
        vo = StereoVO(K, B, fps=source.fps)

    with staged_output_dir(out_dir) as stage_dir:
        work = stage_dir / "work"
        (work / "images").mkdir(parents=True)
        (work / "depth").mkdir()
        # Fusion views: by pose where poses are known while streaming (vo, gt), else by image motion.
        by_pose = c.fuse_by_pose and c.keyframes is not None and mode in ("vo", "gt")
        selector = KeyframeSelector(c.keyframes) if c.keyframes is not None and not by_pose else None
        views = PoseViewSelector(c.fuse_rotation_deg, c.fuse_translation_rel) if by_pose else None
        dense_vo = vo is not None and c.vo_dense_depth
        keyframes: list[int] = []
        view_depths_m: list[float] = []
        depth_by_view: dict[int, float] = {}  # median depth (m) of each fusion view, filled by the worker
        motion = c.motion_stereo if views is not None else None
        partners: dict[int, int] = {}  # fusion view -> the frame it is matched with (motion stereo)
        waiting: dict[int, np.ndarray] = {}  # fusion views still looking for a partner -> their pose
        (work / "partner").mkdir()
        valid_sum = 0.0

        def depth_of(left_g, right_g):
            nonlocal valid_sum
            with sw.stage("disparity"):
                disp = disparity_map(left_g, right_g, dcfg)
                d = depth_from_disparity(disp, f_px, B, c.depth_min_m, depth_max_m)
            counts["frames_depth"] += 1
            valid_sum += float(np.isfinite(d).mean())
            return d

        def store_view(index, left_r, left_g, right_g, depth):
            """Depth (when not computed yet) of a fusion view, written to the work folder; its median depth."""
            if depth is None:
                depth = depth_of(left_g, right_g)
            ok = np.isfinite(depth)
            with sw.stage("write_keyframes"):
                name = f"{index:06d}"
                cv2.imwrite(str(work / "images" / f"{name}.png"), left_r, [cv2.IMWRITE_PNG_COMPRESSION, 1])
                np.save(work / "depth" / f"{name}.npy", depth.astype(np.float32))
            med = float(np.median(depth[ok])) if ok.any() else float("nan")
            depth_by_view[index] = med
            return med

        def find_partners(index, T_now, left_g) -> None:
            """This frame becomes the motion-stereo partner of the waiting views it is far enough from."""
            for kf in list(waiting):
                if index - kf > motion.max_partner_gap_frames:
                    del waiting[kf]
                    continue
                # The median depth of the view before (the first view: its own), known whatever the worker's speed.
                pos = keyframes.index(kf)
                depth_m = depth_by_view.get(keyframes[pos - 1] if pos > 0 else kf, float("nan"))
                if T_now is not None and partner_ok(waiting[kf], T_now, depth_m, motion):
                    with sw.stage("write_keyframes"):
                        cv2.imwrite(str(work / "partner" / f"{kf:06d}.png"), left_g, [cv2.IMWRITE_PNG_COMPRESSION, 1])
                    partners[kf] = index
                    del waiting[kf]

        def collect(fut) -> None:
            med = fut.result()  # re-raises the worker's error here
            if np.isfinite(med):
                view_depths_m.append(med)

        def decide_far_scene(med: float) -> None:
            """Far scene: motion stereo and dense-depth VO from here on (first view's median depth, m)."""
            nonlocal dense_vo, motion
            if not np.isfinite(med):
                return
            disp_px = f_px * B / med
            counts["first_view_disparity_px"] = disp_px
            counts["far_scene"] = bool(disp_px < c.far_scene_disparity_px)
            if counts["far_scene"]:
                log.info("far scene (median disparity %.1f px): motion stereo and dense-depth VO", disp_px)
                dense_vo = vo is not None
                if views is not None and motion is None:
                    motion = MotionStereoConfig()

        # ---- pass 1: frames -> rectified -> (VO) ; depth of the fusion views -> disk ---------
        # Two threads: this one decodes (prefetched), rectifies and tracks; a worker computes SGBM depth of
        # the fusion views and writes them (OpenCV releases the GIL), at most one view in flight so memory
        # stays flat.
        pending = None
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="depth") as pool:
            for frame in _prefetch(source, 2):
                counts["frames_read"] += 1
                if counts["frames_read"] == 2 and pending is not None and views is not None:
                    # Every decision below must not depend on how fast the depth worker is (same input, same
                    # views and result): the first view's depth is waited for once, here (far-scene check,
                    # partners); the view selector uses the depth of the view before the latest, which is always
                    # collected by then - none before the second view, so the frame after the first view is
                    # always fused too (what usually happened when the selector took whatever depth was ready).
                    with sw.stage("wait_depth"):
                        collect(pending)
                    pending = None
                    if c.far_scene_disparity_px is not None and mode in ("vo", "gt"):
                        decide_far_scene(depth_by_view.get(keyframes[0], float("nan")))
                with sw.stage("rectify"):
                    # Colour is only needed for the left eye (fusion); the right eye is matched in grey.
                    left_r, right_g = rectifier(frame.left, cv2.cvtColor(frame.right, cv2.COLOR_BGR2GRAY))
                    left_g = cv2.cvtColor(left_r, cv2.COLOR_BGR2GRAY)
                depth = depth_of(left_g, right_g) if dense_vo else None
                T_now = None
                if vo is not None:
                    with sw.stage("poses"):
                        # Without dense depth, VO lifts its keyframe corners by sparse stereo matching.
                        T_now = vo.track(frame.index, left_g, depth, timestamp_s=frame.timestamp_s,
                                         right_rect_gray=right_g)
                elif mode == "gt":
                    T_now = gt_by_index.get(frame.index)
                if pending is not None and pending.done():
                    collect(pending)
                    pending = None
                if waiting and motion is not None:
                    find_partners(frame.index, T_now, left_g)
                if views is not None:
                    if len(keyframes) >= 2:
                        views.set_depth(depth_by_view[keyframes[-2]])
                    is_key = views.is_view(T_now)
                elif selector is not None:
                    is_key = selector.is_keyframe(frame.index, left_g)
                else:
                    is_key = True
                if mode == "gt" and frame.index not in gt_by_index:
                    is_key = False
                if is_key:
                    if views is not None:
                        views.set_view(T_now)
                    if pending is not None:
                        with sw.stage("wait_depth"):
                            collect(pending)
                    pending = pool.submit(store_view, frame.index, left_r, left_g, right_g, depth)
                    keyframes.append(frame.index)
                    if motion is not None or (views is not None and len(keyframes) == 1):
                        # The first view waits too: the far-scene check may switch motion stereo on.
                        waiting[frame.index] = np.array(T_now, dtype=np.float64)
                report("depth", counts["frames_read"], n_expected or None)
            if pending is not None:
                with sw.stage("wait_depth"):
                    collect(pending)
        counts["bad_frames"] = list(source.bad_frames)
        counts["keyframes"] = len(keyframes)
        counts["valid_depth_fraction_mean"] = valid_sum / max(counts["frames_depth"], 1)
        if counts["frames_read"] < c.min_frames:
            raise StageError("input", f"{source.path}: only {counts['frames_read']} decodable frames in the selected "
                                      f"range; at least {c.min_frames} are needed")
        if counts["valid_depth_fraction_mean"] < 0.01:
            log.warning("almost no valid depth (%.1f%% of pixels): check the calibration, --rectified and the depth range",
                        100 * counts["valid_depth_fraction_mean"])

        # ---- poses --------------------------------------------------------------------------
        report("poses", 0, None)
        with sw.stage("poses"):
            if mode == "vo":
                traj = vo.finish()
            elif mode == "sfm":
                from stereo_recon.sfm import sfm_poses

                if len(keyframes) < c.min_frames:
                    raise StageError("poses", f"only {len(keyframes)} keyframes for SfM; at least {c.min_frames} are "
                                              "needed (lower --step or use more frames)")
                report("sfm", 0, None)
                traj = sfm_poses(work / "images", K, work / "sfm", baseline_m=B, depth_dir=work / "depth", fps=source.fps)
            else:
                from stereo_recon.trajectory import Trajectory

                keyset = set(keyframes) | set(partners.values())
                sel = [i for i, idx in enumerate(gt_traj.indices) if int(idx) in keyset]
                traj = gt_traj.subset(np.asarray(sel, dtype=np.int64)) if sel else Trajectory([], [], np.zeros((0, 4, 4)))
        refine = c.refine_poses_sfm if c.refine_poses_sfm is not None else motion is not None
        if mode == "vo" and refine and len(traj) >= c.min_frames:
            report("sfm", 0, None)
            with sw.stage("refine_poses"):
                traj = _refine_with_sfm(traj, keyframes, partners, work, K, B, source.fps, counts)
        if len(traj) < c.min_frames:
            raise StageError("poses", f"only {len(traj)} frames have a pose (tracking lost); at least {c.min_frames} "
                                      "are needed")
        pose_by_index = {int(i): T for i, T in zip(traj.indices, traj.T_wc)}

        # ---- pass 2: fusion of keyframes with final poses ------------------------------------
        if c.fusion_depth_max_rel is not None and view_depths_m and c.fusion.roi_min_m is None:
            # Region of interest: the object the camera looks at, not the far ground.
            roi_max = c.fusion_depth_max_rel * float(np.median(view_depths_m))
            fcfg = replace(fcfg, depth_max_m=float(min(fcfg.depth_max_m, max(roi_max, fcfg.depth_min_m * 1.01))))
        sub = 1
        if c.fusion_min_width_px is not None:
            sub = max(1, int(rig.image_size[0] // c.fusion_min_width_px))
        counts["fusion_subsample"] = sub
        counts["fusion_depth_max_m"] = fcfg.depth_max_m
        if fcfg.voxel_m is None and view_depths_m:
            # Footprints of full-resolution pixels at the first view's median depth, as without subsampling:
            # the grid's resolution does not depend on how many pixels are integrated.
            footprint = fcfg.voxel_footprint_px
            if motion is not None and partners and motion.voxel_footprint_px is not None:
                footprint = motion.voxel_footprint_px  # the wide pairs' finer depth (motion_stereo)
            fcfg = replace(fcfg, voxel_m=voxel_size_from_depth(np.asarray(view_depths_m[:1]), f_px, footprint,
                                                               fcfg.min_voxel_m, fcfg.max_voxel_m))

        # ---- motion stereo: wide-baseline depth of the paired fusion views (to disk), trajectory scale ----
        wide_views: set[int] = set()
        motion_counts: list[dict] = []
        scale = 1.0  # applied to the wide depths together with the trajectory
        if motion is not None and partners:
            (work / "wide").mkdir()
            out_size = (-(-rig.image_size[0] // sub), -(-rig.image_size[1] // sub))

            def wide_view(idx: int):
                j = partners[idx]
                color = cv2.imread(str(work / "images" / f"{idx:06d}.png"), cv2.IMREAD_COLOR)
                pair = rectify_motion_pair(K, pose_by_index[idx], pose_by_index[j], rig.image_size, out_size)
                partner = cv2.imread(str(work / "partner" / f"{idx:06d}.png"), cv2.IMREAD_GRAYSCALE)
                z, mc = motion_depth(cv2.cvtColor(color, cv2.COLOR_BGR2GRAY), partner,
                                     np.load(work / "depth" / f"{idx:06d}.npy"), pair, dcfg, motion, f_px * B,
                                     fcfg.depth_max_m)
                np.savez(work / "wide" / f"{idx:06d}.npz", color=cv2.remap(color, *pair.maps_a, cv2.INTER_LINEAR),
                         depth=z, K=pair.K_rect, R_rect=pair.R_rect_a)
                log.debug("motion stereo: view %d with frame %d, baseline %.3f m, %s", idx, j, pair.baseline_m, mc)
                return idx, mc

            todo = [idx for idx, j in partners.items() if idx in pose_by_index and j in pose_by_index]
            with sw.stage("motion_stereo"), ThreadPoolExecutor(max_workers=2, thread_name_prefix="motion") as ex:
                for idx, mc in ex.map(wide_view, todo):
                    wide_views.add(idx)
                    motion_counts.append(mc)
                    report("motion stereo", len(wide_views), len(todo))
            counts["motion_stereo_views"] = len(wide_views)
            ratios = [m["rig_ratio_median"] for m in motion_counts if np.isfinite(m["rig_ratio_median"])]
            if mode == "vo" and motion.rescale_trajectory and len(ratios) >= 3:
                # The rig's dense depth against the wide pairs' depth (whose baselines are odometry's steps)
                # measures odometry's scale: the median ratio over all pairs, applied to the whole trajectory
                # (and so to the wide depths). Why it matters: around a truck, a trajectory 0.3 % small puts
                # every camera 3 cm too close to the centre at 9 m, and both side walls 3 cm inside.
                scale = float(np.median(ratios))
                counts["trajectory_scale_from_rig"] = scale
                if abs(scale - 1.0) <= motion.max_rescale:
                    traj.T_wc[:, :3, 3] *= scale
                    pose_by_index = {int(i): T for i, T in zip(traj.indices, traj.T_wc)}
                else:
                    log.warning("odometry's scale disagrees with the rig's depth by %.1f %%; not rescaled",
                                100 * (scale - 1.0))
                    scale = 1.0
            counts["motion_stereo_depth_scale"] = scale

        @functools.lru_cache(maxsize=2 * (c.consistency_views or 0) + 2)
        def fusion_view(idx: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
            """(colour, depth, K, T_wc) of a keyframe as fused, at 1/sub resolution.

            With a motion-stereo partner: the wide-baseline depth, in the pair's rectified frame (a
            rotation of the keyframe's camera, hence its own K and pose); else every sub-th pixel of
            the rig's depth, in the keyframe's camera.
            """
            T = pose_by_index.get(idx)
            if idx in wide_views:
                v = np.load(work / "wide" / f"{idx:06d}.npz")
                return v["color"], v["depth"] * np.float32(scale), v["K"], T @ _rot4(v["R_rect"].T)
            color = cv2.imread(str(work / "images" / f"{idx:06d}.png"), cv2.IMREAD_COLOR)
            return (*subsample_for_fusion(color, np.load(work / "depth" / f"{idx:06d}.npy"), K, sub), T)

        if fcfg.block_count is None and keyframes:
            # Size the voxel-block hash map for all views up front: growing it (Open3D's reserve) rehashes
            # and copies the whole grid, which cost more than the integration itself on the 120-frame orbit.
            _, z0, K0, _ = fusion_view(keyframes[0])
            z0 = np.where((z0 >= fcfg.depth_min_m) & (z0 <= fcfg.depth_max_m), z0, np.nan)
            if np.isfinite(z0).any() and fcfg.voxel_m is not None:
                est = estimate_block_count(z0, K0, fcfg.voxel_m,
                                           fcfg.block_resolution, fcfg.trunc_voxels, frames=len(keyframes))
                # At most 1.5 GiB up front (the grid still grows past it when needed, up to max_memory_gib).
                cap = int(min(1.5, fcfg.max_memory_gib) * 2**30 // (fcfg.block_resolution ** 3 * 20))
                fcfg = replace(fcfg, block_count=int(min(2 * est, cap)))
        fusion = TSDFFusion(fcfg)
        fused = 0
        posed = [idx for idx in keyframes if idx in pose_by_index]
        centres = np.array([pose_by_index[idx][:3, 3] for idx in posed]).reshape(-1, 3)

        def load_views():
            for n, idx in enumerate(keyframes):
                T = pose_by_index.get(idx)
                if T is None:
                    continue
                color, depth, K_view, T = fusion_view(idx)
                if c.consistency_views and len(posed) > 1:
                    near = np.argsort(np.linalg.norm(centres - T[:3, 3], axis=1))[1:c.consistency_views + 1]
                    others = [fusion_view(posed[j])[1:] for j in near]
                    keep = consistent_depth_mask(depth, K_view, T, others, c.consistency_rel_tol,
                                                 c.consistency_min_views)
                    depth = np.where(keep, depth, np.nan).astype(np.float32)
                yield n, T, (color, depth, K_view)

        # The next view is read from disk while this one is integrated.
        for n, T, (color, depth, K_view) in _prefetch(load_views(), 2):
            with sw.stage("fusion"):
                fusion.integrate(color, depth, K_view, T)
            fused += 1
            report("fusion", n + 1, len(keyframes))
        counts["keyframes_fused"] = fused
        if motion_counts:
            counts["motion_stereo_wide_valid_mean"] = float(np.mean([m["wide_valid"] for m in motion_counts]))
            counts["motion_stereo_rig_filled_mean"] = float(np.mean([m["rig_filled"] for m in motion_counts]))
        report("extract", 0, None)
        with sw.stage("extract"):
            min_w = min(fcfg.min_weight, max(1.0, fused / 3.0))  # a handful of views must still give points
            pts, rgb, normals = fusion.extract_cloud(min_weight=min_w, normals=True)
            if len(pts) == 0:
                raise StageError("fusion", "the fused volume has no surface points (no overlapping valid depth)")
            write_cloud_ply(stage_dir / "cloud.ply", pts, rgb, normals)
            if c.mesh:
                import open3d as o3d

                o3d.io.write_triangle_mesh(str(stage_dir / "mesh.ply"), fusion.extract_mesh(min_weight=min_w))
        counts["cloud_points"] = int(len(pts))

        from stereo_recon.trajectory import Trajectory, up_from_trajectory, write_tum

        # poses.txt describes the physical left camera (conventions.py): undo the rectifying rotation.
        traj_out = Trajectory(traj.indices, traj.timestamps_s, traj.T_wc @ _rot4(rect.R1), dict(traj.stats))
        write_tum(stage_dir / "poses.txt", traj_out)
        up = up_from_trajectory(traj_out)
        timings = dict(sw.timings_s)
        timings["total"] = time.perf_counter() - t_start
        inputs = {"video": source.path}
        if calib_path is not None:
            inputs["calib"] = Path(calib_path)
        if mode == "gt":
            inputs["poses_gt"] = Path(c.poses[3:])
        manifest = run_manifest(
            "reconstruct", inputs, {"reconstruct": asdict(c), "disparity": asdict(dcfg), "fusion": asdict(fcfg)},
            timings,
            extra={
                "rig": _rig_summary(rig, rect),
                "source": source.describe(),
                "counts": counts,
                "poses": {"backend": mode, "frames": len(traj), "stats": traj.stats,
                          "tracking_gaps": traj.stats.get("gaps", traj.stats.get("tracking_gaps", [])),
                          "path_length_m": traj.path_length_m()},
                "fusion": asdict(fusion.stats),
                "fused_views": [int(i) for i in posed],  # frame indices of the fused views (COLMAP export)
                "voxel_m": fusion.voxel_m,
                "up": up,
                "outputs": sorted(["cloud.ply", "poses.txt", "run.json"] + (["mesh.ply"] if c.mesh else [])),
            },
        )
        if not c.keep_work:
            shutil.rmtree(work, ignore_errors=True)
        write_json_atomic(stage_dir / "run.json", manifest)
    return manifest
