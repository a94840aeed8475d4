"""Pose back-ends benchmark: stereo VO and pycolmap SfM on a synthetic HD720 orbit, side by side.

Reports, in one table, for
  vo (sgbm)   StereoVO fed with our SGBM depth (the `reconstruct --poses vo` path)
  vo (sparse) StereoVO without depth maps: corners matched in the right image at keyframes only
              (`track(i, left, None, right_rect_gray=right)`), so SGBM is needed for fusion frames only
  vo (gt)     StereoVO fed with the renderer's exact depth (separates VO error from depth error)
  sfm         sfm_poses on every --sfm-every-th rectified left frame, metric scale from SGBM depth
the speed (VO: processed frames/s end to end = decode + rectify + SGBM + VO (sparse: no SGBM), and VO alone;
SfM: wall time of sfm_poses) and the accuracy against the ground-truth poses: ATE RMSE relative to
the path length after a similarity (Umeyama) alignment, the scale error (1/s - 1 of that
alignment: 0 for a metric trajectory), end-to-start drift, loop closures and tracking gaps.
Targets from issue 5 are printed beside them: >= 4 frames/s VO end to end, <= 180 s SfM,
ATE <= 1 % of the path, |scale error| <= 0.5 %.

Data: ``--data DIR`` written by ``stereo-recon synth --preset model-truck --out DIR --rectified --depth``
(video.avi, rig.yaml, poses_gt.txt, depth/), else rendered into ``--cache`` with the synth package; or
``--draw DIR``, one draw of ``stereo-recon bench --random`` (``OUT/draws/draw_NNN``: video, SN*.conf, poses_gt.txt,
truth.json) read as ``stereo-recon run`` reads it (its calibration file, the run's rectification, disparity range and
SGBM preset), with the exact depth rendered again from the draw's spec: how odometry alone fares on an envelope draw.

Run:  .venv/bin/python benchmarks/bench_poses.py [--data DIR | --draw DIR] [--frames 120] [--sfm-every 2] [--skip-sfm]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))   # sibling scripts (bench_depth_bias) for --draw


def _ensure_data(args) -> Path:
    if args.data:
        return Path(args.data)
    out = Path(args.cache or Path(tempfile.gettempdir()) / f"bench_poses_{args.preset}_{args.frames}")
    if not (out / "poses_gt.txt").is_file():
        from stereo_recon.synthetic.sequence import render_sequence

        print(f"rendering {args.frames} frames of {args.preset} into {out} (once) ...", flush=True)
        t0 = time.perf_counter()
        render_sequence(args.preset, out, seed=0, frames=args.frames, rectified=True, depth=True)
        print(f"  rendered in {time.perf_counter() - t0:.0f} s", flush=True)
    return out


def _rot4(R: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    return T


def _scores(est, gt) -> dict:
    from stereo_recon.trajectory import absolute_trajectory_error, scale_error

    if len(est) < 3:
        return {"ate_rel": float("nan"), "scale_err": float("nan"), "end_m": float("nan"), "n": len(est)}
    ate = absolute_trajectory_error(est, gt, with_scale=True)
    g = {int(i): T for i, T in zip(gt.indices, gt.T_wc)}
    rel_e = np.linalg.inv(est.T_wc[0]) @ est.T_wc[-1]
    rel_g = np.linalg.inv(g[int(est.indices[0])]) @ g[int(est.indices[-1])]
    return {"ate_rel": ate["rmse_rel_path"], "ate_m": ate["rmse_m"], "rot_deg": ate["rot_rmse_deg"],
            "scale_err": scale_error(est, gt), "end_m": float(np.linalg.norm(rel_e[:3, 3] - rel_g[:3, 3])),
            "n": ate["n"]}


def _draw_inputs(draw: Path):
    """What ``stereo-recon run`` derives from one ``bench --random`` draw, plus its truth.

    Returns (source, rectification, DisparityConfig, depth_min_m, depth_max_m, ground-truth trajectory of the physical
    left camera, gt_depth(idx, (H, W)) -> the exact z-depth (m) in the rectified left camera).
    """
    import json

    import bench_depth_bias as bdb
    from calib.io import parse_calib_arg
    from stereo_recon.core.manifest import Stopwatch
    from stereo_recon.reconstruct_config import ReconstructConfig
    from stereo_recon.stages.inputs import open_input
    from stereo_recon.trajectory import read_tum
    from stereo_recon.video import open_stereo_source

    video = next(draw.glob("video.*"))
    conf = next(draw.glob("SN*.conf"))
    cfg = ReconstructConfig()
    rig = parse_calib_arg(str(conf), image_size=open_stereo_source(video).eye_size)
    setup = open_input(video, rig, cfg, Stopwatch(), conf)
    truth = json.loads((draw / "truth.json").read_text())
    gt = read_tum(draw / "poses_gt.txt", fps=setup.source.fps)
    depth_of = bdb._rendered_depth(draw, truth)   # the raw left eye's z-depth, rendered again from the draw's spec
    rect = setup.rig.rectification(alpha=0.0, map_type="16SC2")   # the run's fixed-point maps (stereo_recon.rectifier)

    def gt_depth(idx, shape):
        return bdb.resample_rendered(shape, rect.K_rect, np.eye(3), rect.R1, setup.rig, depth_of(idx))

    return setup.source, rect, setup.disparity, cfg.depth_min_m, setup.depth_max_m, gt, gt_depth


def main(argv=None) -> int:
    compare(argv)
    return 0


def compare(argv=None) -> dict:
    """Runs the back-ends and prints the table; returns {back-end: _scores against the ground truth}."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    src_arg = ap.add_mutually_exclusive_group()
    src_arg.add_argument("--data", help="synth output folder (video.avi, rig.yaml, poses_gt.txt, depth/)")
    src_arg.add_argument("--draw", help="a `bench --random` draw folder (OUT/draws/draw_NNN): read as `run` reads it")
    ap.add_argument("--preset", default="model-truck")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--cache", help="where to render when --data is not given")
    ap.add_argument("--sfm-every", type=int, default=2, help="SfM uses every N-th frame")
    ap.add_argument("--skip-sfm", action="store_true")
    ap.add_argument("--disparity-preset", default="balanced")
    args = ap.parse_args(argv)

    import cv2

    from calib.io import load_rig
    from calib.rig import rectify_pair
    from stereo_recon.disparity import depth_from_disparity, disparity_map, disparity_range_for_depth, preset
    from stereo_recon.odometry import StereoVO
    from stereo_recon.sfm import sfm_poses
    from stereo_recon.trajectory import Trajectory, read_tum
    from stereo_recon.video import open_stereo_source

    if args.draw:
        src, rect, dcfg, depth_min, depth_max, gt, gt_depth = _draw_inputs(Path(args.draw))
        video = src.path
    else:
        data = _ensure_data(args)
        video = next(p for p in (data / "video.avi", data / "video.mp4") if p.is_file())
        src = open_stereo_source(video)
        rig = load_rig(data / "rig.yaml", image_size=src.eye_size)
        rect = rig.rectification()
        gt = read_tum(data / "poses_gt.txt", fps=src.fps)
        depth_min, depth_max = 0.3, 20.0
        d0, dn = disparity_range_for_depth(rect.focal_px, rect.baseline_m, depth_min, depth_max)
        dcfg = preset(args.disparity_preset, min_disparity_px=d0, num_disparities_px=dn)
        gt_depth_dir = data / "depth"   # rendered by a rectified rig: already the rectified left camera's
        gt_depth = (lambda idx, shape: np.load(gt_depth_dir / f"{idx:06d}.npy")) if gt_depth_dir.is_dir() else None
    K, B, f = rect.K_rect, rect.baseline_m, rect.focal_px
    print(f"data: {video} ({src.eye_size[0]}x{src.eye_size[1]} per eye, {src.frame_count} frames, "
          f"f = {f:.1f} px, B = {B * 1000:.1f} mm, disparities {dcfg.min_disparity_px}+{dcfg.num_disparities_px})",
          flush=True)

    vo_sgbm = StereoVO(K, B, fps=src.fps)
    vo_gt = StereoVO(K, B, fps=src.fps) if gt_depth is not None else None
    vo_sparse = StereoVO(K, B, fps=src.fps)
    work = Path(tempfile.mkdtemp(prefix="bench_poses_"))
    (work / "images").mkdir()
    (work / "depth").mkdir()
    t = {"decode": 0.0, "rectify": 0.0, "depth": 0.0, "vo": 0.0, "vo_gt": 0.0, "vo_sparse": 0.0}
    n = 0
    t_all = time.perf_counter()
    t_prev = time.perf_counter()
    for frame in src:
        t["decode"] += time.perf_counter() - t_prev
        t0 = time.perf_counter()
        left, right = rectify_pair(frame.left, frame.right, rect)
        lg = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
        rg = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
        t1 = time.perf_counter()
        depth = depth_from_disparity(disparity_map(lg, rg, dcfg), f, B, depth_min, depth_max)
        t2 = time.perf_counter()
        vo_sgbm.track(frame.index, lg, depth, timestamp_s=frame.timestamp_s)
        t3 = time.perf_counter()
        t["rectify"] += t1 - t0
        t["depth"] += t2 - t1
        t["vo"] += t3 - t2
        t5 = time.perf_counter()
        vo_sparse.track(frame.index, lg, None, timestamp_s=frame.timestamp_s, right_rect_gray=rg)
        t["vo_sparse"] += time.perf_counter() - t5
        if vo_gt is not None:
            d_gt = gt_depth(frame.index, lg.shape)
            t4 = time.perf_counter()
            vo_gt.track(frame.index, lg, d_gt, timestamp_s=frame.timestamp_s)
            t["vo_gt"] += time.perf_counter() - t4
        if not args.skip_sfm and frame.index % args.sfm_every == 0:
            cv2.imwrite(str(work / "images" / f"{frame.index:06d}.png"), left)
            np.save(work / "depth" / f"{frame.index:06d}.npy", depth.astype(np.float32))
        n += 1
        t_prev = time.perf_counter()
    wall_vo = time.perf_counter() - t_all - t["vo_gt"] - t["vo_sparse"]
    t0 = time.perf_counter()
    tr_vo = vo_sgbm.finish()
    t["vo"] += time.perf_counter() - t0
    tr_vo_gt = vo_gt.finish() if vo_gt is not None else None
    t0 = time.perf_counter()
    tr_vo_sparse = vo_sparse.finish()
    t["vo_sparse"] += time.perf_counter() - t0

    # Poses are of the rectified left camera; the ground truth describes the physical one.
    def phys(tr):
        return Trajectory(tr.indices, tr.timestamps_s, tr.T_wc @ _rot4(rect.R1), tr.stats)

    rows = {"vo (sgbm)": (phys(tr_vo), tr_vo.stats), "vo (sparse)": (phys(tr_vo_sparse), tr_vo_sparse.stats)}
    if tr_vo_gt is not None:
        rows["vo (gt depth)"] = (phys(tr_vo_gt), tr_vo_gt.stats)
    sfm_time = None
    if not args.skip_sfm:
        t0 = time.perf_counter()
        try:
            tr_sfm = sfm_poses(work / "images", K, work / "sfm", baseline_m=B, depth_dir=work / "depth", fps=src.fps)
            rows["sfm"] = (phys(tr_sfm), tr_sfm.stats)
        except Exception as err:  # report, do not hide, a failing back-end
            print(f"sfm failed: {err}")
        sfm_time = time.perf_counter() - t0
    shutil.rmtree(work, ignore_errors=True)

    e2e_fps = n / (t["decode"] + t["rectify"] + t["depth"] + t["vo"])
    e2e_sparse_fps = n / (t["decode"] + t["rectify"] + t["vo_sparse"])
    print()
    print(f"frames: {n}   wall (decode+rectify+SGBM+VO): {wall_vo:.1f} s")
    print(f"  per frame: decode {1000 * t['decode'] / n:.0f} ms, rectify {1000 * t['rectify'] / n:.0f} ms, "
          f"SGBM depth {1000 * t['depth'] / n:.0f} ms, VO {1000 * t['vo'] / n:.0f} ms")
    print()
    hdr = f"{'':<26}" + "".join(f"{k:>18}" for k in rows) + f"{'target':>18}"
    print(hdr)
    print("-" * len(hdr))
    scores = {k: _scores(tr, gt) for k, (tr, _) in rows.items()}

    def line(name, fn, target=""):
        print(f"{name:<26}" + "".join(f"{fn(k):>18}" for k in rows) + f"{target:>18}")

    line("frames with a pose", lambda k: f"{len(rows[k][0])}/{n if k != 'sfm' else rows[k][1].get('images', 0)}")
    line("speed", lambda k: (f"{e2e_fps:.2f} fps e2e" if k == "vo (sgbm)" else
                             f"{e2e_sparse_fps:.2f} fps e2e" if k == "vo (sparse)" else
                             f"{n / max(t['vo_gt'], 1e-9):.1f} fps VO" if k.startswith("vo (gt") else
                             f"{sfm_time:.0f} s"), ">=4 fps / <=180 s")
    line("VO-only speed", lambda k: f"{n / t['vo']:.1f} fps" if k == "vo (sgbm)" else
         f"{n / t['vo_sparse']:.1f} fps" if k == "vo (sparse)" else "")
    line("ATE rmse / path", lambda k: f"{100 * scores[k]['ate_rel']:.3f} %", "<= 1 %")
    line("ATE rmse", lambda k: f"{1000 * scores[k].get('ate_m', float('nan')):.1f} mm")
    line("scale error", lambda k: f"{100 * scores[k]['scale_err']:+.3f} %", "|.| <= 0.5 %")
    line("end-to-start drift", lambda k: f"{1000 * scores[k]['end_m']:.1f} mm")
    line("loop closures", lambda k: str(rows[k][1].get("loop_closures", "-")))
    line("tracking gaps", lambda k: str(len(rows[k][1].get("tracking_gaps", []))) if k != "sfm" else
         str(len(rows[k][1].get("unregistered", []))) + " unreg.")
    line("keyframes / images", lambda k: str(rows[k][1].get("keyframes", rows[k][1].get("registered", "-"))))
    if "sfm" in rows:
        s = rows["sfm"][1]
        print(f"\nsfm metric scale {s.get('scale', float('nan')):.4f} (MAD {100 * s.get('scale_mad_rel', float('nan')):.2f} %, "
              f"IQR {100 * s.get('scale_iqr_rel', float('nan')):.2f} %, {s.get('scale_samples', 0)} samples), "
              f"{s.get('points3D', 0)} points, reprojection {s.get('mean_reprojection_error_px', float('nan')):.2f} px")
    return scores


if __name__ == "__main__":
    raise SystemExit(main())
