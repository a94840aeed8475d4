"""Stage ``motion_stereo``: wide-baseline depth of the paired fusion views (to disk), and the trajectory's scale."""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from stereo_recon.motion_stereo import (MotionStereoConfig, motion_depth, rectify_motion_pair, rig_depth_for_scale,
                                        sparse_rig_ratios)
from stereo_recon.stages.state import FusionPlan, RunContext, Setup, Streamed, WideDepth

log = logging.getLogger(__name__)


def wide_view(idx: int, j: int, T_a: np.ndarray, T_b: np.ndarray, setup: Setup, plan: FusionPlan,
              motion: MotionStereoConfig, work, for_scale: bool = False) -> dict:
    """Motion-stereo depth of view idx with its partner frame j, written to work/wide/<idx>.npz; its counts.

    T_a, T_b: world-from-camera poses (m) of the two frames; the npz holds the view's colour and depth
    (m) resampled into the pair's rectified frame, that frame's K (px) and its rotation R_rect. for_scale:
    the view measures the trajectory's scale (``rig_scale_ratio_median``): its corners tracked into the rig's
    right eye and the partner (``sparse_rig_ratios``, scale_mode "lk") or its rig pair matched again with SGBM
    (``rig_depth_for_scale``).
    """
    import cv2

    image_size = setup.rig.image_size
    sub = plan.subsample
    out_size = (-(-image_size[0] // sub), -(-image_size[1] // sub))
    color = cv2.imread(str(work / "images" / f"{idx:06d}.png"), cv2.IMREAD_COLOR)
    gray = cv2.cvtColor(color, cv2.COLOR_BGR2GRAY)
    pair = rectify_motion_pair(setup.K, T_a, T_b, image_size, out_size)
    partner = cv2.imread(str(work / "partner" / f"{idx:06d}.png"), cv2.IMREAD_GRAYSCALE)
    rig_depth = np.load(work / "depth" / f"{idx:06d}.npy")
    fb = setup.focal_px * setup.baseline_m
    right = work / "right" / f"{idx:06d}.png"
    right_gray = cv2.imread(str(right), cv2.IMREAD_GRAYSCALE) if for_scale and right.is_file() else None
    scale_depth = None
    if right_gray is not None and motion.scale_mode != "lk":
        scale_depth = rig_depth_for_scale(gray, right_gray, rig_depth, setup.disparity, motion, fb)
    z, mc = motion_depth(gray, partner, rig_depth, pair, setup.disparity, motion, fb, plan.fusion.depth_max_m,
                         scale_depth_a_m=scale_depth)
    if right_gray is not None and motion.scale_mode == "lk":
        ratios = sparse_rig_ratios(gray, right_gray, partner, setup.K, T_a, T_b, fb, rig_depth, motion)
        mc["rig_scale_corners"] = float(len(ratios))
        if len(ratios) >= motion.scale_min_corners:
            mc["rig_scale_ratio_median"] = float(np.median(ratios))
    np.savez(work / "wide" / f"{idx:06d}.npz", color=cv2.remap(color, *pair.maps_a, cv2.INTER_LINEAR),
             depth=z, K=pair.K_rect, R_rect=pair.R_rect_a)
    log.debug("motion stereo: view %d with frame %d, baseline %.3f m, %s", idx, j, pair.baseline_m, mc)
    return mc


def scale_view_indices(todo: list[int], motion: MotionStereoConfig) -> set[int]:
    """The paired views that measure the trajectory's scale: every one with scale_mode "lk" (a few corners
    each), else up to ``scale_views`` (their rig pairs matched again with SGBM), evenly spread."""
    if motion.scale_mode == "lk":
        return set(todo)
    n = min(motion.scale_views, len(todo))
    if n <= 0:
        return set()
    return {todo[int(k)] for k in np.round(np.linspace(0, len(todo) - 1, n)).astype(int)}


def rig_scale(motion_counts, motion: MotionStereoConfig) -> float | None:
    """The camera path's scale against the rig's depth: the median rig/wide depth ratio over the pairs (None: < 3).

    The rig's depth against the wide pairs' depth (whose baselines are the path's steps) measures the path's
    scale: odometry's, or the bundle adjustment's when SfM refined the poses (``sfm.refine_with_sfm``). Why it
    matters: around a truck, a trajectory 0.3 % small puts every camera 3 cm too close to the centre at 9 m,
    and both side walls 3 cm inside. The rig's depth is the re-matched one of
    the scale views (``rig_scale_ratio_median``) when at least 3 of them give a ratio, else the fused
    depth's of every pair.
    """
    for key in ("rig_scale_ratio_median", "rig_ratio_median"):
        ratios = [m[key] for m in motion_counts if np.isfinite(m.get(key, np.nan))]
        if motion.rescale_trajectory and len(ratios) >= 3:
            return float(np.median(ratios))
    return None


def motion_stereo(traj, setup: Setup, streamed: Streamed, plan: FusionPlan, ctx: RunContext):
    """Wide-baseline depth for every posed view with a posed partner; the trajectory rescaled to the rig's depth.

    traj: the final trajectory (world-from-rectified-left-camera, m). Returns (trajectory, WideDepth): the
    trajectory scaled by the median rig/wide ratio (mode "vo", within ``max_rescale``; else the same one).
    Nothing is done without motion stereo or partners.
    """
    motion, partners = streamed.motion, streamed.partners
    if motion is None or not partners:
        return traj, WideDepth()
    from stereo_recon.trajectory import Trajectory

    (ctx.work / "wide").mkdir()
    pose_by_index = {int(i): T for i, T in zip(traj.indices, traj.T_wc)}
    todo = [idx for idx, j in partners.items() if idx in pose_by_index and j in pose_by_index]
    views: set[int] = set()
    motion_counts: list[dict] = []

    for_scale = scale_view_indices(todo, motion) if motion.rescale_trajectory and setup.mode == "vo" else set()

    def one(idx: int) -> tuple[int, dict]:
        j = partners[idx]
        return idx, wide_view(idx, j, pose_by_index[idx], pose_by_index[j], setup, plan, motion, ctx.work,
                              idx in for_scale)

    with ctx.clock.stage("motion_stereo"), ThreadPoolExecutor(max_workers=2, thread_name_prefix="motion") as ex:
        for idx, mc in ex.map(one, todo):
            views.add(idx)
            motion_counts.append(mc)
            ctx.report("motion stereo", len(views), len(todo))
    ctx.counts["motion_stereo_views"] = len(views)
    scale = 1.0  # applied to the wide depths together with the trajectory
    ctx.counts["motion_stereo_scale_views"] = sum(np.isfinite(m["rig_scale_ratio_median"]) for m in motion_counts)
    measured = rig_scale(motion_counts, motion) if setup.mode == "vo" else None
    if measured is not None:
        ctx.counts["trajectory_scale_from_rig"] = measured
        if abs(measured - 1.0) <= motion.max_rescale:
            scale = measured
            T_wc = traj.T_wc.copy()
            T_wc[:, :3, 3] *= scale
            traj = Trajectory(traj.indices, traj.timestamps_s, T_wc, traj.stats)
        else:
            # Not corrected, so every dimension may be off by as much: the run's data-quality gate
            # (``quality.trajectory_scale_check``) makes the verdict undecided.
            log.warning("the camera path's scale disagrees with the rig's depth by %.1f %%; not rescaled",
                        100 * (measured - 1.0))
    ctx.counts["motion_stereo_depth_scale"] = scale
    return traj, WideDepth(frozenset(views), tuple(motion_counts), scale)
