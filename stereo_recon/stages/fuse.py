"""Stage ``fuse_views``: TSDF fusion of the views with their final poses, and the cloud it holds."""

from __future__ import annotations

import functools

import numpy as np

from stereo_recon.core.errors import StageError
from stereo_recon.fusion import TSDFFusion, consistent_depth_mask
from stereo_recon.reconstruct_config import ReconstructConfig
from stereo_recon.stages.plan import size_block_map
from stereo_recon.stages.state import Cloud, FusionPlan, RunContext, WideDepth, rot4
from stereo_recon.threads import prefetch


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


class FusionViews:
    """The views as fused, read from the work folder: (colour, depth m, K px, T_wc) of a view index.

    With a motion-stereo partner: the wide-baseline depth, in the pair's rectified frame (a rotation of
    the view's camera, hence its own K and pose); else every n-th pixel of the rig's depth, in the view's
    camera. The last few views are cached (the consistency check reads neighbours again).
    """

    def __init__(self, work, K: np.ndarray, subsample: int, poses: dict, wide: WideDepth, cache_size: int):
        self.work, self.K, self.subsample, self.poses, self.wide = work, K, subsample, poses, wide
        self.get = functools.lru_cache(maxsize=cache_size)(self._load)

    def _load(self, idx: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        import cv2

        T = self.poses.get(idx)
        if idx in self.wide.views:
            v = np.load(self.work / "wide" / f"{idx:06d}.npz")
            return v["color"], v["depth"] * np.float32(self.wide.scale), v["K"], T @ rot4(v["R_rect"].T)
        color = cv2.imread(str(self.work / "images" / f"{idx:06d}.png"), cv2.IMREAD_COLOR)
        return (*subsample_for_fusion(color, np.load(self.work / "depth" / f"{idx:06d}.npy"), self.K,
                                      self.subsample), T)


def _consistent_views(views: FusionViews, keyframes, posed: list[int], config: ReconstructConfig):
    """(position in keyframes, T_wc, (colour, depth, K)) of each posed view, depth kept where neighbours agree."""
    c = config
    centres = np.array([views.poses[idx][:3, 3] for idx in posed]).reshape(-1, 3)
    for n, idx in enumerate(keyframes):
        if views.poses.get(idx) is None:
            continue
        color, depth, K_view, T = views.get(idx)
        if c.consistency_views and len(posed) > 1:
            near = np.argsort(np.linalg.norm(centres - T[:3, 3], axis=1))[1:c.consistency_views + 1]
            others = [views.get(posed[j])[1:] for j in near]
            keep = consistent_depth_mask(depth, K_view, T, others, c.consistency_rel_tol, c.consistency_min_views)
            depth = np.where(keep, depth, np.nan).astype(np.float32)
        yield n, T, (color, depth, K_view)


def fuse_views(traj, keyframes, plan: FusionPlan, wide: WideDepth, K: np.ndarray, config: ReconstructConfig,
               ctx: RunContext) -> Cloud:
    """Integrate every posed view into a TSDF volume and extract its surface.

    traj: final trajectory (world-from-rectified-left-camera, m); keyframes: view indices in order (work
    folder); plan: ``plan_fusion``'s settings; wide: ``motion_stereo``'s depths; K: (3, 3) rectified
    intrinsics, px. Raises StageError when the volume holds no surface.
    """
    c = config
    poses = {int(i): T for i, T in zip(traj.indices, traj.T_wc)}
    views = FusionViews(ctx.work, K, plan.subsample, poses, wide, 2 * (c.consistency_views or 0) + 2)
    fcfg = plan.fusion
    if fcfg.block_count is None and keyframes:
        _, z0, K0, _ = views.get(keyframes[0])
        fcfg = size_block_map(fcfg, z0, K0, len(keyframes))
    fusion = TSDFFusion(fcfg)
    fused = 0
    posed = [idx for idx in keyframes if idx in poses]
    # The next view is read from disk while this one is integrated.
    for n, T, (color, depth, K_view) in prefetch(_consistent_views(views, keyframes, posed, c), 2):
        with ctx.clock.stage("fusion"):
            fusion.integrate(color, depth, K_view, T)
        fused += 1
        ctx.report("fusion", n + 1, len(keyframes))
    ctx.counts["keyframes_fused"] = fused
    if wide.counts:
        ctx.counts["motion_stereo_wide_valid_mean"] = float(np.mean([m["wide_valid"] for m in wide.counts]))
        ctx.counts["motion_stereo_rig_filled_mean"] = float(np.mean([m["rig_filled"] for m in wide.counts]))
    ctx.report("extract", 0, None)
    with ctx.clock.stage("extract"):
        min_w = min(fcfg.min_weight, max(1.0, fused / 3.0))  # a handful of views must still give points
        pts, rgb, normals = fusion.extract_cloud(min_weight=min_w, normals=True)
        if len(pts) == 0:
            raise StageError("fusion", "the fused volume has no surface points (no overlapping valid depth)")
        mesh = fusion.extract_mesh(min_weight=min_w) if c.mesh else None
    ctx.counts["cloud_points"] = int(len(pts))
    return Cloud(pts, rgb, normals, mesh, fcfg, fusion.stats, fusion.voxel_m, tuple(int(i) for i in posed))


