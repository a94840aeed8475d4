"""The optional GPU rectification (``--gpu``) against the CPU path, side by side in one run.

Decodes frames of a side-by-side video, rectifies each raw pair on the CPU (``cv2.remap`` with the 16SC2
fixed-point maps the streaming pass uses) and on the GPU (``stereo_recon.gpu.GpuRectifier``, float maps),
then prints per-frame times (median; the GPU's after a warm-up, including the host<->device copies) and
what the difference does downstream: grey-level differences of the rectified images and of the default
SGBM disparity computed from each (px, and the share of pixels valid in one map only).

Needs torch with a CUDA device (the ``[gpu]`` extra); exits 2 with one line when there is none.

    python benchmarks/bench_gpu.py [--video sample_data/video.avi --calib sample_data/SN28000001.conf --frames 40]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", default=str(REPO / "sample_data" / "video.avi"))
    ap.add_argument("--calib", default=str(REPO / "sample_data" / "SN28000001.conf"))
    ap.add_argument("--frames", type=int, default=40, help="frames to compare (default 40)")
    ap.add_argument("--disparity-every", type=int, default=4, help="compare SGBM disparities on every N-th frame")
    a = ap.parse_args(argv)

    from stereo_recon import gpu

    if not gpu.cuda_available():
        print("bench_gpu: torch with a CUDA device is not available (pip install -e '.[gpu]' on a CUDA machine)")
        return 2
    import cv2
    import torch

    from calib.io import parse_calib_arg
    from stereo_recon.disparity import DisparityConfig, disparity_map
    from stereo_recon.rectifier import Rectifier
    from stereo_recon.video import open_stereo_source

    src = open_stereo_source(a.video, frame_range=(0, a.frames))
    frames = list(src)
    h, w = frames[0].left.shape[:2]
    rig = parse_calib_arg(a.calib, (w, h))
    cpu = Rectifier(rig, use_gpu=False)
    gpu_r = Rectifier(rig, use_gpu=True)
    rect_f = rig.rectification(alpha=0.0)  # float maps: the CPU reference for what the map type alone does
    fmx, fmy = rect_f.map_left
    inside = (fmx > 1) & (fmx < w - 2) & (fmy > 1) & (fmy < h - 2)

    def versus(ref, other):
        """|ref - other| (px) where both disparities are valid, and the share of pixels valid in one only."""
        both = np.isfinite(ref) & np.isfinite(other) & inside
        one = (np.isfinite(ref) ^ np.isfinite(other)) & inside
        return np.abs(ref - other)[both], one.sum() / max(inside.sum(), 1)

    pairs = [(f.left, cv2.cvtColor(f.right, cv2.COLOR_BGR2GRAY)) for f in frames]
    for lb, rg in pairs[:3]:  # warm-up: CUDA context, kernels, cv2's thread pool
        gpu_r(lb, rg)
        cpu(lb, rg)
    t_cpu, t_gpu, d_img, d_disp, only_one, d_ref, only_ref = [], [], [], [], [], [], []
    for i, (lb, rg) in enumerate(pairs):
        t0 = time.perf_counter()
        cl, cr = cpu(lb, rg)
        t_cpu.append(time.perf_counter() - t0)
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        gl, gr = gpu_r(lb, rg)
        t_gpu.append(time.perf_counter() - t0)
        diff = np.abs(gl.astype(np.int16) - cl.astype(np.int16))
        d_img.append(diff[inside].ravel())
        if i % a.disparity_every == 0:
            dc = disparity_map(cv2.cvtColor(cl, cv2.COLOR_BGR2GRAY), cr, DisparityConfig())
            dg = disparity_map(cv2.cvtColor(gl, cv2.COLOR_BGR2GRAY), gr, DisparityConfig())
            diff_g, one_g = versus(dc, dg)
            d_disp.append(diff_g)
            only_one.append(one_g)
            # The same comparison on the CPU alone (float maps against 16SC2): how much SGBM moves when the
            # images move by the map type's sub-grey-level rounding, with no GPU involved.
            fl = cv2.remap(cv2.cvtColor(lb, cv2.COLOR_BGR2GRAY), *rect_f.map_left, cv2.INTER_LINEAR)
            fr_ = cv2.remap(rg, *rect_f.map_right, cv2.INTER_LINEAR)
            df = disparity_map(fl, fr_, DisparityConfig())
            diff_f, one_f = versus(dc, df)
            d_ref.append(diff_f)
            only_ref.append(one_f)
    di = np.concatenate(d_img)
    dd = np.concatenate(d_disp)
    dr = np.concatenate(d_ref)
    name = torch.cuda.get_device_name(0)
    print(f"bench_gpu: {len(pairs)} frames of {Path(a.video).name} ({w}x{h} per eye); GPU {name}; torch {torch.__version__}")
    print("| quantity | CPU (cv2.remap, 16SC2) | GPU (grid_sample, float maps) |")
    print("|---|---|---|")
    print(f"| rectify one pair, median ms | {1e3 * statistics.median(t_cpu):.2f} | {1e3 * statistics.median(t_gpu):.2f} "
          f"(ratio GPU/CPU {statistics.median(t_gpu) / statistics.median(t_cpu):.2f}) |")
    print(f"| rectified grey levels, GPU - CPU | | mean {di.mean():.3f}, p99 {np.percentile(di, 99):.0f}, "
          f"max {di.max()} |")
    # Batched, as a batch job could call it (the streaming pass rectifies one pair at a time).
    lbs = np.stack([p[0] for p in pairs[:8]])
    rgs = np.stack([p[1] for p in pairs[:8]])
    gpu_r.gpu.rectify_batch(lbs, rgs)
    t_b = []
    for _ in range(5):
        t0 = time.perf_counter()
        gpu_r.gpu.rectify_batch(lbs, rgs)
        t_b.append((time.perf_counter() - t0) / len(lbs))
    print(f"| rectify in batches of {len(lbs)}, median ms per pair | | {1e3 * statistics.median(t_b):.2f} |")

    def spread(x, one):
        return (f"median {np.median(x):.4f} px, p99 {np.percentile(x, 99):.3f} px, > 0.5 px "
                f"{100 * np.mean(x > 0.5):.2f} %; valid in one map only {100 * float(np.mean(one)):.2f} %")

    print(f"| SGBM disparity against the CPU path's ({len(d_disp)} frames) | CPU float maps: {spread(dr, only_ref)} "
          f"| {spread(dd, only_one)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
