"""Depth-stage benchmark: our rectify + SGBM + filters vs bare OpenCV SGBM, and Middlebury bad-2.0.

Speed (issue 5 target: depth stage <= 1.3x bare cv2 SGBM on the same frames). For each HD720
frame both are timed back to back (interleaved, so machine load hits both alike):
  ours       = calib rectify_pair (fixed-point remap; left colour, right grey) + disparity_map(preset)
               + depth_from_disparity
  bare       = cv2.StereoSGBM (plain reference settings: 3-way, block 5, colour, P1=8*3*25, P2=32*3*25,
               uniqueness 10, speckle 100/2, disp12MaxDiff 1) on the raw frames, same disparity range
  bare-same  = cv2.StereoSGBM with our preset's matcher settings on grey frames (no rectify, no filters)

Frames: ``--video`` + ``--calib`` (e.g. ``stereo-recon synth --preset model-truck --out DIR`` then
``--video DIR/video.avi --calib DIR/rig.yaml``), else 120 HD720 pairs made from the four Middlebury
2014 scenes resized to 1280x720 (rows stay epipolar lines), rectified with a ZED2-like HD720 rig.

Accuracy: bad-2.0 (|error| > 2 px, holes bad, non-occluded mask) on the Middlebury 2014 quarter scenes,
plain SGBM vs each preset (NOTES: plain = 19.0 % on average).

End to end (optional): ``--reconstruct SYNTH_DIR [--poses vo|sfm|gt]`` runs ``reconstruct`` on a synth folder and
reports processed frames/s (target >= 4 for the VO path), CPU time, ATE, scale error, and (when the folder has
depth/ from ``synth --depth``) the truck cloud's median point-to-surface distance and coverage against the
rendered depth; then bare cv2 SGBM alone on the same frames, side by side. ``--compare-legacy`` also runs the
pre-speed-up path (SGBM for VO on every frame, image-motion keyframes, full-resolution fusion).

Run:  .venv/bin/python benchmarks/bench_depth.py [--frames 120] [--video V --calib C] [--preset balanced]
      .venv/bin/python benchmarks/bench_depth.py --skip-speed --skip-accuracy --reconstruct DIR --poses vo [--compare-legacy]
      (DIR from ``stereo-recon synth --preset model-truck --out DIR --frames 120 --depth``)
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

SCENES = ("Adirondack", "Motorcycle", "Piano", "Playtable")


def _middlebury_dir(arg: str | None) -> Path:
    return Path(arg) if arg else REPO.parent / "shared" / "data" / "middlebury"


def _zed_like_rig():
    """HD720 rig with ZED2-like intrinsics and distortion (the synth package's, when present)."""
    try:
        from stereo_recon.synthetic.camera import zed2_rig

        return zed2_rig("HD720")
    except Exception:  # the synthetic package is optional for this benchmark
        from calib.rig import StereoRig

        K = np.array([[528.0, 0, 641.0], [0, 528.0, 362.0], [0, 0, 1.0]])
        D = np.array([-0.04, 0.01, 0.0005, -0.0003, -0.005])
        return StereoRig(K1=K, D1=D, K2=K.copy(), D2=D.copy(), R=np.eye(3), T=np.array([-0.12, 0.0, 0.0]),
                         image_size=(1280, 720))


def _frames(args):
    """Yield (left, right) raw BGR HD720 pairs, and the rig."""
    import cv2

    if args.video:
        from calib.io import parse_calib_arg
        from stereo_recon.video import open_stereo_source, validate_against_rig

        src = open_stereo_source(args.video, (0, args.frames))
        rig = validate_against_rig(src, parse_calib_arg(args.calib, image_size=src.eye_size))
        return ((f.left, f.right) for f in src), rig, f"{args.video} ({src.eye_size[0]}x{src.eye_size[1]} per eye)"
    from stereo_recon.evaluation import load_middlebury_2014

    pairs = []
    for s in SCENES:
        p = load_middlebury_2014(_middlebury_dir(args.middlebury) / f"2014_{s}_Q")
        pairs.append((cv2.resize(p.left, (1280, 720)), cv2.resize(p.right, (1280, 720))))
    gen = (pairs[i % len(pairs)] for i in range(args.frames))
    return gen, _zed_like_rig(), "Middlebury 2014 scenes resized to 1280x720 (cycled)"


def bench_speed(args) -> dict:
    import cv2

    from calib.rig import rectify_pair
    from stereo_recon.disparity import depth_from_disparity, disparity_map, make_matcher, preset

    frames, rig, what = _frames(args)
    rect = rig.rectification(alpha=0.0, map_type="16SC2")
    cfg = preset(args.preset, num_disparities_px=args.num_disparities, fill_max_px=args.fill_max_px)
    plain = preset("plain", num_disparities_px=args.num_disparities)
    bare_plain = make_matcher(plain, 3)
    bare_same = make_matcher(cfg, 1)
    t_ours, t_bare, t_same = [], [], []
    for left, right in frames:
        t0 = time.perf_counter()
        # As reconstruct does it: left eye rectified in colour (fusion needs it), right eye in grey.
        lr, rg = rectify_pair(left, cv2.cvtColor(right, cv2.COLOR_BGR2GRAY), rect)
        lg = cv2.cvtColor(lr, cv2.COLOR_BGR2GRAY)
        d = disparity_map(lg, rg, cfg)
        depth_from_disparity(d, rect.focal_px, rect.baseline_m)
        t1 = time.perf_counter()
        bare_plain.compute(left, right)
        t2 = time.perf_counter()
        bare_same.compute(cv2.cvtColor(left, cv2.COLOR_BGR2GRAY), cv2.cvtColor(right, cv2.COLOR_BGR2GRAY))
        t3 = time.perf_counter()
        t_ours.append(t1 - t0)
        t_bare.append(t2 - t1)
        t_same.append(t3 - t2)
    n = len(t_ours)
    ours, bare, same = (1000 * float(np.median(t)) for t in (t_ours, t_bare, t_same))
    print(f"\n== depth stage speed: {n} frames, {what}; {args.num_disparities} disparities; preset {args.preset} ==")
    print(f"{'':32s}{'median ms/frame':>16s}{'total s':>10s}")
    print(f"{'ours (rectify+SGBM+filters)':32s}{ours:16.1f}{sum(t_ours):10.2f}")
    print(f"{'bare cv2 SGBM (plain settings)':32s}{bare:16.1f}{sum(t_bare):10.2f}")
    print(f"{'bare cv2 SGBM (our settings)':32s}{same:16.1f}{sum(t_same):10.2f}")
    print(f"ratio ours / bare plain = {ours / bare:.2f}x   (target <= 1.30x)")
    print(f"ratio ours / bare with our matcher settings = {ours / same:.2f}x   (cost of rectify + filters)")
    return {"frames": n, "ours_ms": ours, "bare_ms": bare, "bare_same_ms": same}


def bench_middlebury(args) -> dict:
    from stereo_recon.disparity import disparity_map, preset
    from stereo_recon.evaluation import bad_pixel_rate, load_middlebury_2014

    names = ["plain", "fast", "balanced", "quality", "wls"]
    table = {n: [] for n in names}
    times = {n: 0.0 for n in names}
    for s in SCENES:
        p = load_middlebury_2014(_middlebury_dir(args.middlebury) / f"2014_{s}_Q")
        for n in names:
            t0 = time.perf_counter()
            d = disparity_map(p.left, p.right, preset(n, num_disparities_px=p.ndisp))
            times[n] += time.perf_counter() - t0
            table[n].append(bad_pixel_rate(d, p.gt_disp_px, p.nonocc_mask))
    print("\n== Middlebury 2014 quarter: bad-2.0 % (holes bad, non-occluded) [density %] ==")
    print(f"{'preset':10s}" + "".join(f"{s:>18s}" for s in SCENES) + f"{'average':>10s}{'time s':>8s}")
    for n in names:
        cells = "".join(f"{e['bad_pct']:10.1f} [{e['density_pct']:4.0f}]" for e in table[n])
        avg = np.mean([e["bad_pct"] for e in table[n]])
        print(f"{n:10s}{cells}{avg:10.1f}{times[n]:8.2f}")
    print("reference (NOTES): plain SGBM 19.0 % average; target <= 12 %")
    _bench_2003(args, names)
    return {n: float(np.mean([e["bad_pct"] for e in table[n]])) for n in names}


def _bench_2003(args, names) -> None:
    """Middlebury 2003 cones/teddy (quarter size): GT = disp2.pgm / 4, 0 unknown; all known pixels (no occlusion mask)."""
    import cv2

    from stereo_recon.disparity import disparity_map, preset
    from stereo_recon.evaluation import bad_pixel_rate

    root = _middlebury_dir(args.middlebury)
    scenes = [s for s in ("cones", "teddy") if (root / f"2003_{s}_quarter" / "im2.png").is_file()]
    if not scenes:
        return
    print("\n== Middlebury 2003 quarter: bad-2.0 % over all pixels with GT (occlusions included, holes bad) ==")
    print(f"{'preset':10s}" + "".join(f"{s:>10s}" for s in scenes))
    data = []
    for s in scenes:
        d = root / f"2003_{s}_quarter"
        gt = cv2.imread(str(d / "disp2.pgm"), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 4.0
        gt[gt == 0] = np.nan
        data.append((cv2.imread(str(d / "im2.png")), cv2.imread(str(d / "im6.png")), gt))
    for n in names:
        row = [bad_pixel_rate(disparity_map(L, R, preset(n, num_disparities_px=64)), gt, np.isfinite(gt))["bad_pct"]
               for L, R, gt in data]
        print(f"{n:10s}" + "".join(f"{v:10.1f}" for v in row))


def _bare_sgbm_on_video(video: Path, frames: int | None, d_num: int) -> tuple[float, int]:
    """Wall seconds of bare cv2 SGBM (plain reference settings, colour, raw frames) on the video's frames."""
    import cv2

    from stereo_recon.disparity import make_matcher, preset
    from stereo_recon.video import open_stereo_source

    matcher = make_matcher(preset("plain", num_disparities_px=d_num), 3)
    t, n = 0.0, 0
    for fr in open_stereo_source(video, (0, frames) if frames else None):
        t0 = time.perf_counter()
        matcher.compute(fr.left, fr.right)
        t += time.perf_counter() - t0
        n += 1
    return t, n


# ReconstructConfig overrides that restore the pre-speed-up VO path: SGBM depth for VO on every frame,
# image-motion keyframes, full-resolution fusion up to the configured depth limit.
LEGACY = dict(fuse_by_pose=False, vo_dense_depth=True, fusion_min_width_px=None, fusion_depth_max_rel=None)


def bench_reconstruct(args) -> dict:
    """End to end on a synth folder (video.avi, rig.yaml, poses_gt.txt, truth.json[, depth/]): time, ATE, cloud."""
    import json
    import tempfile

    import cv2

    from calib.io import load_rig
    from stereo_recon.disparity import disparity_range_for_depth
    from stereo_recon.reconstruct import ReconstructConfig, reconstruct
    from stereo_recon.trajectory import absolute_trajectory_error, read_tum, scale_error

    d = Path(args.reconstruct)
    truth = json.loads((d / "truth.json").read_text())
    rig = load_rig(d / "rig.yaml")
    poses = f"gt:{d / 'poses_gt.txt'}" if args.poses == "gt" else args.poses
    variants = {"new": {}}
    if args.compare_legacy:
        variants["legacy"] = LEGACY
    gt = read_tum(d / "poses_gt.txt", fps=truth["fps"])
    results = {}
    for name, over in variants.items():
        cfg = ReconstructConfig(poses=poses, depth_min_m=args.depth_min_m, depth_max_m=args.depth_max_m,
                                disparity_preset=args.preset, **over)
        out = Path(tempfile.mkdtemp(prefix="bench_recon_")) / "out"
        c0 = time.process_time()
        t0 = time.perf_counter()
        man = reconstruct(d / "video.avi", rig, out, cfg)
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c0
        n = man["counts"]["frames_read"]
        est = read_tum(out / "poses.txt", fps=truth["fps"])
        ate = absolute_trajectory_error(est, gt, with_scale=False)
        r = {"fps": n / wall, "wall_s": wall, "cpu_s": cpu, "frames": n, "ate": ate, "scale_err": scale_error(est, gt)}
        print(f"\n== reconstruct [{name}] {d} ({n} frames, poses {args.poses}, preset {args.preset}) ==")
        print(f"wall {wall:.1f} s = {n / wall:.2f} processed frames/s (target >= 4), CPU {cpu:.1f} s "
              f"(load average {os.getloadavg()[0]:.1f}); stages: "
              + ", ".join(f"{k} {v:.1f}s" for k, v in man["timings_s"].items()))
        print(f"ATE rmse {ate['rmse_m'] * 1000:.1f} mm = {100 * ate['rmse_rel_path']:.3f} % of the {ate['path_length_m']:.2f} m "
              f"path (target <= 1 %); scale error {100 * r['scale_err']:+.3f} % (target |.| <= 0.5 %); "
              f"{man['counts']['keyframes_fused']} views fused, {man['counts']['frames_depth']} SGBM maps, "
              f"{man['counts']['cloud_points']} points, voxel {man['voxel_m'] * 1000:.1f} mm, TSDF "
              f"{man['fusion']['memory_gib']:.2f} GiB")
        if (d / "depth").is_dir():
            r.update(_cloud_scores(args, d, truth, rig, gt, est, out))
        results[name] = r
    # Bare OpenCV on the same frames, measured in the same run (machine load hits both alike).
    rect = rig.rectification(alpha=0.0)
    _, d_num = disparity_range_for_depth(rect.focal_px, rect.baseline_m, args.depth_min_m, args.depth_max_m, 256)
    t_bare, n_bare = _bare_sgbm_on_video(d / "video.avi", None, d_num)
    print(f"\n== side by side ({n_bare} frames, load average {os.getloadavg()[0]:.1f}) ==")
    print(f"{'':40s}{'wall s':>10s}{'frames/s':>10s}")
    for name, r in results.items():
        print(f"{'reconstruct --poses ' + args.poses + ' [' + name + '] e2e':40s}{r['wall_s']:10.1f}{r['fps']:10.2f}")
    print(f"{'bare cv2 SGBM only (plain, ' + str(d_num) + ' disp.)':40s}{t_bare:10.1f}{n_bare / t_bare:10.2f}")
    results["bare_sgbm"] = {"wall_s": t_bare, "fps": n_bare / t_bare}
    return results


def _cloud_scores(args, d, truth, rig, gt, est, out) -> dict:
    """Truck cloud vs the rendered depth: median point-to-surface distance and coverage."""
    import cv2
    from scipy.spatial import cKDTree
    import open3d as o3d

    T_wt = np.asarray(truth["truck"]["T_world_truck"])
    L, W, H = truth["length_m"], truth["width_m"], truth["height_m"]

    def in_truck(p, m=0.02, z0=0.01):
        q = (p - T_wt[:3, 3]) @ T_wt[:3, :3]
        return (np.abs(q[:, 0]) < L / 2 + m) & (np.abs(q[:, 1]) < W / 2 + m) & (q[:, 2] > z0) & (q[:, 2] < H + m)

    # Reference surface: GT depth maps (raw left camera) of every 4th frame, every 2nd pixel, back-projected
    # with the GT poses and kept around the truck (5 cm margin, ground included) to bound memory.
    w, h = rig.image_size
    u, v = np.meshgrid(np.arange(0, w, 2, dtype=np.float64), np.arange(0, h, 2, dtype=np.float64))
    xy = cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2), rig.K1, rig.D1).reshape(-1, 2)
    ref = []
    for i, T in zip(gt.indices[::4], gt.T_wc[::4]):
        z = np.load(d / "depth" / f"{int(i):06d}.npy")[::2, ::2].ravel().astype(np.float64)
        ok = np.isfinite(z) & (z > 0) & (z < args.depth_max_m)
        p = np.stack([xy[ok, 0] * z[ok], xy[ok, 1] * z[ok], z[ok]], 1) @ T[:3, :3].T + T[:3, 3]
        ref.append(p[in_truck(p, 0.05, -0.05)])
    ref = np.vstack(ref)
    cloud = np.asarray(o3d.io.read_point_cloud(str(out / "cloud.ply")).points)
    if args.poses != "gt":  # VO/SfM world = their first camera; map it onto the truth through frame 0
        A = gt.T_wc[list(gt.indices).index(int(est.indices[0]))] @ np.linalg.inv(est.T_wc[0])
        cloud = cloud @ A[:3, :3].T + A[:3, 3]
    cloud = cloud[in_truck(cloud, 0.05, -0.05)]

    ours, rtruck = cloud[in_truck(cloud)], ref[in_truck(ref)]
    rp = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(ref))
    rp.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    nrm = np.asarray(rp.normals)
    _, nn = cKDTree(ref).query(ours)
    acc = np.abs(np.sum((ours - ref[nn]) * nrm[nn], axis=1))
    cov = (cKDTree(cloud).query(rtruck)[0] < 0.01 * L).mean()
    print(f"truck points {len(ours)}: median distance to the true surface {1000 * np.median(acc):.1f} mm = "
          f"{100 * np.median(acc) / L:.2f} % of L (target <= 0.5 %); coverage of the visible truck surface "
          f"{100 * cov:.1f} % (target >= 90 %)")
    return {"acc_rel": float(np.median(acc) / L), "coverage": float(cov)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--video", help="side-by-side HD720 video (e.g. from stereo-recon synth)")
    ap.add_argument("--calib", help="calibration for --video")
    ap.add_argument("--preset", default="balanced")
    ap.add_argument("--num-disparities", type=int, default=128)
    ap.add_argument("--fill-max-px", type=int, default=32, help="as reconstruct uses it (None: -1)")
    ap.add_argument("--middlebury", help="folder with 2014_<scene>_Q (default ../shared/data/middlebury)")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--reconstruct", metavar="SYNTH_DIR",
                    help="also run reconstruct end to end on a `stereo-recon synth` folder and score it")
    ap.add_argument("--poses", default="vo", help="pose back-end for --reconstruct: vo, sfm or gt")
    ap.add_argument("--compare-legacy", action="store_true",
                    help="also run --reconstruct the pre-speed-up way (SGBM on every frame, full-resolution fusion)")
    ap.add_argument("--depth-min-m", type=float, default=0.3, help="for --reconstruct (default 0.3, as the CLI)")
    ap.add_argument("--depth-max-m", type=float, default=20.0, help="for --reconstruct (default 20, as the CLI)")
    ap.add_argument("--skip-accuracy", action="store_true")
    args = ap.parse_args(argv)
    if args.fill_max_px is not None and args.fill_max_px < 0:
        args.fill_max_px = None
    if args.video and not args.calib:
        ap.error("--video needs --calib")
    import cv2

    print(f"OpenCV {cv2.__version__}, threads {cv2.getNumThreads()}")
    if not args.skip_accuracy:
        bench_middlebury(args)
    if not args.skip_speed:
        bench_speed(args)
    if args.reconstruct:
        bench_reconstruct(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
