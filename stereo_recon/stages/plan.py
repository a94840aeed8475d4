"""Stage ``plan_fusion``: the fused region, pixel subsampling and voxel size; ``size_block_map`` sizes the TSDF's hash map."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from stereo_recon.fusion import FusionConfig, estimate_block_count, voxel_size_from_depth
from stereo_recon.reconstruct_config import ReconstructConfig
from stereo_recon.stages.state import FusionPlan


def plan_fusion(fusion: FusionConfig, view_depths_m, image_size: tuple[int, int], focal_px: float,
                config: ReconstructConfig, wide_footprint_px: float | None = None) -> FusionPlan:
    """TSDF settings for this scene: depth cut at the region of interest, voxel from the first view's depth.

    fusion: settings before planning (``Setup.fusion``); view_depths_m: median depths (m) of the fusion views,
    the first view's first; image_size: (width, height) px of the rectified frames; focal_px: rectified focal
    length (px); wide_footprint_px: the voxel's footprint in pixels when motion-stereo pairs are fused (their
    finer depth), None = ``fusion.voxel_footprint_px``.
    """
    c, fcfg = config, fusion
    if c.fusion_depth_max_rel is not None and view_depths_m and fcfg.roi_min_m is None:
        # Region of interest: the object the camera looks at, not the far ground.
        roi_max = c.fusion_depth_max_rel * float(np.median(view_depths_m))
        fcfg = replace(fcfg, depth_max_m=float(min(fcfg.depth_max_m, max(roi_max, fcfg.depth_min_m * 1.01))))
    sub = 1
    if c.fusion_min_width_px is not None:
        sub = max(1, int(image_size[0] // c.fusion_min_width_px))
    if fcfg.voxel_m is None and view_depths_m:
        # Footprints of full-resolution pixels at the first view's median depth, as without subsampling:
        # the grid's resolution does not depend on how many pixels are integrated.
        footprint = fcfg.voxel_footprint_px if wide_footprint_px is None else wide_footprint_px
        fcfg = replace(fcfg, voxel_m=voxel_size_from_depth(np.asarray(view_depths_m[:1]), focal_px, footprint,
                                                           fcfg.min_voxel_m, fcfg.max_voxel_m))
    return FusionPlan(fcfg, sub)


def size_block_map(fusion: FusionConfig, depth_m: np.ndarray, K: np.ndarray, n_views: int) -> FusionConfig:
    """``fusion`` with its voxel-block hash map sized for all views up front, from one view's depth.

    depth_m (H, W) m and K (3, 3) px: the first view as fused; n_views: views to integrate. Unchanged when
    the block count is set already, the voxel is unknown or the view has no depth in range.
    Why: growing the map (Open3D's reserve) rehashes and copies the whole grid, which cost more than the
    integration itself on the 120-frame orbit.
    """
    if fusion.block_count is not None:
        return fusion
    z0 = np.where((depth_m >= fusion.depth_min_m) & (depth_m <= fusion.depth_max_m), depth_m, np.nan)
    if not (np.isfinite(z0).any() and fusion.voxel_m is not None):
        return fusion
    est = estimate_block_count(z0, K, fusion.voxel_m, fusion.block_resolution, fusion.trunc_voxels, frames=n_views)
    # At most 1.5 GiB up front (the grid still grows past it when needed, up to max_memory_gib).
    cap = int(min(1.5, fusion.max_memory_gib) * 2**30 // (fusion.block_resolution ** 3 * 20))
    return replace(fusion, block_count=int(min(2 * est, cap)))
