"""Accuracy sweep of the measure stage on random synthetic truck scenes (not a test).

Each scene draws a truck (model scale 1-2.5 m or full scale 8-18 m, narrower cab or not), a
point spacing of length/200-400, noise up to half the spacing, up to 2% outliers, ground tilt up
to 30°, any heading, OpenCV-like or z-up axes, distractors, sometimes a parked second vehicle,
a side seen only partly and a density gradient. Prints per scene the signed relative errors of
length, width and height, whether |error| <= 2 x the reported uncertainty, and the rules used;
then the maximum and mean absolute errors.

Run:  .venv/bin/python benchmarks/bench_measure_accuracy.py [--scenes 24] [--seed 123]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from measure.pipeline import measure_points  # noqa: E402
from measure.synthetic_cloud import SceneSpec, TruckShape, make_truck_scene  # noqa: E402
from stereo_recon.core.errors import StereoReconError  # noqa: E402

DIMS = ("length", "width", "height")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=24)
    ap.add_argument("--seed", type=int, default=123)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    rows, covered, failures = [], [], 0
    for i in range(args.scenes):
        full = i % 2 == 0
        L = rng.uniform(8, 18) if full else rng.uniform(1.0, 2.5)
        W = L * rng.uniform(0.15, 0.25)
        H = W * rng.uniform(1.0, 1.6)
        shape = TruckShape(L, W, H, cab_width_m=W * rng.choice([1.0, 0.9]), cab_height_m=H * rng.uniform(0.7, 0.95))
        sp = L / rng.uniform(200, 400)
        noise = sp * rng.uniform(0, 0.5)
        spec = SceneSpec(spacing_m=sp, noise_m=noise, outlier_fraction=rng.uniform(0, 0.02), tilt_deg=rng.uniform(0, 30),
                         yaw_deg=rng.uniform(-180, 180), camera_frame=bool(rng.integers(2)), distractors=int(rng.integers(0, 6)),
                         second_vehicle_gap_m=float(sp * rng.uniform(10, 40)) if rng.random() < 0.5 else None,
                         partial_faces={"box_left": float(rng.uniform(0.3, 1))}, density_gradient=float(rng.uniform(0, 2)))
        pts, truth = make_truck_scene(shape, spec, rng=int(rng.integers(1_000_000_000)))
        try:
            m = measure_points(pts)
        except StereoReconError as err:
            failures += 1
            print(f"scene {i:2d}: FAILED: {err}")
            continue
        e = [(getattr(m, f"{d}_m") - truth[f"{d}_m"]) / truth[f"{d}_m"] * 100 for d in DIMS]
        c = [abs(getattr(m, f"{d}_m") - truth[f"{d}_m"]) <= 2 * m.uncertainty_m[d] for d in DIMS]
        rows.append(e)
        covered.append(c)
        print(f"scene {i:2d} {'full ' if full else 'model'} L={L:5.2f} m, {len(pts):7,d} pts, noise/spacing {noise / sp:.2f}: "
              f"error % L {e[0]:+.2f} W {e[1]:+.2f} H {e[2]:+.2f}; within 2u {c}; rules {m.rules['length']}, {m.rules['width']}, {m.rules['height']}")
    if rows:
        r = np.abs(np.asarray(rows))
        print(f"\n{len(rows)} scenes measured, {failures} failed; |error| % max L {r[:, 0].max():.2f} W {r[:, 1].max():.2f} H {r[:, 2].max():.2f}; "
              f"mean L {r[:, 0].mean():.3f} W {r[:, 1].mean():.3f} H {r[:, 2].mean():.3f}; covered by 2u: {100 * np.mean(covered):.0f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
