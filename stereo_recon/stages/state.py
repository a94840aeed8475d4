"""The records the reconstruction stages hand to each other, and the run context they share."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from stereo_recon.disparity import DisparityConfig
from stereo_recon.fusion import FusionConfig
from stereo_recon.core.manifest import Stopwatch
from stereo_recon.motion_stereo import MotionStereoConfig

ProgressFn = Callable[[str, int, "int | None"], None]


def rot4(R: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform of a rotation."""
    T = np.eye(4)
    T[:3, :3] = R
    return T


@dataclass
class RunContext:
    """What the stages of one run share: where they write, their stopwatch, progress and manifest counts.

    stage_dir: the output folder being written (complete or untouched, ``staged_output_dir``);
    work: its scratch folder (views' images and depth maps, SfM database); report(stage, done, total);
    counts: the manifest's counts, filled stage by stage.
    """

    stage_dir: Path
    work: Path
    clock: Stopwatch
    report: ProgressFn
    counts: dict


@dataclass(frozen=True)
class Setup:
    """The opened input and the settings derived from its rig (``open_input``).

    source: ``video.StereoSource``; rig: ``calib.rig.StereoRig`` as used (scaled, or rectified input);
    rect: its rectification (alpha 0); depth_max_m: farthest depth matched (m); disparity: SGBM settings
    for [depth_min_m, depth_max_m]; fusion: TSDF settings before planning; mode: "vo", "sfm" or "gt";
    gt: the known trajectory in the rectified left camera (mode "gt"), else None.
    """

    source: object
    rig: object
    rect: object
    depth_max_m: float
    disparity: DisparityConfig
    fusion: FusionConfig
    mode: str
    gt: object = None

    @property
    def K(self) -> np.ndarray:
        """(3, 3) rectified left intrinsics, px."""
        return self.rect.K_rect

    @property
    def focal_px(self) -> float:
        return self.rect.focal_px

    @property
    def baseline_m(self) -> float:
        return self.rect.baseline_m


@dataclass(frozen=True)
class Streamed:
    """What the streaming pass leaves for the later stages (``stream_views``).

    keyframes: frame indices of the fusion views, in order (their rectified left image in work/images,
    depth in work/depth); view_depths_m: median depths (m) of the views, in completion order (NaN-free);
    partners: fusion view -> the later frame it is matched with (motion stereo; image in work/partner);
    motion: motion-stereo settings after the far-scene switch (None = off); vo: the visual odometry
    object to finish (mode "vo"), else None.
    """

    keyframes: tuple[int, ...]
    view_depths_m: tuple[float, ...]
    partners: dict
    motion: MotionStereoConfig | None
    vo: object = None


@dataclass(frozen=True)
class FusionPlan:
    """How the views are fused (``plan_fusion``): TSDF settings (ROI depth cut, voxel) and pixel subsampling n."""

    fusion: FusionConfig
    subsample: int


@dataclass(frozen=True)
class WideDepth:
    """Motion-stereo depth of the paired views (``motion_stereo``), in work/wide/<index>.npz.

    views: indices with a wide-baseline depth; counts: per-pair diagnostics in view order; scale: the
    factor applied to the wide depths together with the trajectory (1 = not rescaled).
    """

    views: frozenset = frozenset()
    counts: tuple = ()
    scale: float = 1.0


@dataclass(frozen=True)
class Cloud:
    """The fused surface (``fuse_views``): points (N, 3) m world frame, colours (N, 3), normals (N, 3).

    mesh: marching-cubes mesh (``mesh=True``) or None; fusion: TSDF settings as used; stats: the fusion's
    counters; voxel_m: voxel edge (m); views: indices of the fused (posed) views.
    """

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    mesh: object
    fusion: FusionConfig
    stats: object
    voxel_m: float
    views: tuple[int, ...]
