"""Stages ``solve_poses`` and ``refine_poses``: the final camera trajectory of the fusion views."""

from __future__ import annotations

import numpy as np

from stereo_recon.core.errors import StageError
from stereo_recon.reconstruct_config import ReconstructConfig
from stereo_recon.stages.state import RunContext, Setup, Streamed


def solve_poses(setup: Setup, streamed: Streamed, config: ReconstructConfig, ctx: RunContext):
    """The trajectory by the configured back-end: VO's (loop-closed), pycolmap SfM's of the views, or the known one.

    Returns a ``trajectory.Trajectory`` (world-from-rectified-left-camera, m). Raises StageError when SfM
    has fewer than ``config.min_frames`` views.
    """
    c, keyframes = config, streamed.keyframes
    ctx.report("poses", 0, None)
    with ctx.clock.stage("poses"):
        if setup.mode == "vo":
            return streamed.vo.finish()
        if setup.mode == "sfm":
            from stereo_recon.sfm import sfm_poses

            if len(keyframes) < c.min_frames:
                raise StageError("poses", f"only {len(keyframes)} keyframes for SfM; at least {c.min_frames} are "
                                          "needed (lower --step or use more frames)")
            ctx.report("sfm", 0, None)
            return sfm_poses(ctx.work / "images", setup.K, ctx.work / "sfm", baseline_m=setup.baseline_m,
                             depth_dir=ctx.work / "depth", fps=setup.source.fps)
        from stereo_recon.trajectory import Trajectory

        keyset = set(keyframes) | set(streamed.partners.values())
        sel = [i for i, idx in enumerate(setup.gt.indices) if int(idx) in keyset]
        return setup.gt.subset(np.asarray(sel, dtype=np.int64)) if sel else Trajectory([], [], np.zeros((0, 4, 4)))


def refine_poses(traj, setup: Setup, streamed: Streamed, config: ReconstructConfig, ctx: RunContext):
    """VO's trajectory with the views bundle-adjusted by SfM when asked (``refine_poses_sfm``; None = with motion
    stereo), then checked: raises StageError when fewer than ``config.min_frames`` frames have a pose."""
    c = config
    refine = c.refine_poses_sfm if c.refine_poses_sfm is not None else streamed.motion is not None
    if setup.mode == "vo" and refine and len(traj) >= c.min_frames:
        from stereo_recon.sfm import refine_with_sfm

        ctx.report("sfm", 0, None)
        with ctx.clock.stage("refine_poses"):
            traj = refine_with_sfm(traj, streamed.keyframes, streamed.partners, ctx.work, setup.K, setup.baseline_m,
                                   setup.source.fps, ctx.counts, c.refine_max_move_rel, c.refine_max_turn_deg)
    if len(traj) < c.min_frames:
        raise StageError("poses", f"only {len(traj)} frames have a pose (tracking lost); at least {c.min_frames} "
                                  "are needed")
    return traj
