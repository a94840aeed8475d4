"""Every parameter of the reconstruction (``ReconstructConfig``), validated on construction."""

from __future__ import annotations

from dataclasses import dataclass, field

from stereo_recon.core.errors import ConfigError
from stereo_recon.fusion import FusionConfig
from stereo_recon.motion_stereo import MotionStereoConfig
from stereo_recon.views import KeyframeConfig


@dataclass(frozen=True)
class ReconstructConfig:
    """Every parameter of ``reconstruct`` (the CLI maps its options onto these fields)."""

    # Pose back-end: "vo" (stereo visual odometry), "sfm" (pycolmap), or "gt:PATH" (known TUM trajectory).
    poses: str = "vo"
    # Half-open frame range (start, stop) of the source; None = all. step: every step-th frame.
    frame_range: tuple[int, int | None] | None = None
    step: int = 1
    # Override the video's frame rate (timestamps = index / fps).
    fps: float | None = None
    # Frames are already rectified (ZED SDK exports are): skip rectification. None = as the rig says.
    rectified: bool | None = None
    # Depth range (m): sets the SGBM disparity range and what is fused. depth_max_m None = derived from
    # the rig: the depth of ``min_disparity_px`` of disparity (f*B/1 px: 63 m for a ZED2 at HD720). Why not a
    # fixed 20 m: a full-scale truck flown at 2 x its length is 25-40 m away; a fixed cap left nothing of it
    # (a random envelope draw at 21 m radius fused 126 points). The fused region is bounded by
    # fusion_depth_max_rel instead, which follows the scene.
    depth_min_m: float = 0.3
    depth_max_m: float | None = None
    min_disparity_px: float = 1.0
    # Disparity preset ("fast", "balanced", "quality", "wls") and field overrides (disparity range is derived).
    disparity_preset: str = "balanced"
    disparity_overrides: dict = field(default_factory=dict)
    # Upper bound of the SGBM disparity search (px); the near depth limit is raised to fit.
    max_num_disparities: int = 256
    # Gaps wider than this (px) stay holes: background filling is right for occlusions, not for wide untextured areas.
    fill_max_px: int | None = 32
    # Keyframes (fused, and the images given to SfM) by image motion, for sfm (vo and gt: by pose, below);
    # None = every processed frame is fused, whatever the back-end.
    # 6 % of the width between keyframes: on the 120-frame synthetic HD720 orbit, 23 keyframes gave the
    # same truck accuracy (0.27 % of L) and coverage (99.5 %) as 43 at 3 %, with 30 % less fusion time.
    keyframes: KeyframeConfig | None = KeyframeConfig(min_flow_frac=0.06, max_gap_frames=20)
    # Fusion views by pose (vo and gt back-ends, whose poses are known while streaming; sfm uses
    # ``keyframes``): a frame is fused when the camera turned by fuse_rotation_deg, or moved by
    # fuse_translation_rel x the median depth of the last fused view, since the last fused view.
    # SGBM runs on these frames only; VO matches its corners sparsely in the right image instead.
    # An orbit needs 16-24 views for full coverage; 18 deg gives 20 on a full circle. fuse_by_pose False:
    # image-motion keyframes (``keyframes``) for every back-end.
    fuse_by_pose: bool = True
    fuse_rotation_deg: float = 18.0
    fuse_translation_rel: float = 0.4
    # Feed VO with dense SGBM depth of every frame (the slow path: SGBM on every frame) instead of
    # sparse stereo at its keyframes.
    vo_dense_depth: bool = False
    # Integrate every n-th pixel of depth and colour (K scaled accordingly), n the largest integer
    # keeping at least this width (HD720: n = 2; VGA: 1); None = full resolution. The voxel (2 px
    # footprints at full resolution) stays the same.
    fusion_min_width_px: int | None = 640
    # Fused depth is cut at this multiple of the median depth of the fused views (the region of
    # interest around the object; far ground costs blocks and adds Z^2 noise); None = depth_max_m only.
    fusion_depth_max_rel: float | None = 2.0
    # Geometric consistency before fusion (as MVS fusion does): a depth pixel is fused only when at
    # least ``consistency_min_views`` of the ``consistency_views`` nearest fused views (by camera
    # position) see the same point within ``consistency_rel_tol`` x depth. None = fuse every pixel
    # (the default: on the sample truck it brings the side walls' median to within 1 mm of the truth
    # but keeps only 10-50 % of their points, so the cab, not the box, then sets the width).
    consistency_views: int | None = None
    consistency_min_views: int = 1
    consistency_rel_tol: float = 0.01
    # Motion stereo (``motion_stereo``): each fusion view is also matched with a later frame about
    # 0.11 x the scene depth away, that wide-baseline depth is fused instead of the rig's, and VO's
    # trajectory is rescaled to the rig's depth. Needs poses while streaming (vo and gt back-ends).
    # None = only for far scenes (below). Forced on for the 20 model trucks (``bench --motion-stereo``)
    # their widths got worse (2.42 % mean error instead of 1.35 %: the narrow walls come out 1-2 mm
    # inside), heights better (0.17 % instead of 0.48 %).
    motion_stereo: MotionStereoConfig | None = None
    # Far scenes: when the first view's median depth exceeds this many rig baselines, the run uses
    # motion stereo (the default config unless motion_stereo is set) and feeds VO the dense depth of
    # every frame (sparse stereo on 5-8 px of disparity left VO's scale 0.28 % short, dense 0.18 %).
    # vo and gt back-ends; None = never. Why depth in baselines: the wide pair's disparity over the
    # rig's is baseline_rel x Z / B whatever the resolution, so the switch does not move with it
    # (14.2 baselines = 36.6 px of rig disparity at HD720's 520 px focal, 18 px at VGA).
    # Why 14.2: it lies between two tuning sets. Table 2's close orbits (first views at 7.8-14.0
    # baselines, 37-67 px) measured better on the rig (motion stereo forced on: widths 2.42 % instead
    # of 1.35 %); 38 model-scale random draws of tuning seeds 2027-2029 flown wider (14.6-38.6 baselines),
    # re-run with motion stereo, went from 13 "no ground plane" refusals to 1 (and 1 "no truck"), their
    # mean error from 7.2 % to 2.8 % and their heights from 8.9 % (bias -8.9 %: a plain roof seen at
    # 14-30 deg sits ~1 px of disparity towards the background, 10 cm too far at 2.3 m) to 2.8 %
    # (docs/ROUNDS.md, issue 12's fourth round). Full scale
    # (8-15 m, 60-120 baselines) always switches: the two rendered presets' widths -0.97 % / -3.04 %,
    # lengths and heights within 0.14 %, instead of +2.85 % / -3.56 % and 0.5-0.8 % on the rig's depth.
    far_scene_depth_baselines: float | None = 14.2
    # Bundle-adjusted poses for the fused views (vo back-end): pycolmap SfM on the fused views and
    # their motion-stereo partners, grafted onto VO's trajectory by a similarity (``graft_poses``).
    # Why: at full scale VO's rotations wander by 0.43 deg rms (over-height preset) in step with
    # its sideways position, which puts points 10 m away several cm off and skews the wide pairs;
    # grafted, the trajectory is within 0.065 deg rms (ATE 60 -> 12 mm; width -3.03 -> -1.03 %
    # before the finer voxel), for ~25 s of SfM (one thread) on 35 HD720 images. None = with motion stereo (far
    # scenes) only; if SfM fails, VO's poses are kept (logged, counts["sfm_refine"]).
    refine_poses_sfm: bool | None = None
    # SfM's poses are kept as a refinement of VO's while, after the similarity, they lie within
    # refine_max_move_rel of the path's rms radius and refine_max_turn_deg of VO's (medians over the views).
    # Beyond, SfM has found another solution and one of the two is wrong (SfM another orbit on a full-scale
    # tanker: 0.50 and 35 deg; VO broken on another: 0.38 and 18 deg): the poses under which consecutive views'
    # depth maps agree better are kept (``sfm.refine_with_sfm``; counts["sfm_refine"]["rejected"] or
    # ["kept_over_odometry"]). Where SfM was right on tuning seed 2079 (35 runs), VO lay up to 0.10 of the
    # radius (a 17 m box flown 20 m out) and 8.0 deg (a 17 m semi-trailer 30 m out) from it: a magnitude alone
    # cannot say which of the two is wrong, so the bounds stay wide and only beyond them the depth decides.
    refine_max_move_rel: float = 0.2
    refine_max_turn_deg: float = 20.0
    # TSDF settings; voxel_m None = derived from the first keyframe's depth.
    fusion: FusionConfig = FusionConfig()
    voxel_m: float | None = None
    # Also write mesh.ply.
    mesh: bool = False
    # Rectification and back-projection on a CUDA device through torch/kornia (stereo_recon.gpu).
    gpu: bool = False
    # Fewer processed frames (or posed frames) than this is an error.
    min_frames: int = 3
    # Keep the work folder (keyframe images and depth maps, SfM database) in the output as work/.
    keep_work: bool = False
    # Undecodable frames in a row that end the video.
    max_consecutive_bad: int = 10

    def __post_init__(self) -> None:
        if not (self.poses in ("vo", "sfm") or self.poses.startswith("gt:")):
            raise ConfigError(f"--poses {self.poses!r}: expected vo, sfm or gt:PATH (a TUM trajectory)")
        if not 0 < self.depth_min_m or (self.depth_max_m is not None and not self.depth_min_m < self.depth_max_m):
            raise ConfigError(f"depth range [{self.depth_min_m}, {self.depth_max_m}] m: need 0 < min < max")
        if not self.min_disparity_px > 0:
            raise ConfigError(f"min_disparity_px={self.min_disparity_px}: must be > 0")
        if self.step < 1:
            raise ConfigError(f"--step {self.step}: must be >= 1")
        if self.voxel_m is not None and not self.voxel_m > 0:
            raise ConfigError(f"--voxel-m {self.voxel_m}: must be > 0")
        if not (self.fuse_rotation_deg > 0 and self.fuse_translation_rel > 0):
            raise ConfigError("fuse_rotation_deg and fuse_translation_rel must be > 0")
        if self.fusion_min_width_px is not None and self.fusion_min_width_px < 16:
            raise ConfigError(f"fusion_min_width_px={self.fusion_min_width_px}: must be >= 16 or None")
        if self.fusion_depth_max_rel is not None and not self.fusion_depth_max_rel > 1.0:
            raise ConfigError(f"fusion_depth_max_rel={self.fusion_depth_max_rel}: must be > 1 or None")
        if self.far_scene_depth_baselines is not None and not self.far_scene_depth_baselines > 0:
            raise ConfigError(f"--far-scene-baselines {self.far_scene_depth_baselines}: must be > 0 (or off)")
        if self.refine_poses_sfm and self.poses != "vo":
            raise ConfigError(f"--refine-poses on: bundle adjustment refines visual odometry's poses (--poses vo), "
                              f"not --poses {self.poses}")
        if not (self.refine_max_move_rel > 0 and self.refine_max_turn_deg > 0):
            raise ConfigError(f"refine_max_move_rel={self.refine_max_move_rel}, refine_max_turn_deg="
                              f"{self.refine_max_turn_deg}: must be > 0")
        if self.motion_stereo is not None and (self.poses == "sfm" or not self.fuse_by_pose or self.keyframes is None):
            raise ConfigError("motion stereo needs poses while streaming and views chosen by pose: --poses vo or "
                              "gt:PATH, without --all-frames")
        if self.consistency_views is not None and not (
                self.consistency_views >= 1 and 1 <= self.consistency_min_views <= self.consistency_views
                and self.consistency_rel_tol > 0):
            raise ConfigError(f"consistency: need views >= 1, 1 <= min_views <= views, rel_tol > 0 (got "
                              f"{self.consistency_views}, {self.consistency_min_views}, {self.consistency_rel_tol})")


def resolved_depth_max_m(config: ReconstructConfig, focal_px: float, baseline_m: float) -> float:
    """Farthest depth matched and fused (m): ``config.depth_max_m``, or the depth of ``config.min_disparity_px``
    of disparity for this rig (focal_px, px; baseline_m, m) when it is None."""
    if config.depth_max_m is not None:
        return float(config.depth_max_m)
    return float(max(focal_px * baseline_m / config.min_disparity_px, 1.01 * config.depth_min_m))
