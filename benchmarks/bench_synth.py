"""Speed of the synthetic ZED2 renderer, printed beside the targets of issue 4.

Targets (2 CPU cores): <= 0.5 s per HD720 stereo pair; a 120-frame HD720 orbit (render + MJPG
encode + files) in <= 60 s.

    .venv/bin/python benchmarks/bench_synth.py                 # per-pair timings + the 120-frame orbit
    .venv/bin/python benchmarks/bench_synth.py --pairs 5 --no-sequence
    .venv/bin/python benchmarks/bench_synth.py --pairs 1 --no-sequence     # mostly the accuracy checks

Wall time depends on what else runs on the machine; the CPU time (all threads of this process)
is printed too, and the 1-minute load average, so a busy machine is visible in the output. On an
idle 2-core machine wall ~ CPU / 1.7 (ray casting and both eyes' shading run in parallel).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time

import numpy as np


def _load() -> str:
    try:
        return f"{os.getloadavg()[0]:.1f}"
    except OSError:
        return "n/a"


def _accuracy(resolution: str) -> None:
    """Geometric self-checks: ray inversion of the distortion and rectified plane disparity vs f*B/Z."""
    import cv2

    from stereo_recon.synthetic.camera import pixel_rays, zed2_rig
    from stereo_recon.synthetic.checks import plane_disparity_check

    rig = zed2_rig(resolution)
    rays = pixel_rays(rig.K1, rig.D1, rig.image_size).astype(np.float64)
    w, h = rig.image_size
    uv, _ = cv2.projectPoints(rays * 2.0, np.zeros(3), np.zeros(3), rig.K1, rig.D1)
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    err = np.abs(uv.reshape(-1, 2) - np.c_[u.ravel(), v.ravel()]).max()
    print(f"  ray inversion through the distortion ({resolution}, cv2.projectPoints round trip): max {err:.1e} px   target ~0")
    print(f"  fronto-parallel plane at 1.5 m, VGA, sensor noise 1.5 DN  {'expected d':>10s} {'median err':>11s} {'p90 |err|':>10s} {'p90 |row|':>10s}   target")
    for name, kw in (("raw, rectified with written .conf", {"rectified": False}), ("rectified mode (SVO-like)", {"rectified": True}),
                     ("raw, NOT rectified (must fail)", {"rectified": False, "rectify": False})):
        r = plane_disparity_check("VGA", Z_m=1.5, **kw)
        print(f"    {name:54s} {r['expected_px']:10.3f} {r['median_err_px']:+11.3f} {r['p90_abs_err_px']:10.3f} {r['p90_abs_row_px']:10.3f}   "
              f"<= 0.25 / 0.5 px")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=8, help="stereo pairs to time per configuration")
    ap.add_argument("--frames", type=int, default=120, help="frames of the timed orbit sequence")
    ap.add_argument("--no-sequence", action="store_true", help="skip the full-sequence timing")
    ap.add_argument("--resolution", default="HD720")
    ap.add_argument("--no-accuracy", action="store_true", help="skip the geometric self-checks")
    args = ap.parse_args(argv)

    from stereo_recon.synthetic.camera import zed2_rig
    from stereo_recon.synthetic.flight import orbit_poses
    from stereo_recon.synthetic.presets import get_preset
    from stereo_recon.synthetic.render import RenderConfig, StereoRenderer
    from stereo_recon.synthetic.scene import truck_scene
    from stereo_recon.synthetic.sequence import render_sequence

    p = get_preset("model-truck")
    rig = zed2_rig(args.resolution)
    scene = truck_scene(p.truck, truck_yaw_rad=np.deg2rad(p.truck_yaw_deg), texel_m=p.texel_m, n_distractors=p.n_distractors, rng=0)
    poses = orbit_poses(max(args.pairs, 2), (0.0, 0.0), p.orbit, rng=0)
    print(f"synthetic renderer benchmark: {args.resolution} {rig.image_size[0]}x{rig.image_size[1]} per eye, "
          f"{len(scene.mesh.triangles)} triangles, {os.cpu_count()} CPUs visible, load {_load()}")
    t0 = time.perf_counter()
    StereoRenderer(scene, rig, RenderConfig(shadows=False))  # ray directions are cached per rig after this
    print(f"  setup (per-pixel rays through the distortion, noise buffer): {time.perf_counter() - t0:.2f} s (once per rig)")
    t0 = time.perf_counter()
    sm = StereoRenderer(scene, rig, RenderConfig()).shadow_map
    if sm is not None:
        print(f"  setup (scene BVH + ground shadow map {sm.lit.shape[1]}x{sm.lit.shape[0]} cells of {1000 * sm.cell_m:.1f} mm, "
              f"{sm.cast_cells / 1e6:.2f} M cast): {time.perf_counter() - t0:.2f} s (once per scene)")
    print(f"  {'configuration':34s} {'wall s/pair':>12s} {'CPU s/pair':>11s} {'target':>8s}")
    for name, cfg in (("raw, shadows (default)", RenderConfig()), ("raw, no shadows", RenderConfig(shadows=False))):
        r = StereoRenderer(scene, rig, cfg)
        r.render(poses[0], rng=0)  # warm-up
        walls, cpus = [], []
        for i in range(args.pairs):
            w0, c0 = time.perf_counter(), time.process_time()
            r.render(poses[i], rng=i)
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
        print(f"  {name:34s} {np.median(walls):12.3f} {np.median(cpus):11.3f} {'<= 0.5':>8s}")
    if not args.no_sequence:
        tmp = tempfile.mkdtemp(prefix="bench_synth_")
        try:
            load0 = _load()
            w0, c0 = time.perf_counter(), time.process_time()
            render_sequence("model-truck", os.path.join(tmp, "seq"), seed=0, frames=args.frames, resolution=args.resolution)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            size = os.path.getsize(os.path.join(tmp, "seq", "video.avi")) / 1e6
            with open(os.path.join(tmp, "seq", "synth_run.json")) as f:
                stages = json.load(f)["timings_s"]
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        print(f"  {args.frames}-frame orbit (render+encode+files)  {wall:8.1f} s wall  {cpu:6.1f} s CPU   target <= 60 s wall   "
              f"(load {load0} -> {_load()}; video {size:.1f} MB; {', '.join(f'{k} {v:.1f} s' for k, v in stages.items())}; "
              f"'encode' = waiting for the background encoder)")
    if not args.no_accuracy:
        _accuracy(args.resolution)
    print(f"  load average after: {_load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
