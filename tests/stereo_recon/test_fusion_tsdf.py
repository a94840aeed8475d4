"""TSDF fusion against analytic geometry: a box on a ground plane rendered with Open3D's RaycastingScene."""

from __future__ import annotations

import numpy as np
import pytest

o3d = pytest.importorskip("open3d")

from stereo_recon.core.errors import ConfigError, StageError  # noqa: E402
from stereo_recon.fusion import FusionConfig, TSDFFusion, estimate_block_count, voxel_size_from_depth  # noqa: E402
from stereo_recon.synthetic.flight import look_at  # noqa: E402

W, H = 320, 240
K = np.array([[300.0, 0, 160.0], [0, 300.0, 120.0], [0, 0, 1.0]])
# Box 1.2 x 0.8 x 0.5 m (not aligned with any voxel grid, so no exact zero crossings), ground z=0.
BOX_MIN = np.array([-0.6013, -0.4021, 0.0])
BOX_MAX = np.array([0.6013, 0.4021, 0.5037])


def _render(scene, T_wc):
    u, v = np.meshgrid(np.arange(W) + 0.0, np.arange(H) + 0.0)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    dw = d @ T_wc[:3, :3].T
    rays = np.hstack([np.repeat(T_wc[:3, 3][None], len(dw), 0), dw]).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().reshape(H, W)
    depth = t.astype(np.float32)  # t along un-normalised ray with z=1 in camera = depth
    depth[~np.isfinite(depth)] = np.nan
    return depth


def _orbit(n=12, radius=2.5, height=1.6):
    return [look_at(np.array([radius * np.cos(a), radius * np.sin(a), height]), np.array([0, 0, 0.25]))
            for a in np.linspace(0, 2 * np.pi, n, endpoint=False)]


def _box_distance(p):
    """Distance of points to the box surface (outside or inside)."""
    c = (BOX_MIN + BOX_MAX) / 2
    h = (BOX_MAX - BOX_MIN) / 2
    q = np.abs(p - c) - h
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    inside = np.minimum(q.max(axis=1), 0)
    return outside + np.abs(inside)


def test_the_fused_cloud_sits_on_its_voxel_grid(box_on_ground):
    """The measure reads the lattice back from the cloud alone (``measure.resolution.point_lattice``, recorded in
    a measurement's parameters): it is the fusion's voxel."""
    from measure.resolution import point_lattice

    scene = box_on_ground(BOX_MIN, BOX_MAX, ground_half_m=2.0)
    fusion = TSDFFusion(FusionConfig(voxel_m=0.02, depth_max_m=4.0, min_weight=2.0, block_count=64))
    colour = np.full((H, W, 3), (30, 120, 200), np.uint8)
    for T in _orbit(6):
        fusion.integrate(colour, _render(scene, T), K, T)
    pts, _ = fusion.extract_cloud()
    assert point_lattice(pts.astype(np.float32)) == pytest.approx(0.02, rel=1e-5)


def test_fused_box_points_lie_on_true_surface(box_on_ground):
    scene = box_on_ground(BOX_MIN, BOX_MAX, ground_half_m=2.0)
    voxel = 0.02
    fusion = TSDFFusion(FusionConfig(voxel_m=voxel, depth_max_m=4.0, min_weight=2.0, block_count=64))
    colour = np.full((H, W, 3), (30, 120, 200), np.uint8)  # BGR
    for T in _orbit():
        fusion.integrate(colour, _render(scene, T), K, T)
    pts, rgb = fusion.extract_cloud()
    assert len(pts) > 5000
    # Distance of each point to the scene (box + ground), from the ray-casting scene itself.
    dist = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    assert np.median(dist) < 0.25 * voxel
    assert np.quantile(dist, 0.95) < 1.0 * voxel
    # The box's top is recovered at its true height (within a voxel).
    top = pts[(np.abs(pts[:, 0]) < 0.4) & (np.abs(pts[:, 1]) < 0.25) & (pts[:, 2] > 0.25)]
    assert len(top) > 200
    assert abs(np.median(top[:, 2]) - BOX_MAX[2]) < voxel
    on_box = _box_distance(pts) < voxel
    assert on_box.sum() > 1000
    # Colour survives (BGR in -> RGB out).
    assert np.allclose(np.median(rgb, axis=0), np.array([200, 120, 30]) / 255.0, atol=0.02)
    # The grid grew from a deliberately tiny initial capacity instead of crashing.
    assert fusion.stats.grow_events >= 1
    assert fusion.stats.blocks_allocated <= fusion.stats.capacity_blocks
    mesh = fusion.extract_mesh()
    assert len(mesh.triangles) > 1000


