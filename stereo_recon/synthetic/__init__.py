"""Synthetic ZED2 drone stereo video with exact ground truth (scene, renderer, flights, presets).

World frame: metres, right-handed, z up, the ground is the plane z = 0. Camera frame: OpenCV
(x right, y down, z forward). Poses: world-from-LEFT-camera (TUM ``poses_gt.txt``).
Truck frame: origin on the ground at the footprint centre, x to the front, y left, z up; the
truck spans exactly x in [-L/2, L/2], y in [-W/2, W/2], z in [0, H].

Main entry points::

    render_sequence(preset, out_dir, seed=0, frames=None, rectified=False, resolution="HD720", depth=False, ...)
    StereoRenderer(scene, rig, RenderConfig()).render(T_wc) -> RenderedPair(left, right, depth_left_m)
    truck_scene(TruckSpec(...), ...) -> Scene;  zed2_rig(resolution, rectified) -> calib.rig.StereoRig
    orbit_poses(frames, centre_xy, OrbitConfig(), rng) / pass_poses(frames, T_world_truck, PassConfig(), rng)
    get_preset(name) / preset_names()
    plane_disparity_check(resolution, rectified) -> rectified disparity of a plane vs f*B/Z
    draw_spec(seed, index) -> RandomSceneSpec (the operating envelope, envelope.py); render_random(K, seed, out_dir)
"""

# Lazy exports: ``stereo-recon --help`` imports this package (through its cli module) and must not
# pay for cv2/scipy/open3d.
_EXPORTS = {
    "checks": ("plane_disparity_check",),
    "envelope": ("RandomSceneSpec", "build_draw", "draw_spec", "render_draw", "render_random", "sample_scene_spec"),
    "camera": ("RESOLUTIONS", "SYNTH_SERIAL", "pixel_rays", "project_points", "zed2_rig"),
    "flight": ("OrbitConfig", "PassConfig", "look_at", "orbit_poses", "pass_poses"),
    "presets": ("TABLE2_STANDARD_M", "Preset", "get_preset", "over_limit_expectation", "preset_names"),
    "render": ("RenderConfig", "RenderedPair", "StereoRenderer"),
    "scene": ("Scene", "TruckSpec", "truck_mesh", "truck_scene"),
    "sequence": ("render_sequence",),
}
_WHERE = {name: mod for mod, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name in _WHERE:
        import importlib

        return getattr(importlib.import_module(f"stereo_recon.synthetic.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'stereo_recon.synthetic' has no attribute {name!r}")
