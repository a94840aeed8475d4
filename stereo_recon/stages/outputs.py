"""Stage ``write_outputs``: cloud.ply (and mesh.ply), poses.txt and the run manifest run.json."""

from __future__ import annotations

import shutil
import time
from dataclasses import asdict
from pathlib import Path

from stereo_recon.core.atomic import write_json_atomic
from stereo_recon.core.cloud_io import write_cloud
from stereo_recon.core.manifest import run_manifest
from stereo_recon.core.paths import CLOUD, MESH, POSES, RUN_JSON, RunPaths
from stereo_recon.reconstruct_config import ReconstructConfig
from stereo_recon.stages.state import Cloud, RunContext, Setup, rot4


def rig_summary(rig, rect) -> dict:
    """The rig and its rectification as recorded in run.json (OpenCV names, px and m)."""
    return {"K1": rig.K1, "D1": rig.D1, "K2": rig.K2, "D2": rig.D2, "R": rig.R, "T": rig.T,
            "image_size": list(rig.image_size), "rectified_input": bool(rig.rectified), "baseline_m": rig.baseline_m,
            "metadata": dict(rig.metadata),
            "rectified": {"K_rect": rect.K_rect, "focal_px": rect.focal_px, "baseline_m": rect.baseline_m,
                          "roi_left": list(rect.roi_left)}}


def write_outputs(cloud: Cloud, traj, setup: Setup, config: ReconstructConfig, ctx: RunContext,
                  calib_path=None, t_start: float | None = None) -> dict:
    """Write the run's outputs into ``ctx.stage_dir`` and return the run.json manifest.

    cloud: ``fuse_views``'s surface (world frame, m); traj: the final trajectory in the rectified left
    camera (written for the physical left camera, TUM); calib_path: recorded with its sha256; t_start:
    ``time.perf_counter()`` at the run's start (total time). Removes the work folder unless ``keep_work``.
    """
    from stereo_recon.trajectory import Trajectory, up_from_trajectory, write_tum

    c, out = config, RunPaths(ctx.stage_dir)
    with ctx.clock.stage("extract"):
        write_cloud(out.cloud, cloud.points, cloud.colors, cloud.normals)
        if c.mesh:
            import open3d as o3d

            o3d.io.write_triangle_mesh(str(out.mesh), cloud.mesh)
    # poses.txt describes the physical left camera (conventions.py): undo the rectifying rotation.
    traj_out = Trajectory(traj.indices, traj.timestamps_s, traj.T_wc @ rot4(setup.rect.R1), dict(traj.stats))
    write_tum(out.poses, traj_out)
    up = up_from_trajectory(traj_out)
    timings = dict(ctx.clock.timings_s)
    timings["total"] = time.perf_counter() - (t_start if t_start is not None else time.perf_counter())
    inputs = {"video": setup.source.path}
    if calib_path is not None:
        inputs["calib"] = Path(calib_path)
    if setup.mode == "gt":
        inputs["poses_gt"] = Path(c.poses[3:])
    manifest = run_manifest(
        "reconstruct", inputs, {"reconstruct": asdict(c), "disparity": asdict(setup.disparity),
                                "fusion": asdict(cloud.fusion)},
        timings,
        extra={
            "rig": rig_summary(setup.rig, setup.rect),
            "source": setup.source.describe(),
            "counts": ctx.counts,
            "poses": {"backend": setup.mode, "frames": len(traj), "stats": traj.stats,
                      "tracking_gaps": traj.stats.get("gaps", traj.stats.get("tracking_gaps", [])),
                      "path_length_m": traj.path_length_m()},
            "fusion": asdict(cloud.stats),
            "fused_views": list(cloud.views),  # frame indices of the fused views (COLMAP export)
            "voxel_m": cloud.voxel_m,
            "up": up,
            "outputs": sorted([CLOUD, POSES, RUN_JSON] + ([MESH] if c.mesh else [])),
        },
    )
    if not c.keep_work:
        shutil.rmtree(ctx.work, ignore_errors=True)
    write_json_atomic(out.run_json, manifest)
    return manifest
