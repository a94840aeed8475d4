"""Stage ``open_input``: open the video, fit the rig to it, derive the disparity and fusion settings."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

from stereo_recon.disparity import DisparityConfig, disparity_range_for_depth, preset
from stereo_recon.core.errors import StageError
from stereo_recon.reconstruct_config import ReconstructConfig, resolved_depth_max_m
from stereo_recon.stages.state import Setup, rot4
from stereo_recon.video import StereoSource, open_stereo_source, validate_against_rig

log = logging.getLogger(__name__)


def fit_rig(source, rig, config: ReconstructConfig, calib_path=None):
    """The rig as used on this source: scaled to its frames, or the rectified camera of already-rectified frames."""
    from calib.rig import StereoRig

    rig = validate_against_rig(source, rig)
    if config.rectified and not rig.rectified:
        # Already-rectified frames: the rectified pinhole is approximated by the left eye's intrinsics.
        log.warning("frames marked rectified: using the left intrinsics and baseline of %s as the rectified camera",
                    calib_path or "the rig")
        rig = StereoRig.from_rectified(rig.K1[0, 0], rig.K1[1, 1], rig.K1[0, 2], rig.K1[1, 2], rig.baseline_m,
                                       rig.image_size, source="rectified flag", **{"from": dict(rig.metadata)})
    return rig


def open_input(source_path, rig, config: ReconstructConfig, clock, calib_path=None) -> Setup:
    """Open the stereo source and derive what every later stage needs from it and its rig.

    source_path: side-by-side video or image folder (``video.open_stereo_source``), or a source already
    opened (``video.StereoSource``; the config's range and step are applied to it); rig:
    ``calib.rig.StereoRig``; clock: the run's ``Stopwatch``; calib_path: the calibration file (messages).
    Raises StageError when the selected range holds fewer than ``config.min_frames`` frames.
    """
    c = config
    with clock.stage("open"):
        if isinstance(source_path, StereoSource):   # opened by the caller (the run's recording checks): not again
            source = source_path.select(c.frame_range, c.step, c.fps, c.max_consecutive_bad)
        else:
            source = open_stereo_source(source_path, c.frame_range, c.step, c.fps, c.max_consecutive_bad)
        rig = fit_rig(source, rig, c, calib_path)
        rect = rig.rectification(alpha=0.0)
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
        gt_traj.T_wc = gt_traj.T_wc @ rot4(rect.R1.T)
    return Setup(source, rig, rect, depth_max_m, dcfg, fcfg, mode, gt_traj)
