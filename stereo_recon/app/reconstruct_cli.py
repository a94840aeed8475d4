"""``stereo-recon reconstruct``: side-by-side stereo video -> cloud.ply, poses.txt, run.json."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stereo_recon.app.options import REFINE_POSES_CHOICES, add_frame_options, add_pose_options
from stereo_recon.core.paths import POSES, RUN_JSON, RunPaths


def register(subparsers) -> None:
    """Add the ``reconstruct`` subcommand."""
    p = subparsers.add_parser(
        "reconstruct",
        help="fused point cloud and camera trajectory from a side-by-side stereo video",
        description="Stream a side-by-side stereo video (or a folder of left/right images), rectify, compute SGBM "
                    "depth, estimate metric camera poses (stereo VO, pycolmap SfM, or a known TUM trajectory), fuse "
                    "keyframes into an Open3D TSDF volume and write OUT/cloud.ply, OUT/poses.txt (TUM) and OUT/run.json.",
    )
    p.add_argument("video", help="side-by-side video (left eye in the left half) or folder of stereo images")
    p.add_argument("--calib", required=True,
                   help="ZED SN*.conf, rig .yaml/.xml, or fx,fy,cx,cy,baseline_m[,w,h] for rectified frames")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--poses", default="vo", metavar="{vo,sfm,gt:PATH}",
                   help="pose back-end: vo (stereo visual odometry, default), sfm (pycolmap), or gt:PATH to fuse with a "
                        "known TUM trajectory (world-from-left-camera, timestamp = frame index / fps)")
    p.add_argument("--fps", type=float, default=None, help="override the video's frame rate (timestamps)")
    p.add_argument("--voxel-m", type=float, default=None, help="TSDF voxel size in m (default: from the scene's depth)")
    p.add_argument("--depth-min-m", type=float, default=0.3, help="nearest depth used, m (default 0.3, ZED2)")
    p.add_argument("--depth-max-m", type=float, default=None,
                   help="farthest depth used, m (default: where the rig's disparity falls to 1 px, 63 m for a ZED2 at HD720)")
    p.add_argument("--all-frames", action="store_true",
                   help="fuse every processed frame instead of motion-selected keyframes")
    p.add_argument("--rectified", action="store_true",
                   help="frames are already rectified (ZED SDK exports): skip rectification")
    p.add_argument("--gpu", action="store_true", help="rectify on a CUDA GPU with torch/kornia (pip install .[gpu])")
    p.add_argument("--keep-work", action="store_true", help="keep keyframe images/depth maps in OUT/work")
    p.add_argument("--export-colmap", default=None, metavar="DIR",
                   help="also write the fused views as a COLMAP model: DIR/sparse/0 (cameras, images with poses) and "
                        "DIR/images (their left frames)")
    add_frame_options(p)
    add_pose_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler: build the config, run ``reconstruct``, print a summary."""
    from calib.io import parse_calib_arg
    from stereo_recon.core.errors import ConfigError
    from stereo_recon.motion_stereo import MotionStereoConfig
    from stereo_recon.core.progress import ProgressConfig, StageProgress
    from stereo_recon.reconstruct import ReconstructConfig, reconstruct
    from stereo_recon.video import open_stereo_source, parse_frame_range

    if args.gpu:
        from stereo_recon import gpu

        if not gpu.cuda_available():
            raise ConfigError("--gpu: torch with a CUDA device is not available (install the [gpu] extra)")
    from stereo_recon.core.validate import check_number, check_output_dir

    # Options and the output folder are checked before the video is opened.
    check_number("--fps", args.fps)
    check_number("--voxel-m", args.voxel_m)
    check_number("--depth-min-m", args.depth_min_m, allow_none=False)
    check_number("--depth-max-m", args.depth_max_m)   # None: derived from the rig
    check_number("--step", args.step, integer=True, minimum=1, strict=False)
    check_output_dir(args.out)
    if args.poses.startswith("gt:") and not Path(args.poses[3:]).is_file():
        raise ConfigError(f"--poses {args.poses}: trajectory file not found")
    frame_range = parse_frame_range(args.frames)
    source = open_stereo_source(args.video, frame_range, args.step, args.fps)
    rig = parse_calib_arg(args.calib, image_size=source.eye_size)
    config = ReconstructConfig(
        poses=args.poses, frame_range=frame_range, step=args.step, fps=args.fps,
        rectified=True if args.rectified else None, depth_min_m=args.depth_min_m, depth_max_m=args.depth_max_m,
        disparity_preset=args.preset, voxel_m=args.voxel_m, mesh=args.mesh, gpu=args.gpu,
        keyframes=None if args.all_frames else ReconstructConfig().keyframes, keep_work=args.keep_work,
        motion_stereo=MotionStereoConfig() if args.motion_stereo else None,
        refine_poses_sfm=REFINE_POSES_CHOICES[args.refine_poses],
    )
    progress = StageProgress(("depth", "poses", "sfm", "motion stereo", "fusion", "extract"),
                             config=ProgressConfig(enabled=not getattr(args, "quiet", False)))
    calib_path = Path(args.calib) if Path(args.calib).exists() else None
    try:
        man = reconstruct(args.video, rig, args.out, config, calib_path=calib_path, progress=progress)
    finally:
        progress.close()
    if args.export_colmap:
        from stereo_recon.colmap_export import export_colmap

        model = export_colmap(args.out, args.export_colmap)
        if not getattr(args, "quiet", False):
            print(f"  COLMAP model: {model} (images in {Path(args.export_colmap) / 'images'})")
    if not getattr(args, "quiet", False):
        cnt, poses = man["counts"], man["poses"]
        gaps = poses.get("tracking_gaps") or []
        t = man["timings_s"]
        print(f"reconstruct: {cnt['frames_read']} frames read ({len(cnt['bad_frames'])} undecodable), "
              f"{cnt['keyframes_fused']} keyframes fused, {poses['frames']} poses ({poses['backend']}), "
              f"{len(gaps)} tracking gap(s)", file=sys.stdout)
        print(f"  cloud: {cnt['cloud_points']} points, voxel {man['voxel_m'] * 1000:.1f} mm; "
              f"up = [{', '.join(f'{v:.3f}' for v in man['up'])}]")
        stages = ", ".join(f"{k} {v:.1f}s" for k, v in t.items())
        print(f"  times: {stages}")
        print(f"  wrote {RunPaths(Path(args.out)).cloud}, {POSES}, {RUN_JSON}")
    return 0
