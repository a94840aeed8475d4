"""Far-scene bundle adjustment's time by phase on an envelope draw: SIFT extraction on one thread and on every core.

The view set a far run bundle-adjusts, on one `stereo-recon bench --random` draw (``OUT/draws/draw_NNN``: video,
SN*.conf, poses_gt.txt): 17 views spread over the recording, each with the frame two on as its motion-stereo partner
(the run's layout, approximately), rectified as ``run`` rectifies them. pycolmap SfM with the project's settings
(``stereo_recon.sfm.sfm_poses``), once per variant, timed by phase (feature extraction, matching, incremental
mapping), scored against the rendered cameras (ATE relative to the path after a similarity, rotation rms), and
compared pose for pose with the first variant:
  1 thread    ``SfMConfig()``: every phase on one thread, the default (repeatable to the last digit; the reference)
  all cores   ``SfMConfig(extraction_threads=-1)``: extraction on every core; matching and mapping on one. Faster, but
              COLMAP numbers the images as their extraction finishes, so the poses can differ run to run

Run:  .venv/bin/python benchmarks/bench_sfm.py --draw out/envelope-2085/draws/draw_004 [--repeat 2]
"""

from __future__ import annotations

import argparse
import functools
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

PHASES = ("extract_features", "match_image_pairs", "match_exhaustive", "incremental_mapping")


def view_set(n_frames: int, views: int = 17, partner_step: int = 2) -> list[int]:
    """Frame indices of ``views`` views spread over ``n_frames`` frames, each with the frame ``partner_step`` on."""
    first = {int(round(v)) for v in np.linspace(0, n_frames - 1 - partner_step, views)}
    return sorted(first | {v + partner_step for v in first})


def write_views(draw: Path, out: Path) -> tuple[np.ndarray, np.ndarray]:
    """The draw's view set, rectified (the run's 16SC2 maps), as out/NNNNNN.png; returns (the rectified K (3, 3) px,
    R1 (3, 3): the rotation from the physical left camera to the rectified one)."""
    import cv2

    from calib.io import parse_calib_arg
    from calib.rig import rectify_pair
    from stereo_recon.video import open_stereo_source

    source = open_stereo_source(next(draw.glob("video.*")))
    rig = parse_calib_arg(str(next(draw.glob("SN*.conf"))), image_size=source.eye_size)
    rect = rig.rectification(alpha=0.0, map_type="16SC2")
    wanted = set(view_set(source.frame_count))
    for frame in source:
        if frame.index in wanted:
            left, _ = rectify_pair(frame.left, cv2.cvtColor(frame.right, cv2.COLOR_BGR2GRAY), rect)
            cv2.imwrite(str(out / f"{frame.index:06d}.png"), left)
    return rect.K_rect, rect.R1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--draw", required=True, help="a `bench --random` draw folder (OUT/draws/draw_NNN)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per variant (the fastest is shown)")
    args = ap.parse_args(argv)

    import pycolmap

    from stereo_recon.sfm import SfMConfig, sfm_poses
    from stereo_recon.trajectory import Trajectory, absolute_trajectory_error, read_tum

    draw = Path(args.draw)
    gt = read_tum(draw / "poses_gt.txt")
    # Each phase is one pycolmap call inside sfm_poses: wrapping those calls times them without a second copy of
    # the SfM pipeline here.
    spent: dict[str, float] = {}

    def timed(name, fn):
        @functools.wraps(fn)
        def call(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                spent[name] = spent.get(name, 0.0) + time.perf_counter() - t0
        return call

    for name in PHASES:
        setattr(pycolmap, name, timed(name, getattr(pycolmap, name)))

    work = Path(tempfile.mkdtemp(prefix="bench_sfm_"))
    try:
        (work / "images").mkdir()
        K, R1 = write_views(draw, work / "images")
        images = len(list((work / "images").iterdir()))
        print(f"{draw}: {images} views, {os.cpu_count()} cores", flush=True)
        rows = {}
        for label, config in (("1 thread", SfMConfig()), ("all cores", SfMConfig(extraction_threads=-1))):
            best = None
            for k in range(args.repeat):
                spent.clear()
                t0 = time.perf_counter()
                traj = sfm_poses(work / "images", K, work / f"sfm_{len(rows)}_{k}", config=config)
                wall = time.perf_counter() - t0
                if best is None or wall < best[0]:
                    best = (wall, dict(spent), traj)
            rows[label] = best
        ref = rows["1 thread"][2]
        rot = np.eye(4)
        rot[:3, :3] = R1   # the rectified left camera -> the physical one poses_gt.txt describes
        print(f"\n{'':<22}" + "".join(f"{k:>14}" for k in rows) + f"{'ratio':>10}")
        for phase in ("wall", "extraction", "matching", "mapping"):
            keys = {"extraction": ("extract_features",), "matching": ("match_image_pairs", "match_exhaustive"),
                    "mapping": ("incremental_mapping",)}.get(phase)
            vals = [r[0] if keys is None else sum(r[1].get(k, 0.0) for k in keys) for r in rows.values()]
            print(f"{phase + ' (s)':<22}" + "".join(f"{v:>14.1f}" for v in vals) + f"{vals[1] / max(vals[0], 1e-9):>10.2f}")
        for label, (_, _, traj) in rows.items():
            ate = absolute_trajectory_error(Trajectory(traj.indices, traj.timestamps_s, traj.T_wc @ rot, traj.stats), gt)
            same = np.array_equal(traj.indices, ref.indices) and np.array_equal(traj.T_wc, ref.T_wc)
            print(f"{label}: {traj.stats['registered']}/{images} registered, ATE {100 * ate['rmse_rel_path']:.3f} % of "
                  f"the path, rotation {ate['rot_rmse_deg']:.3f} deg; poses identical to 1 thread's: {same}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
