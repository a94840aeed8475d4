"""The reconstruction as named stages, chained by ``stereo_recon.reconstruct.reconstruct``.

Each stage is a function ``stage(inputs, config, ctx) -> outputs``: inputs and outputs are small
frozen records (``state``), config the run's ``ReconstructConfig``, ctx the run's ``RunContext``
(output and work folders, stopwatch, progress callback, the manifest's counts).

    open_input      (inputs)  video + rig              -> Setup (source, rectification, disparity/fusion settings)
    stream_views    (stream)  Setup                    -> Streamed (fusion views on disk, their depths, partners)
      far_scene     (stream)  first view's depth       -> FarScene (switch to motion stereo, dense-depth VO)
    solve_poses     (poses)   Setup, Streamed          -> Trajectory (VO / SfM / known)
    refine_poses    (poses)   Trajectory, Streamed     -> Trajectory (SfM bundle adjustment grafted on VO)
    plan_fusion     (plan)    Setup, Streamed          -> FusionPlan (ROI depth, subsampling, voxel)
    motion_stereo   (motion)  Trajectory, FusionPlan   -> (Trajectory rescaled, WideDepth on disk)
    fuse_views      (fuse)    Trajectory, FusionPlan   -> Cloud (TSDF, block map sized up front)
    write_outputs   (outputs) Cloud, Trajectory        -> cloud.ply, poses.txt, run.json
"""
