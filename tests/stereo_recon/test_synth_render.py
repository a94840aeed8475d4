"""The synthetic renderer: rays hit where the geometry says; rectified disparity of a plane is f*B/Z."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereo_recon.synthetic.camera import pixel_rays, project_points, zed2_rig
from stereo_recon.synthetic.flight import orbit_poses
from stereo_recon.synthetic.presets import get_preset
from stereo_recon.synthetic.render import RenderConfig, StereoRenderer
from stereo_recon.synthetic.scene import TruckSpec, truck_scene


def test_pixel_rays_invert_the_distortion_exactly():
    rig = zed2_rig("VGA")
    rays = pixel_rays(rig.K1, rig.D1, rig.image_size)
    w, h = rig.image_size
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    # Project the ray points with OpenCV's own model: they must land on their pixel centres.
    uv, _ = cv2.projectPoints(rays.astype(np.float64) * 3.0, np.zeros(3), np.zeros(3), rig.K1, rig.D1)
    err = np.abs(uv.reshape(-1, 2) - np.c_[u.ravel(), v.ravel()])
    assert err.max() < 1e-3  # float32 rays; exact up to rounding
    # The distortion is not negligible: ignoring it would move border pixels by pixels.
    pin = rays[:, :2] * [rig.K1[0, 0], rig.K1[1, 1]] + rig.K1[:2, 2]
    assert np.abs(pin - np.c_[u.ravel(), v.ravel()]).max() > 2.0


@pytest.fixture(scope="module")
def truck_render():
    spec = TruckSpec(2.1, 0.38, 0.38, "box")
    yaw = np.deg2rad(25.0)
    scene = truck_scene(spec, truck_yaw_rad=yaw, n_distractors=3, texel_m=0.002, rng=1)
    rig = zed2_rig("VGA")
    T_wc = orbit_poses(8, (0.0, 0.0), get_preset("model-truck").orbit, rng=3)[1]
    pair = StereoRenderer(scene, rig, RenderConfig(noise_sigma_dn=0.0)).render(T_wc)
    return spec, scene, rig, T_wc, pair


def test_rays_hit_the_truck_top_and_the_ground_where_the_geometry_says(truck_render):
    spec, scene, rig, T_wc, pair = truck_render
    T_wt = scene.info["truck_T_world"]
    rays = pixel_rays(rig.K1, rig.D1, rig.image_size).astype(np.float64)
    d_w = rays @ T_wc[:3, :3].T  # world directions, z-depth parametrisation
    o = T_wc[:3, 3]
    depth = pair.depth_left_m.ravel()
    # Analytic hit with the top plane z = H over the rear half (the cargo box roof; 1 cm margin, truck frame).
    t_top = (spec.height_m - o[2]) / d_w[:, 2]
    p_top = o + t_top[:, None] * d_w
    q = (p_top - T_wt[:3, 3]) @ T_wt[:3, :3]
    top = (t_top > 0) & (q[:, 0] > -spec.length_m / 2 + 0.01) & (q[:, 0] < 0) & (np.abs(q[:, 1]) < spec.width_m / 2 - 0.01)
    assert top.sum() > 500
    np.testing.assert_allclose(depth[top], t_top[top], rtol=1e-5)
    # The pixel of a projected rear top corner (inset 1 cm) sees that corner's depth.
    corner_t = np.array([-spec.length_m / 2 + 0.01, spec.width_m / 2 - 0.01, spec.height_m])
    Xw = T_wt[:3, :3] @ corner_t + T_wt[:3, 3]
    Xc = (Xw - o) @ T_wc[:3, :3]
    uv = project_points(Xc[None], rig.K1, rig.D1)[0]
    u, v = int(round(uv[0])), int(round(uv[1]))
    assert abs(pair.depth_left_m[v, u] - Xc[2]) < 0.01 * Xc[2]
    # Ground pixels far from the truck and distractors hit z = 0.
    t_g = -o[2] / d_w[:, 2]
    p_g = o + t_g[:, None] * d_w
    clear = (t_g > 0) & (np.hypot(p_g[:, 0], p_g[:, 1]) < 3.0) & (np.hypot(p_g[:, 0], p_g[:, 1]) > 1.5)
    for dis in scene.info["distractors"]:
        clear &= np.hypot(p_g[:, 0] - dis["x_m"], p_g[:, 1] - dis["y_m"]) > dis["radius_m"] + 0.6
    visible = clear & (np.abs(depth - t_g) < 1e-3 * t_g)
    assert visible.sum() > 0.8 * clear.sum() > 1000  # the rest is hidden behind the truck


def test_truck_pixels_differ_between_eyes_by_the_stereo_disparity(truck_render):
    spec, scene, rig, T_wc, pair = truck_render
    assert pair.left.shape == (rig.image_size[1], rig.image_size[0], 3) and pair.left.dtype == np.uint8
    assert not np.array_equal(pair.left, pair.right)
    assert 0.05 < np.isinf(pair.depth_left_m).mean() < 0.5  # some sky above the horizon


@pytest.mark.parametrize("rectified", [False, True])
def test_rectified_plane_disparity_is_fB_over_Z(tmp_path, rectified):
    from stereo_recon.synthetic.checks import plane_disparity_check

    # Rectified with the calibration as WRITTEN to disk (.conf in raw mode, rig YAML in rectified mode).
    res = plane_disparity_check("VGA", rectified=rectified, Z_m=1.5, work_dir=tmp_path)
    assert res["windows"] >= 20
    assert abs(res["median_err_px"]) < 0.25
    assert res["p90_abs_err_px"] < 0.25
    assert res["p90_abs_row_px"] < 0.5  # rows align


def test_unrectified_raw_pair_fails_the_plane_check(tmp_path):
    from stereo_recon.synthetic.checks import plane_disparity_check

    # The check can fail: without rectification the raw (distorted, misaligned) pair is off.
    res = plane_disparity_check("VGA", rectified=False, Z_m=1.5, work_dir=tmp_path, rectify=False)
    assert abs(res["median_err_px"]) > 0.25 or res["p90_abs_row_px"] > 0.5
