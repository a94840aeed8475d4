"""Reading clouds (PLY, PCD, XYZ, PTS) and the point-resolution estimate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure.cloud_io import read_cloud
from stereo_recon.core.cloud_io import write_cloud
from measure.resolution import point_lattice, point_resolution
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
