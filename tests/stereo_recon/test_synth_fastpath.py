"""The renderer's shortcuts reproduce the brute-force ray cast: analytic ground outside the object hulls, ground shadow map."""

from __future__ import annotations

import numpy as np
import pytest

from stereo_recon.synthetic.camera import zed2_rig
from stereo_recon.synthetic.flight import OrbitConfig, look_at, orbit_poses
from stereo_recon.synthetic.presets import get_preset
from stereo_recon.synthetic.render import RenderConfig, StereoRenderer
from stereo_recon.synthetic.scene import truck_scene


def _renderer(preset: str, shadows: bool = True) -> tuple[StereoRenderer, list[np.ndarray]]:
    p = get_preset(preset)
    scene = truck_scene(p.truck, truck_yaw_rad=np.deg2rad(p.truck_yaw_deg), texel_m=p.texel_m, n_distractors=p.n_distractors,
                        second_truck=p.second_truck, second_offset_m=p.second_gap_m, rng=0)
    # A low, wide orbit through the distractor ring as well: objects beside and behind the camera plane.
    o = p.orbit
    poses = list(orbit_poses(6, (0.0, 0.0), o, rng=0))
    low = OrbitConfig(radius_m=2.0 * o.radius_m, altitude_m=0.5 * o.altitude_m, look_height_m=o.look_height_m, jitter_deg=2.0,
                      position_jitter_m=o.position_jitter_m, fps=o.fps)
    poses += list(orbit_poses(6, (0.0, 0.0), low, rng=1))
    # Beside the truck's flank looking along it: the truck straddles the camera plane (clipped hull).
    T_wt, t = scene.info["truck_T_world"], p.truck
    eye = T_wt[:3, :3] @ [0.0, 0.8 * t.width_m, 1.2 * t.height_m] + T_wt[:3, 3]
    target = T_wt[:3, :3] @ [t.length_m, 0.5 * t.width_m, 0.3 * t.height_m] + T_wt[:3, 3]
    poses.append(look_at(eye, target))
    return StereoRenderer(scene, zed2_rig("VGA"), RenderConfig(shadows=shadows)), poses


@pytest.mark.parametrize("preset", ["model-truck", "two-vehicles", "full-truck"])
def test_analytic_ground_path_equals_the_full_ray_cast(preset):
    r, poses = _renderer(preset, shadows=False)
    with r:
        for T in poses:
            t, prim, nrm = r.first_hits(T)
            t0, prim0, nrm0 = r.first_hits(T, full_cast=True)
            hit = np.isfinite(t0)
            assert np.array_equal(np.isfinite(t), hit)
            assert 0.02 < (~hit).mean() < 0.6 and hit.mean() > 0.4  # sky and ground both in view
            np.testing.assert_allclose(t[hit], t0[hit], rtol=2e-6)
            # The same surface (material) at every pixel; the triangle may be the other half of the ground quad.
            mat = r._tri_material_ext[np.minimum(prim, r._n_tri)]
            mat0 = r._tri_material_ext[np.minimum(prim0, r._n_tri)]
            assert np.array_equal(mat, mat0)
            np.testing.assert_allclose(np.abs(nrm[hit]), np.abs(nrm0[hit]), atol=1e-5)
            assert (mat0[hit] != r._fast["gid"]).any()  # objects are in view: the check is not vacuous


def test_ground_shadow_map_matches_per_pixel_shadow_rays():
    import open3d as o3d

    r, poses = _renderer("model-truck")
    sm = r.shadow_map
    assert sm is not None and sm.cast_cells < sm.lit.size  # only blocks a shadow can reach were cast
    # The map's rim is sunlit (lookups clamp onto it for the ground outside the map).
    assert (sm.lit[[0, -1], :] == 255).all() and (sm.lit[:, [0, -1]] == 255).all()
    shadowed, wrong, wrong_far = 0, 0, 0
    total = 0
    with r:
        for T in poses[:6]:
            t, prim, _ = r.first_hits(T, full_cast=True)
            ground = r._tri_material_ext[np.minimum(prim, r._n_tri)] == r._fast["gid"]
            rays = r.rays(T)[ground]
            p = rays[:, :3] + rays[:, 3:] * t[ground, None]
            sr = np.empty((len(p), 6), np.float32)
            sr[:, :3] = p
            sr[:, 2] += r._shadow_eps
            sr[:, 3:] = r._sun
            occ = r.raycaster.test_occlusions(o3d.core.Tensor.from_numpy(sr)).numpy().astype(bool)
            lit = sm.lookup(p[:, 0].copy(), p[:, 1].copy())
            shadowed += occ.sum()
            total += len(p)
            bad = (lit < 0.5) != occ
            wrong += bad.sum()
            wrong_far += (bad & ((lit == 0.0) | (lit == 1.0))).sum()  # away from the bilinear edge band
    assert shadowed > 0.01 * total  # the truck's shadow is in view
    assert wrong < 0.01 * shadowed  # disagreement only along the shadow edges
    assert wrong_far < 0.001 * shadowed