def test_refuses_clearly_beyond_memory_budget(box_on_ground):
    scene = box_on_ground(BOX_MIN, BOX_MAX, ground_half_m=2.0)
    T = _orbit(1)[0]
    fusion = TSDFFusion(FusionConfig(voxel_m=0.004, depth_max_m=4.0, max_memory_gib=0.01))
    with pytest.raises(StageError, match="fusion: .*--voxel-m"):
        fusion.integrate(np.zeros((H, W, 3), np.uint8), _render(scene, T), K, T)


def test_roi_excludes_ground_and_derived_voxel(box_on_ground):
    scene = box_on_ground(BOX_MIN, BOX_MAX, ground_half_m=2.0)
    T = _orbit(1)[0]
    depth = _render(scene, T)
    v = voxel_size_from_depth(depth, K[0, 0], footprint_px=2.0)
    assert v == pytest.approx(2.0 * np.nanmedian(depth) / K[0, 0])
    cfg = FusionConfig(voxel_footprint_px=2.0, depth_max_m=4.0, min_weight=0.5,
                       roi_min_m=(-1.0, -1.0, 0.05), roi_max_m=(1.0, 1.0, 1.0))
    fusion = TSDFFusion(cfg)
    fusion.integrate(np.zeros((H, W, 3), np.uint8), depth, K, T)
    # Derived from the depth inside the ROI (the box, slightly nearer than the whole view's median).
    assert 0.8 * v < fusion.voxel_m < 1.05 * v
    pts, _ = fusion.extract_cloud()
    assert len(pts) > 100
    # Nothing from the ground far outside the box (ROI in x/y of +-1 m, plus the truncation band).
    assert np.all(np.abs(pts[:, :2]) < 1.0 + 10 * v)
    assert estimate_block_count(depth, K, v) > 0


def test_bad_config_and_empty_volume():
    with pytest.raises(ConfigError):
        FusionConfig(depth_min_m=5.0, depth_max_m=1.0)
    f = TSDFFusion(FusionConfig(voxel_m=0.05))
    assert f.integrate(np.zeros((H, W, 3), np.uint8), np.full((H, W), np.nan, np.float32), K, np.eye(4)) == 0
    with pytest.raises(StageError, match="no frame"):
        f.extract_cloud()


def test_extracted_points_have_one_order_whatever_order_the_threads_give():
    """Neighbouring voxel blocks can emit two points at the same position whose normals differ in the last
    bits; sorted by position alone, their order was the threads' (a Ray worker's cloud.ply differed from a
    local worker's by two swapped points). Sorting by position, normal and colour gives one order."""
    from stereo_recon.fusion import canonical_order

    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (500, 3))
    pts[250:] = pts[:250]                                     # every position twice
    nrm = rng.normal(size=(500, 3))
    nrm[250:] = nrm[:250] + rng.normal(0, 1e-8, (250, 3))     # normals apart in the last bits
    cols = rng.uniform(0, 1, (500, 3))
    want = None
    for seed in range(3):
        perm = np.random.default_rng(seed).permutation(500)
        o = canonical_order(pts[perm], nrm[perm], cols[perm])
        got = np.hstack([pts[perm][o], nrm[perm][o], cols[perm][o]])
        if want is None:
            want = got
        assert np.array_equal(got, want)
    assert np.all(np.diff(want[:, 0]) >= 0)
