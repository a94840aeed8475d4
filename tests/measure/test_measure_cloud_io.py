"""Reading clouds (PLY, PCD, XYZ, PTS) and the point-resolution estimate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure.cloud_io import read_cloud
from stereo_recon.core.cloud_io import write_cloud
from measure.kde import binned_kde, local_maxima
from measure.resolution import lattice_dither, point_lattice, point_resolution
from stereo_recon.core.errors import InputError


@pytest.mark.parametrize("suffix", [".ply", ".pcd", ".xyz"])
def test_round_trip(tmp_path, suffix):
    pts = np.random.default_rng(0).random((300, 3)) * 10
    write_cloud(tmp_path / f"c{suffix}", pts)
    back = read_cloud(tmp_path / f"c{suffix}")
    tol = 1e-6 if suffix != ".xyz" else 1e-5
    np.testing.assert_allclose(back, pts, atol=tol)


def test_pts_with_and_without_count_line(tmp_path):
    pts = np.random.default_rng(1).random((200, 3))
    extra = np.c_[pts, np.full((200, 1), 7), np.zeros((200, 3))]   # intensity, rgb
    np.savetxt(tmp_path / "a.pts", extra, header="200", comments="")
    np.savetxt(tmp_path / "b.pts", extra)
    np.testing.assert_allclose(read_cloud(tmp_path / "a.pts"), pts, atol=1e-12)
    np.testing.assert_allclose(read_cloud(tmp_path / "b.pts"), pts, atol=1e-12)


def test_bad_files(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_cloud(tmp_path / "missing.ply")
    with pytest.raises(InputError, match="not a file"):
        read_cloud(tmp_path)
    (tmp_path / "x.las").write_text("1 2 3\n")
    with pytest.raises(InputError, match="unsupported"):
        read_cloud(tmp_path / "x.las")
    (tmp_path / "e.pcd").write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_cloud(tmp_path / "e.pcd")
    inf = np.random.default_rng(0).random((200, 3))
    inf[3, 0] = np.inf
    np.savetxt(tmp_path / "inf.xyz", inf)
    with pytest.raises(InputError, match="NaN or infinite"):
        read_cloud(tmp_path / "inf.xyz")
    (tmp_path / "bad.pts").write_text("hello world\nfoo bar baz\n")
    with pytest.raises(InputError, match="bad.pts"):
        read_cloud(tmp_path / "bad.pts")


def test_resolution_of_a_regular_grid():
    g = np.stack(np.meshgrid(np.arange(100), np.arange(100), [0.0], indexing="ij"), -1).reshape(-1, 3) * 0.02
    assert point_resolution(g) == pytest.approx(0.02, rel=1e-9)
    # Seeded and independent of the order of points.
    perm = np.random.default_rng(3).permutation(len(g))
    assert point_resolution(g[perm], sample_size=500, rng=1) == pytest.approx(0.02, rel=1e-9)


def _on_lattice(rng, n: int, voxel_m: float) -> np.ndarray:
    """Points of a slanted plane as a TSDF gives them: zero crossings along the voxel edges, two of each point's
    three coordinates on the voxel grid's planes, the third wherever the surface crosses that edge."""
    p = rng.uniform(0.0, 1.0, (n, 3))
    p[:, 2] = 0.3 * p[:, 0] + 0.2 * p[:, 1]
    on = np.round(p / voxel_m) * voxel_m
    free = rng.integers(0, 3, n)
    on[np.arange(n), free] = p[np.arange(n), free]
    return on


def test_lattice_of_a_fused_cloud_and_of_a_raw_one():
    """A fused cloud's points sit on its voxel grid: the spacing is read back from the coordinates many points
    hold exactly; a raw cloud, or the fused one turned so that every coordinate mixes all three, sits on none."""
    rng = np.random.default_rng(0)
    pts = _on_lattice(rng, 50_000, 0.0036)
    assert point_lattice(pts) == pytest.approx(0.0036, rel=1e-9)
    assert point_lattice(pts.astype(np.float32)) == pytest.approx(0.0036, rel=1e-6)   # as a PLY stores it
    assert point_lattice(pts + rng.normal(0.0, 1e-4, pts.shape)) is None
    # Turned so that each coordinate mixes all three (a ground-aligned frame's: the free one moves them all).
    turned = pts @ Rotation.from_rotvec([0.2, -0.3, 0.4]).as_matrix().T
    assert point_lattice(turned) is None


def test_lattice_dither_fills_the_comb_a_fused_surface_makes():
    """A fused surface lying along an axis projects onto it as a comb, one tooth per voxel: a density read at a
    fifth of the voxel (the width's bandwidth at its floor) peaks on every tooth. Dithered, only the lattice
    coordinates move (within half a step, the crossing's own coordinate stays), the teeth are gone, and the
    same seed gives the same dither."""
    v = 0.0036
    rng = np.random.default_rng(3)
    pts = _on_lattice(rng, 60_000, v)
    # A face off the planes that many crossings share exactly (a wall 1/3 step from them): not a lattice value.
    wall = np.column_stack([np.full(500, 0.5 + v / 3), rng.uniform(0, 1, 500), rng.uniform(0, 1, 500)])
    pts = np.vstack([pts, wall])
    d = lattice_dither(pts, v, rng=7)
    assert np.array_equal(d, lattice_dither(pts, v, rng=7))
    assert np.abs(d).max() <= v / 2
    on = np.abs(pts / v - np.round(pts / v)) < 1e-9
    assert np.all(d[~on] == 0.0)                                # the crossings' coordinates and the wall stay
    assert np.mean(d[on] != 0.0) > 0.999
    assert np.all(d[-500:, 0] == 0.0)
    # Where the surface lies along x (the points whose free coordinate is z): the comb, and then none.
    flat = ~on[:, 2] & on[:, 0]
    x = pts[flat, 0]
    interior = lambda dens: (dens.grid_m > 0.2) & (dens.grid_m < 0.8)
    before = binned_kde(x, bandwidth_m=0.2 * v, step_m=v / 40)
    after = binned_kde(x + d[flat, 0], bandwidth_m=0.2 * v, step_m=v / 40)
    peaks = lambda dens: int(np.sum(interior(dens)[local_maxima(dens.density)]))
    assert peaks(before) >= 0.9 * 0.6 / v                      # a peak on every plane
    ripple = lambda dens: np.std(dens.density[interior(dens)]) / np.mean(dens.density[interior(dens)])
    # Against as many points drawn uniformly, unquantised (their ripple is the sampling noise alone, 0.14 here).
    ref = ripple(binned_kde(rng.uniform(0, 1, len(x)), bandwidth_m=0.2 * v, step_m=v / 40))
    assert ripple(before) > 3 * ref and ripple(after) < 1.2 * ref
    # A raw cloud has no lattice values: nothing moves.
    raw = rng.uniform(0, 1, (5000, 3))
    assert not np.any(lattice_dither(raw, v, rng=0))
