"""Ground plane (Algorithm 1) against the truth and Open3D's RANSAC segment_plane."""

from __future__ import annotations

import numpy as np
import pytest

from measure.ground import estimate_up, ground_plane, remove_ground
from measure.resolution import point_resolution
from measure.synthetic_cloud import FULL_TRUCK, MODEL_TRUCK, SceneSpec, make_truck_scene


def _angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(np.dot(a, b)) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.slow
@pytest.mark.parametrize("shape,spacing,tilt", [(FULL_TRUCK, 0.08, 12.0), (MODEL_TRUCK, 0.008, 25.0)])
def test_ground_normal_beats_ransac_on_tilted_noisy_ground(shape, spacing, tilt):
    """Noise of 0.6 x spacing, 3% outliers, distractors, >= 40% non-ground points, 3 scenes each."""
    o3d = pytest.importorskip("open3d")
    noise = 0.6 * spacing
    ours, ransac = [], []
    for seed in (1, 2, 3):
        pts, truth = make_truck_scene(shape, SceneSpec(spacing_m=spacing, noise_m=noise, tilt_deg=tilt, outlier_fraction=0.03, ground_margin=0.15,
                                                       distractors=3, camera_frame=True), rng=seed)
        assert np.mean(truth["labels"] != 0) >= 0.4   # at least 40% of the points are not ground
        res = point_resolution(pts)
        xi = 2 * res
        g = ground_plane(pts, xi)                      # no hint: the camera's y axis is NOT assumed
        assert g.normal @ truth["up"] > 0              # oriented up, towards the truck
        ours.append(_angle_deg(g.normal, truth["up"]))
        # The plane's offset: the ground lies at height 0 (within a fraction of the noise).
        assert abs(g.offset + truth["ground_offset"]) < 0.1 * noise
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        o3d.utility.random.seed(seed)
        model, _ = pc.segment_plane(distance_threshold=xi, ransac_n=3, num_iterations=1000)
        ransac.append(_angle_deg(np.asarray(model[:3]), truth["up"]))
    assert max(ours) < 0.5
    assert np.mean(ours) <= np.mean(ransac), (ours, ransac)


def test_up_hint_is_used_and_orients_the_normal():
    pts, truth = make_truck_scene(MODEL_TRUCK, SceneSpec(spacing_m=0.01, tilt_deg=8.0, camera_frame=True), rng=4)
    hint = truth["up"] + np.array([0.05, -0.03, 0.04])   # a rough 'up' from a camera trajectory
    g = ground_plane(pts, 0.02, up_hint=hint)
    assert g.initial_normal_source == "up_hint"
    assert _angle_deg(g.normal, truth["up"]) < 0.05 and g.normal @ truth["up"] > 0
    flipped = ground_plane(pts, 0.02, up_hint=-hint)
    assert flipped.normal @ truth["up"] < 0          # the hint's sign wins


def test_estimate_up_is_not_the_camera_axis():
    pts, truth = make_truck_scene(FULL_TRUCK, SceneSpec(spacing_m=0.1, tilt_deg=30.0, camera_frame=True), rng=5)
    up = estimate_up(pts)
    assert _angle_deg(up, truth["up"]) < 2.0
    assert _angle_deg(truth["up"], [0, -1, 0]) > 25    # the truth is far from the camera's -y


def test_remove_ground_keeps_truck_drops_ground():
    pts, truth = make_truck_scene(MODEL_TRUCK, SceneSpec(spacing_m=0.008, noise_m=0.002, tilt_deg=5.0), rng=6)
    res = point_resolution(pts)
    g = ground_plane(pts, 2 * res)
    keep = remove_ground(pts, g, 3.5 * res)
    lab = truth["labels"]
    assert np.mean(keep[lab == 0]) < 0.001
    h = pts @ truth["up"] - truth["ground_offset"]
    assert np.mean(keep[(lab == 1) & (h > 5 * res)]) > 0.999


def test_a_rough_up_hint_15_degrees_off_still_finds_the_ground():
    pts, truth = make_truck_scene(MODEL_TRUCK, SceneSpec(spacing_m=0.01, noise_m=0.002, tilt_deg=20.0, camera_frame=True), rng=7)
    up = truth["up"]
    side = np.cross(up, [1.0, 0, 0])
    side /= np.linalg.norm(side)
    hint = np.cos(np.deg2rad(15)) * up + np.sin(np.deg2rad(15)) * side
    g = ground_plane(pts, 0.02, up_hint=hint)
    assert _angle_deg(g.normal, up) < 0.05 and g.normal @ up > 0
    assert g.inlier_rate > 0.3



@pytest.mark.parametrize("noise", [0.10, 0.15])
def test_the_hint_as_given_finds_the_ground_where_the_local_normals_lead_off(monkeypatch, noise):
    """Tuning seed 2074/6 (a black tanker over a plain, noisy ground): the local normals near the orbit's up led
    the start 2.8 deg off it and Algorithm 1 found no ground (tau 0.008 in a band of 7 mm), while the orbit's up
    was exact. Here the normals' start is set 3 deg off on a ground 3-5 bands thick: from it the plane stays
    1.5-2.8 deg off with a tau of 0.03-0.06; from the hint as given (``refine_hint=False``, the measure
    pipeline's second try) it is found within 0.1 deg."""
    import measure.ground as ground

    pts, truth = make_truck_scene(FULL_TRUCK, SceneSpec(spacing_m=0.1, noise_m=noise, ground_margin=1.0, camera_frame=True), rng=6)
    up = np.asarray(truth["up"], float)
    axis = np.cross(up, [1.0, 0.0, 0.0])
    axis /= np.linalg.norm(axis)
    led_off = up * np.cos(np.radians(3.0)) + np.cross(axis, up) * np.sin(np.radians(3.0))
    monkeypatch.setattr(ground, "estimate_up", lambda p, rng=None, prior=None: led_off)
    g = ground_plane(pts, 0.03, up_hint=up, refine_hint=False)
    assert g.initial_normal_source == "up_hint_as_given"
    assert _angle_deg(g.normal, up) < 0.1 and g.normal @ up > 0, _angle_deg(g.normal, up)
    led = ground_plane(pts, 0.03, up_hint=up)
    assert led.initial_normal_source == "up_hint"
    assert _angle_deg(led.normal, up) > 1.0 and led.inlier_rate < 0.5 * g.inlier_rate, (_angle_deg(led.normal, up), led.inlier_rate)
