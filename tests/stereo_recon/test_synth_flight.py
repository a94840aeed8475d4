"""Synthetic flights (orbit, straight pass), truck construction and texture helpers."""

from __future__ import annotations

import numpy as np
import pytest

from stereo_recon.synthetic.flight import OrbitConfig, PassConfig, look_at, orbit_poses, pass_poses
from stereo_recon.synthetic.mesh import pose, rot_z
from stereo_recon.synthetic.presets import TABLE2_STANDARD_M, get_preset, preset_names
from stereo_recon.synthetic.scene import BODY_TYPES, TruckSpec, truck_mesh
from stereo_recon.synthetic.texture import noise_tile


def test_look_at_gives_opencv_axes():
    T = look_at((0.0, 0.0, 1.0), (5.0, 0.0, 1.0))  # looking along +x, world z up
    R = T[:3, :3]
    np.testing.assert_allclose(R[:, 2], [1, 0, 0], atol=1e-12)  # optical axis
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)  # image y points down
    np.testing.assert_allclose(R[:, 0], [0, -1, 0], atol=1e-12)  # image x points right
    assert np.isclose(np.linalg.det(R), 1.0)


def test_orbit_circles_the_centre_at_the_altitude_with_small_jitter():
    cfg = OrbitConfig(radius_m=1.7, altitude_m=1.0, jitter_deg=0.6, position_jitter_m=0.01)
    T = orbit_poses(48, (0.3, -0.2), cfg, rng=1)
    c = T[:, :3, 3]
    r = np.hypot(c[:, 0] - 0.3, c[:, 1] + 0.2)
    assert np.abs(r - 1.7).max() < 0.05 and np.abs(c[:, 2] - 1.0).max() < 0.05
    ang = np.unwrap(np.arctan2(c[:, 1] + 0.2, c[:, 0] - 0.3))
    assert abs(abs(ang[-1] - ang[0]) - 2 * np.pi * 47 / 48) < 0.05  # a full turn without repeating frame 0
    target = np.array([0.3, -0.2, cfg.look_height_m])
    to_t = (target - c) / np.linalg.norm(target - c, axis=1)[:, None]
    off_deg = np.rad2deg(np.arccos(np.clip(np.einsum("ij,ij->i", T[:, :3, 2], to_t), -1, 1)))
    assert 0.05 < off_deg.max() < 4.0  # jitter present but small
    T_still = orbit_poses(8, (0, 0), OrbitConfig(jitter_deg=0.0, position_jitter_m=0.0), rng=1)
    for Ti in T_still:
        np.testing.assert_allclose(Ti[:3, :3] @ Ti[:3, :3].T, np.eye(3), atol=1e-12)


def test_orbit_is_reproducible_from_the_seed():
    a = orbit_poses(10, (0, 0), rng=3)
    assert np.array_equal(a, orbit_poses(10, (0, 0), rng=3)) and not np.array_equal(a, orbit_poses(10, (0, 0), rng=4))


def test_straight_pass_runs_parallel_to_the_truck():
    T_wt = pose(rot_z(np.deg2rad(30)), (1.0, 2.0, 0.0))
    T = pass_poses(20, T_wt, PassConfig(offset_m=1.5, altitude_m=1.0, extent_m=1.6, position_jitter_m=0.0), rng=0)
    q = (T[:, :3, 3] - T_wt[:3, 3]) @ T_wt[:3, :3]  # camera centres in the truck frame
    np.testing.assert_allclose(q[:, 1], 1.5, atol=1e-9)
    np.testing.assert_allclose(q[:, 2], 1.0, atol=1e-9)
    np.testing.assert_allclose(q[[0, -1], 0], [-1.6, 1.6], atol=1e-9)


@pytest.mark.parametrize("body", BODY_TYPES)
@pytest.mark.parametrize("dims", [(2.1, 0.38, 0.38), (12.0, 2.55, 4.0), (1.065, 0.182, 0.323), (16.5, 2.5, 4.3)])
def test_truck_mesh_has_exact_outer_dimensions(body, dims):
    L, W, H = dims
    m = truck_mesh(TruckSpec(L, W, H, body))
    lo, hi = m.bounds()
    np.testing.assert_allclose(lo, [-L / 2, -W / 2, 0.0], atol=1e-12)
    np.testing.assert_allclose(hi, [L / 2, W / 2, H], atol=1e-12)
    assert len(m.materials) == len(m.triangles) and {"truck.tyre", "truck.cab"} <= set(m.materials)


def test_truck_spec_rejects_nonsense():
    with pytest.raises(ValueError):
        TruckSpec(2.0, 0.4, 0.4, "bus")
    with pytest.raises(ValueError):
        TruckSpec(0.5, 0.4, 0.4)


def test_all_presets_resolve():
    names = preset_names()
    assert len(names) == 25
    for n in names:
        p = get_preset(n)
        if p.kind == "truck":
            assert p.truck.length_m > p.truck.width_m and p.texel_m > 0
    assert [get_preset(f"table2:{i}").truck.width_m for i in range(1, 21)] == [s[1] for s in TABLE2_STANDARD_M]


def test_noise_tile_is_periodic_band_limited_unit_noise():
    t = noise_tile(0.6, 11).astype(np.float64) / 4096.0
    assert abs(t.mean()) < 0.01 and abs(t.std() - 1.0) < 0.01
    # Periodic: the wrap-around step is as smooth as an interior step.
    assert np.abs(t[0] - t[-1]).mean() < 1.5 * np.abs(np.diff(t, axis=0)).mean()
    # Band-limited: little energy at the Nyquist frequency (no pixel-level aliasing).
    spec = np.abs(np.fft.fft2(t)) ** 2
    f = np.fft.fftfreq(t.shape[0])
    fr = np.hypot(f[:, None], f[None, :])
    assert spec[fr > 0.4].sum() < 1e-3 * spec.sum()
