"""Scale-free depth limits: a truck 25-40 m away (a full-scale orbit at 2 x its length) is matched and fused."""

from __future__ import annotations

import numpy as np
import pytest

from stereo_recon.disparity import depth_from_disparity, disparity_range_for_depth
from stereo_recon.odometry import VOConfig
from stereo_recon.reconstruct import ReconstructConfig, resolved_depth_max_m

F_PX, B_M = 528.0, 0.12   # ZED2 at HD720


def test_default_depth_limit_is_one_pixel_of_disparity():
    far = resolved_depth_max_m(ReconstructConfig(), F_PX, B_M)
    assert far == pytest.approx(F_PX * B_M / 1.0)
    # The SGBM search reaches that far: 2 px of disparity (31.7 m) lies in the range.
    d_min, d_num = disparity_range_for_depth(F_PX, B_M, 0.3, far)
    assert d_min <= 2 < d_min + d_num
    z = depth_from_disparity(np.array([[2.0, 1.5, 0.5]], np.float32), F_PX, B_M, 0.3, far)
    assert np.isfinite(z[0, :2]).all() and np.isnan(z[0, 2])   # 0.5 px (127 m) is beyond the rig
    # An explicit limit still wins, and the VO matcher has no fixed cap either.
    assert resolved_depth_max_m(ReconstructConfig(depth_max_m=10.0), F_PX, B_M) == 10.0
    assert not np.isfinite(VOConfig().max_depth_m)


def test_default_fusion_integrates_a_box_30_m_away(box_on_ground):
    """A 14 x 10 x 6 m box seen from a 30 m orbit is fused with the default (uncapped) depth range."""
    o3d = pytest.importorskip("open3d")
    from stereo_recon.fusion import FusionConfig, TSDFFusion
    from stereo_recon.synthetic.flight import look_at

    w, h, s = 320, 240, 12.0
    K = np.array([[300.0, 0, 160.0], [0, 300.0, 120.0], [0, 0, 1.0]])
    box_max = s * np.array([0.6013, 0.4021, 0.5037])
    scene = box_on_ground(-box_max * [1, 1, 0], box_max, ground_half_m=2.0 * s)
    u, v = np.meshgrid(np.arange(w) + 0.0, np.arange(h) + 0.0)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    fusion = TSDFFusion(FusionConfig(voxel_m=0.02 * s, min_weight=2.0))
    for a in np.linspace(0, 2 * np.pi, 12, endpoint=False):
        T = look_at(s * np.array([2.5 * np.cos(a), 2.5 * np.sin(a), 1.6]), s * np.array([0, 0, 0.25]))
        rays = np.hstack([np.repeat(T[:3, 3][None], len(d), 0), d @ T[:3, :3].T]).astype(np.float32)
        depth = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().reshape(h, w).astype(np.float32)
        depth[~np.isfinite(depth)] = np.nan
        fusion.integrate(np.full((h, w, 3), 128, np.uint8), depth, K, T)
    pts, _ = fusion.extract_cloud()
    top = pts[(np.abs(pts[:, 0]) < 0.6 * box_max[0]) & (np.abs(pts[:, 1]) < 0.6 * box_max[1]) & (pts[:, 2] > 0.5 * box_max[2])]
    assert len(top) > 200                                   # the roof, ~33 m from the cameras, is there
    assert abs(np.median(top[:, 2]) - box_max[2]) < 0.02 * s
