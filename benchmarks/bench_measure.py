"""Benchmark of the measure stage on one synthetic 10⁶-point truck scene (not a test).

Prints, side by side on the same cloud:
- FoF: ours (measure.fof) vs Open3D cluster_dbscan(min_points=1) vs scipy cKDTree.query_pairs +
  connected_components — wall time, ratio, and whether the partitions are identical;
  once on the whole scene (ground included) and once on the points left after ground removal
  (what the measure stage actually clusters);
- the whole measure stage (measure_points): wall time and peak memory, measured in a fresh
  subprocess (ru_maxrss) so earlier allocations do not count.

Run:  .venv/bin/python benchmarks/bench_measure.py [--points 1000000] [--skip-open3d] [--skip-scipy]
Targets (issue 2, 2-core machine): FoF <= 0.5 s and >= 10x faster than Open3D with the identical
partition; whole stage <= 3 s and <= 1.5 GB peak.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from measure.fof import fof_clusters, fof_reference_scipy, same_partition  # noqa: E402
from measure.synthetic_cloud import FULL_TRUCK, scene_with_n_points  # noqa: E402


def scene(n: int) -> tuple[np.ndarray, dict]:
    """The benchmark scene: a 12 x 2.55 x 4 m truck, a parked vehicle, posts, outliers, noise, tilt."""
    return scene_with_n_points(n, FULL_TRUCK, rng=0, noise_m=0.005, outlier_fraction=0.001, distractors=5,
                               second_vehicle_gap_m=1.0, tilt_deg=8.0, camera_frame=True)


def _best_of(fn, repeat: int) -> tuple[float, float, object]:
    """Best wall time, the CPU time of that run (all threads of this process), and the result."""
    best, cpu, out = float("inf"), float("nan"), None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        dt = time.perf_counter() - t
        if dt < best:
            best, cpu = dt, time.process_time() - c
    return best, cpu, out


def _open3d_labels(points, eps):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    lab = np.asarray(pc.cluster_dbscan(eps, 1, print_progress=False))
    u, c = np.unique(lab, return_counts=True)
    lab = lab.copy()
    lab[c[np.searchsorted(u, lab)] < 2] = -1   # Open3D gives singletons their own label; ours: -1
    return lab


def bench_fof(name: str, pts: np.ndarray, eps: float, args) -> None:
    t_ours, c_ours, ours = _best_of(lambda: fof_clusters(pts, eps), args.repeat)
    n_cl = int(ours.max()) + 1
    print(f"\nFoF on {name}: {len(pts):,} points, eps = {eps * 1000:.1f} mm -> {n_cl} clusters, {int((ours < 0).sum())} noise points")
    print(f"  {'implementation':<44} {'wall (s)':>9} {'cpu (s)':>8} {'ours faster (wall)':>19} {'same partition':>15}")
    print(f"  {'measure.fof.fof_clusters (best of %d)' % args.repeat:<44} {t_ours:9.3f} {c_ours:8.3f} {'':>19} {'':>15}")
    if not args.skip_open3d:
        t, c, lab = _best_of(lambda: _open3d_labels(pts, eps), 1)
        print(f"  {'open3d cluster_dbscan(min_points=1)':<44} {t:9.3f} {c:8.3f} {t / t_ours:18.1f}x {str(same_partition(ours, lab)):>15}")
    if not args.skip_scipy:
        t, c, lab = _best_of(lambda: fof_reference_scipy(pts, eps), 1)
        print(f"  {'scipy query_pairs + connected_components':<44} {t:9.3f} {c:8.3f} {t / t_ours:18.1f}x {str(same_partition(ours, lab)):>15}")


_CHILD = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, {root!r})
from measure.pipeline import measure_points

def vm_hwm_mb():
    # Peak resident set of this process image (VmHWM). ru_maxrss is not used: Linux carries the
    # parent's peak over fork+exec into it.
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")

pts = np.load({path!r})
measure_points(pts[:: max(1, len(pts) // 50_000)])   # warm-up: imports, first-call costs
try:
    open("/proc/self/clear_refs", "w").write("5")    # reset VmHWM to the current RSS
except OSError:
    pass
base = vm_hwm_mb()
t, c = time.perf_counter(), time.process_time()
m = measure_points(pts)
dt, dc = time.perf_counter() - t, time.process_time() - c
print(json.dumps({{"time_s": dt, "cpu_s": dc, "peak_rss_mb": vm_hwm_mb(), "rss_before_mb": base, "timings_s": m.timings_s,
                   "dims": [m.length_m, m.width_m, m.height_m], "rules": m.rules}}))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-open3d", action="store_true")
    ap.add_argument("--skip-scipy", action="store_true")
    args = ap.parse_args()

    import os

    print(f"cores: {os.cpu_count()}, load average {os.getloadavg()[0]:.1f} (timings are only comparable on an idle machine), numpy {np.__version__}")
    pts, truth = scene(args.points)
    from measure.ground import ground_plane, remove_ground
    from measure.resolution import point_resolution

    res = point_resolution(pts)
    eps = 3.0 * res   # MeasureConfig default: eps = 3 x resolution
    print(f"scene: {len(pts):,} points, resolution (median NN) {res * 1000:.1f} mm; truth {truth['length_m']} x {truth['width_m']} x {truth['height_m']} m")
    bench_fof("the whole scene (ground included)", pts, eps, args)
    g = ground_plane(pts, 2 * res)
    above = pts[remove_ground(pts, g, 3.5 * res)]
    bench_fof("the points above the ground (what measure clusters)", above, eps, args)

    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "scene.npy")
        np.save(path, pts)
        code = _CHILD.format(root=str(Path(__file__).resolve().parents[1]), path=path)
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"\nwhole measure stage (measure_points, fresh process, {len(pts):,} points):")
    print(f"  wall {r['time_s']:.2f} s, cpu {r['cpu_s']:.2f} s (target <= 3 s); peak RSS of the process {r['peak_rss_mb']:.0f} MB "
          f"(target <= 1536 MB; {r['rss_before_mb']:.0f} MB before the run: interpreter, libraries, the loaded cloud, a warm-up)")
    print("  stages: " + ", ".join(f"{k} {v:.3f} s" for k, v in r["timings_s"].items()))
    L, W, H = r["dims"]
    print(f"  measured {L:.3f} x {W:.3f} x {H:.3f} m vs truth {truth['length_m']} x {truth['width_m']} x {truth['height_m']} m; rules {r['rules']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
