"""Batch benchmark: N copies of the bundled sample through ``batch`` on a local 2-CPU Ray instance vs the
local process pool with 2 workers (issue 16 target: Ray overhead <= 10 % of the pool's wall time on 4 videos).

Each side is the whole command a user runs (``stereo-recon batch ...`` in a fresh process: imports, Ray's
start-up and shut-down, the job folders travelling back to the driver, summary.csv), timed by wall clock.
The two sides alternate, ``--repeats`` times each, so that load from other work on the machine hits both
alike; the best time of each side is compared. The Ray side's cloud.ply files must equal the pool's byte for byte.

Ray sets OMP_NUM_THREADS to each task's CPUs (1 here); the pool's processes keep all threads unless
``--pool-omp-threads 1`` gives them the same cap.

Run:  .venv/bin/python benchmarks/bench_batch.py [--videos 4] [--repeats 2] [--frames N] [--pool-omp-threads 1]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data"


def _videos(folder: Path, n: int, frames: int | None) -> list[Path]:
    """``n`` recordings: copies of the sample (or of its first ``frames`` frames), each under its own name."""
    src = SAMPLE / "video.avi"
    if frames is not None:
        import cv2

        cap = cv2.VideoCapture(str(src))
        fps = cap.get(cv2.CAP_PROP_FPS)
        cut = folder / "cut.avi"
        writer = None
        for _ in range(frames):
            ok, frame = cap.read()
            if not ok:
                break
            if writer is None:
                writer = cv2.VideoWriter(str(cut), cv2.VideoWriter_fourcc(*"MJPG"), fps, (frame.shape[1], frame.shape[0]))
            writer.write(frame)
        writer.release()
        src = cut
    out = []
    for i in range(n):
        dst = folder / f"flight{i + 1}.avi"
        shutil.copyfile(src, dst)
        out.append(dst)
    return out


def _batch(videos: list[Path], out: Path, options: list[str], extra_env: dict | None = None) -> float:
    """Wall seconds of one ``stereo-recon batch`` command (fails loudly if it does)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
           "MPLBACKEND": "Agg", **(extra_env or {})}
    cmd = [sys.executable, "-m", "stereo_recon.app.cli", "-q", "batch", *map(str, videos), "--calib",
           str(SAMPLE / "SN28000001.conf"), "--out", str(out), *options]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return wall


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--videos", type=int, default=4, help="recordings per batch (default 4)")
    ap.add_argument("--repeats", type=int, default=2, help="runs of each side, alternating (default 2)")
    ap.add_argument("--frames", type=int, default=None, help="use only the sample's first N frames (default: all 48)")
    ap.add_argument("--pool-omp-threads", type=int, default=None,
                    help="OMP_NUM_THREADS for the pool's processes (Ray sets it to each task's CPUs; default: unset)")
    args = ap.parse_args()
    try:
        import ray  # noqa: F401
    except ImportError:
        sys.exit("bench_batch: Ray is not installed (pip install -e .[ray])")

    sides = {"local pool, --workers 2": ["--executor", "local", "--workers", "2"],
             "Ray, local 2-CPU instance": ["--executor", "ray", "--workers", "2"]}
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        tmp = Path(tmp)
        videos = _videos(tmp, args.videos, args.frames)
        walls: dict[str, list[float]] = {k: [] for k in sides}
        for rep in range(args.repeats):
            order = list(sides) if rep % 2 == 0 else list(sides)[::-1]
            for side in order:
                out = tmp / f"out-{rep}-{list(sides).index(side)}"
                extra = {"OMP_NUM_THREADS": str(args.pool_omp_threads)} if args.pool_omp_threads and "pool" in side else None
                walls[side].append(_batch(videos, out, sides[side], extra))
                print(f"  {side}: {walls[side][-1]:.1f} s", flush=True)
        for v in videos:  # same recordings, same clouds, whichever executor ran them
            ref = (tmp / "out-0-0" / v.stem / "cloud.ply").read_bytes()
            assert (tmp / "out-0-1" / v.stem / "cloud.ply").read_bytes() == ref, f"{v.stem}: clouds differ"
    local, ray_ = (min(walls[k]) for k in sides)
    omp = f" (OMP_NUM_THREADS={args.pool_omp_threads})" if args.pool_omp_threads else ""
    print(f"{args.videos} sample videos ({args.frames or 48} frames each), best of {args.repeats}: local pool --workers 2{omp} "
          f"{local:.1f} s, Ray local 2-CPU instance {ray_:.1f} s, ratio {ray_ / local:.3f} "
          f"(Ray overhead {100 * (ray_ / local - 1):+.1f} %; target <= +10 %); clouds identical")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
