"""The wide pairs' (motion-stereo) depth of a rendered draw with the TRUE poses, per surface class, for matcher settings.

Why: fused again with rendered depth, tankers' flanks sit within 0.2-0.4 voxels of the tank; with the run's own depth
0.8-1.9 voxels inside (``bench_depth_bias.py --refuse``). This script takes the poses out of the question: it pairs
every sixth frame of a draw with its first partner that ``motion_stereo.partner_ok`` accepts under the true poses,
rectifies the pair as the pipeline does (``rectify_motion_pair``, fusion resolution 640 x 360), matches it with
``motion_depth`` and reads the depth against the rendered depth per ``bench_depth_bias`` class (median over the
pairs of each pair's median relative error, %, + = too far). Variants override ``DisparityConfig`` fields (the
motion stereo's own mode stays ``MotionStereoConfig.mode``) or ``MotionStereoConfig`` fields.

Usage (a ``bench --random`` draw, and any run of it for the disparity settings it used)::

    python benchmarks/bench_wide_matcher.py out/envelope-2080/draws/draw_021 out/envelope-2080/runs/draw_021 \\
        half:p1_per_px=4,p2_per_px=16 quarter:p1_per_px=2,p2_per_px=8

Issue 12, fifty-second round: on 2080/21 (full-scale tanker, 10 pairs) the flank band (``walls``) reads +0.31 %
against roof -0.08 and ground -0.05 %; with the SGBM penalties at a quarter +0.18 / -0.04 / -0.05 %.
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def wide_pairs(draw: Path, every: int = 6, out_size: tuple[int, int] = (640, 360)) -> tuple[list, dict]:
    """(pairs, frames): each pair (view, partner, MotionPair, rendered z in the pair's frame (flat), classes, the
    view's rendered z in its rectified frame (H, W)) under the true poses; frames: index -> rectified left grey."""
    import cv2

    import bench_depth_bias as bdb
    from calib.io import load_rig
    from calib.rig import rectify_pair
    from stereo_recon.motion_stereo import MotionStereoConfig, partner_ok, rectify_motion_pair
    from stereo_recon.stages.state import rot4
    from stereo_recon.trajectory import read_tum
    from stereo_recon.video import open_stereo_source

    truth = json.loads((draw / "truth.json").read_text())
    source = open_stereo_source(next(draw.glob("video.*")))
    rig = load_rig(glob.glob(str(draw / "SN*.conf"))[0], image_size=source.eye_size)
    rect = rig.rectification(alpha=0.0)
    K = np.array([[rect.focal_px, 0, rect.cx_px], [0, rect.focal_px, rect.cy_px], [0, 0, 1.0]])
    gt = read_tum(draw / "poses_gt.txt", fps=float(truth["fps"]))
    T = {int(i): P @ rot4(rect.R1.T) for i, P in zip(gt.indices, gt.T_wc)}   # world from rectified left camera
    frames = {}
    for fr in source:
        left, _ = rectify_pair(fr.left, cv2.cvtColor(fr.right, cv2.COLOR_BGR2GRAY), rect)
        frames[fr.index] = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    depth_of = bdb._rendered_depth(draw, truth)
    w_full, h_full = source.eye_size
    ms = MotionStereoConfig()
    pairs = []
    for idx in range(0, len(frames), every):
        rendered = depth_of(idx)
        z_view = bdb.resample_rendered((h_full, w_full), K, np.eye(3), rect.R1, rig, rendered)
        median = float(np.nanmedian(z_view))
        j = next((j for j in range(idx + 1, min(idx + 1 + ms.max_partner_gap_frames, len(frames)))
                  if partner_ok(T[idx], T[j], median, ms)), None)
        if j is None:
            continue
        pair = rectify_motion_pair(K, T[idx], T[j], (w_full, h_full), out_size)
        exact = bdb.resample_rendered(out_size[::-1], pair.K_rect, pair.R_rect_a, rect.R1, rig, rendered).reshape(-1)
        u, v = np.meshgrid(np.arange(out_size[0], dtype=float), np.arange(out_size[1], dtype=float))
        rays = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3) @ np.linalg.inv(pair.K_rect).T
        T_pair = T[idx] @ rot4(pair.R_rect_a.T)
        world = (rays * exact[:, None]) @ T_pair[:3, :3].T + T_pair[:3, 3]
        pairs.append((idx, j, pair, exact, bdb._classes(world, truth), z_view))
    return pairs, {"frames": frames, "fb_px_m": rect.focal_px * rect.baseline_m}


def main(argv=None) -> int:
    import bench_depth_bias as bdb
    from stereo_recon.disparity import DisparityConfig
    from stereo_recon.motion_stereo import MotionStereoConfig, motion_depth

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("draw", type=Path, help="a rendered draw folder (truth.json with its random_spec, or depth/)")
    ap.add_argument("run", type=Path, help="a run of it (its run.json's disparity settings are the baseline)")
    ap.add_argument("variants", nargs="*", help="NAME:field=value,field=value (DisparityConfig or MotionStereoConfig)")
    args = ap.parse_args(argv)
    meta = json.loads((args.run / "run.json").read_text())
    dfields = {f.name for f in dataclasses.fields(DisparityConfig)}
    mfields = {f.name for f in dataclasses.fields(MotionStereoConfig)}
    base = DisparityConfig(**{k: v for k, v in meta["parameters"]["disparity"].items() if k in dfields})
    variants = [("run's", {})]
    for text in args.variants:
        name, _, kv = text.partition(":")
        fields = dict(x.split("=", 1) for x in kv.split(",") if x)
        unknown = set(fields) - dfields - mfields
        if unknown:
            ap.error(f"{text}: unknown field(s) {', '.join(sorted(unknown))}")
        variants.append((name, {k: json.loads(v) if v not in ("None",) else None for k, v in fields.items()}))
    pairs, ctx = wide_pairs(args.draw)
    print(f"{args.draw.name}: {len(pairs)} wide pairs under the true poses; median relative depth error, % (+ = too far)")
    for name, kw in variants:
        dcfg = dataclasses.replace(base, **{k: v for k, v in kw.items() if k in dfields and k not in mfields})
        mcfg = dataclasses.replace(MotionStereoConfig(), **{k: v for k, v in kw.items() if k in mfields})
        per = {c: [] for c in bdb.CLASSES}
        valid = []
        for idx, j, pair, exact, classes, z_view in pairs:
            z, _ = motion_depth(ctx["frames"][idx], ctx["frames"][j], z_view, pair, dcfg, mcfg, ctx["fb_px_m"], 1e4)
            rel = z.reshape(-1) / exact - 1.0
            valid.append(float(np.isfinite(rel).mean()))
            for c, m in classes.items():
                m = m & np.isfinite(rel)
                if m.sum() > 50:
                    per[c].append(float(np.median(rel[m])))
        cells = "  ".join(f"{c} {100 * np.median(v):+.3f}" if v else f"{c} -" for c, v in per.items())
        print(f"{name:12s} valid {np.mean(valid):.2f}  {cells}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
