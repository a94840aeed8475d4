"""Command-line options shared by several subcommands, declared once, and their mapping onto ReconstructConfig."""

from __future__ import annotations

import argparse

# --refine-poses -> ReconstructConfig.refine_poses_sfm
REFINE_POSES_CHOICES = {"auto": None, "on": True, "off": False}
PRESETS = ("fast", "balanced", "quality", "wls")
# --plain-paint -> ReconstructConfig.disparity_overrides (stereo_recon.disparity's texture test and occlusion-wide
# fill, and no same-surface interpolation, which would bridge a dropped roof to the ground behind it). Off by
# default: the threshold that keeps a plain black roof from being carved (tuning draw 2035/0 at 48 frames H
# -17.2 % -> -2.4 %) also drops weakly textured panels (Table 2 end to end 0.66 -> 1.16 %, one truck split in two;
# docs/ROUNDS.md, issue 12's fifteenth round).
PLAIN_PAINT = {"min_texture_snr": 2.0, "fill_occlusion_slack_px": 3.0, "fill_same_surface_px": None}


def add_pose_options(p: argparse.ArgumentParser) -> None:
    """--motion-stereo and --refine-poses (run, batch, bench, reconstruct)."""
    p.add_argument("--motion-stereo", action="store_true",
                   help="match each fused view with a later frame ~0.11 x the depth away (a wide baseline) and fuse "
                        "that depth, also on near scenes (far scenes get it anyway); vo or gt poses only")
    p.add_argument("--refine-poses", choices=tuple(REFINE_POSES_CHOICES), default="auto",
                   help="bundle-adjust the fused views' VO poses with pycolmap SfM (auto: far scenes only; vo poses)")
    p.add_argument("--far-scene-baselines", type=_far_scene_baselines, default=None, metavar="Z|off",
                   help="a scene whose first view's median depth is beyond Z rig baselines is far: motion stereo, "
                        "dense-depth VO and SfM-refined poses (default 14.2; off: never)")


def _far_scene_baselines(text: str):
    """--far-scene-baselines: a positive number of rig baselines, or 'off' (returned as the string)."""
    if text.strip().lower() == "off":
        return "off"
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: a positive number of rig baselines (e.g. 14.2) or 'off'")
    return value


def add_frame_options(p: argparse.ArgumentParser) -> None:
    """--frames, --step, --preset, --mesh, --plain-paint (run, batch, reconstruct)."""
    p.add_argument("--frames", default=None, metavar="A:B", help="half-open frame range of the video to use, e.g. 100:400 (default: all)")
    p.add_argument("--step", type=int, default=1, help="use every N-th frame (default 1)")
    p.add_argument("--preset", default="balanced", choices=PRESETS, help="disparity (SGBM) preset (default balanced)")
    p.add_argument("--mesh", action="store_true", help="also write mesh.ply (marching cubes of the TSDF volume)")
    p.add_argument("--plain-paint", action="store_true",
                   help="a plain dark body: no depth where the image noise drowns the texture, holes filled only as "
                        "wide as an occlusion (keeps a black roof from being carved; costs depth on weakly textured "
                        "panels, so off by default)")


def reconstruct_overrides(args) -> dict:
    """ReconstructConfig fields for the options above that differ from their defaults (as ``reconstruct`` takes them)."""
    from stereo_recon.motion_stereo import MotionStereoConfig
    from stereo_recon.video import parse_frame_range

    overrides: dict = {}
    if getattr(args, "motion_stereo", False):
        overrides["motion_stereo"] = MotionStereoConfig()
    refine = REFINE_POSES_CHOICES[getattr(args, "refine_poses", "auto")]
    if refine is not None:
        overrides["refine_poses_sfm"] = refine
    far = getattr(args, "far_scene_baselines", None)
    if far is not None:
        overrides["far_scene_depth_baselines"] = None if far == "off" else far
    if getattr(args, "frames", None) is not None and isinstance(args.frames, str):   # bench's --frames is a count
        overrides["frame_range"] = parse_frame_range(args.frames)
    if getattr(args, "step", 1) != 1:
        overrides["step"] = args.step
    if getattr(args, "preset", "balanced") != "balanced":
        overrides["disparity_preset"] = args.preset
    if getattr(args, "mesh", False):
        overrides["mesh"] = True
    if getattr(args, "plain_paint", False):
        overrides["disparity_overrides"] = dict(PLAIN_PAINT)
    return overrides


def reconstruct_config(args):
    """The one ReconstructConfig of a command (validated on construction: ConfigError for a bad combination)."""
    from stereo_recon.reconstruct import ReconstructConfig

    return ReconstructConfig(poses=args.poses, rectified=getattr(args, "rectified", None), **reconstruct_overrides(args))
