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

The stages (``stereo_recon.stages``, each ``stage(inputs, config, ctx) -> outputs``) are chained
by ``reconstruct``: open_input -> stream_views (with the far-scene switch) -> solve_poses ->
refine_poses -> plan_fusion -> motion_stereo -> fuse_views -> write_outputs.

Output folder (written through ``staged_output_dir``: complete or untouched):
    cloud.ply   fused coloured point cloud, world frame, metres
    poses.txt   TUM, world-from-left-camera (the physical, unrectified left eye), timestamp = index / fps
    run.json    inputs (sha256), rig, every parameter, versions, timings, counts, "up", tracking gaps
    mesh.ply    (with ``mesh=True``) marching-cubes surface
"""

from __future__ import annotations

import time

from stereo_recon.core.atomic import staged_output_dir
from stereo_recon.core.manifest import Stopwatch
from stereo_recon.core.paths import RunPaths
from stereo_recon.reconstruct_config import ReconstructConfig, resolved_depth_max_m  # noqa: F401 (public here)
from stereo_recon.stages.fuse import fuse_views, subsample_for_fusion  # noqa: F401 (public here)
from stereo_recon.stages.inputs import open_input
from stereo_recon.stages.motion import motion_stereo
from stereo_recon.stages.outputs import write_outputs
from stereo_recon.stages.plan import plan_fusion
from stereo_recon.stages.poses import refine_poses, solve_poses
from stereo_recon.stages.state import ProgressFn, RunContext
from stereo_recon.stages.stream import stream_views
from stereo_recon.threads import prefetch as _prefetch  # noqa: F401 (earlier name)
from stereo_recon.views import PoseViewSelector  # noqa: F401 (earlier name of views.ViewSelector by pose)


def reconstruct(source_path, rig, out_dir, config: ReconstructConfig = ReconstructConfig(),
                calib_path=None, progress: ProgressFn | None = None) -> dict:
    """Reconstruct a coloured point cloud and camera trajectory from a stereo video.

    source_path: side-by-side video or image folder (``video.open_stereo_source``), or an opened ``video.StereoSource``.
    rig: ``calib.rig.StereoRig`` (scaled to the frames when the aspect matches).
    out_dir: output folder (cloud.ply, poses.txt, run.json[, mesh.ply]); written atomically.
    calib_path: the calibration file, recorded with its sha256 in run.json.
    progress: optional callback (stage, done, total or None) for a terminal display.
    Returns the run.json dict. Raises InputError / StageError with one-line messages.
    """
    c = config
    clock = Stopwatch()
    t_start = time.perf_counter()
    setup = open_input(source_path, rig, c, clock, calib_path)
    with staged_output_dir(out_dir) as stage_dir:
        ctx = RunContext(stage_dir, RunPaths(stage_dir).work, clock, progress or (lambda stage, done, total: None),
                         {"frames_read": 0, "frames_depth": 0, "keyframes": 0, "valid_depth_fraction_mean": 0.0})
        streamed = stream_views(setup, c, ctx)
        traj = solve_poses(setup, streamed, c, ctx)
        traj = refine_poses(traj, setup, streamed, c, ctx)
        motion = streamed.motion
        wide_footprint = (motion.voxel_footprint_px if motion is not None and streamed.partners else None)
        plan = plan_fusion(setup.fusion, streamed.view_depths_m, setup.rig.image_size, setup.focal_px, c,
                           wide_footprint)
        ctx.counts["fusion_subsample"] = plan.subsample
        ctx.counts["fusion_depth_max_m"] = plan.fusion.depth_max_m
        traj, wide = motion_stereo(traj, setup, streamed, plan, ctx)
        cloud = fuse_views(traj, streamed.keyframes, plan, wide, setup.K, c, ctx)
        return write_outputs(cloud, traj, setup, c, ctx, calib_path, t_start)
