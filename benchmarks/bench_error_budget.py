"""Where a `stereo-recon bench` run's width and height errors come from (not a test).

For every truck of a bench folder (``runs/NAME`` next to ``scenes/NAME``, as ``stereo-recon bench
--out DIR`` writes them), it splits the measured error into:

- odometry's scale: the similarity (Umeyama) that best maps the run's camera centres onto the
  rendered ones; its scale minus 1 is the share of every dimension that the trajectory explains;
- the cloud's faces: with that similarity and the truck's true pose, each point lands in the truck
  frame (x forward, y left, z up, origin on the ground at the truck's centre); the median signed
  offset of the side walls (outwards positive, mm) and of the roof (up positive) says how far the
  fused surfaces sit from the true ones. Walls are read on the middle of the body (x within
  -0.4 L .. +0.2 L, z within 0.3 H .. 0.7 H, points within 0.03 W + 1 cm of the wall);
- the measurement's own share: measured error minus (scale + wall offsets), for the width.

Flatbeds have no side walls (their width is the deck's edge): their wall columns read "-".

Run:  .venv/bin/python benchmarks/bench_error_budget.py DIR   (DIR: the --out of stereo-recon bench)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from measure.cloud_io import read_cloud  # noqa: E402
from stereo_recon.trajectory import align_trajectories, read_tum  # noqa: E402


def face_offsets_mm(points_truck: np.ndarray, L: float, W: float, H: float, walls: bool) -> dict:
    """Median signed offsets (mm) of the left/right walls (outwards +) and the roof (up +) from the truth.

    points_truck: (N, 3) m in the truck frame (x forward, y left, z up, ground z = 0).
    """
    x, y, z = points_truck.T
    mid = (x > -0.4 * L) & (x < 0.2 * L)
    out = {"wall_left_mm": np.nan, "wall_right_mm": np.nan, "roof_mm": np.nan}
    if walls:
        band = mid & (z > 0.3 * H) & (z < 0.7 * H)
        for key, side in (("wall_left_mm", 1.0), ("wall_right_mm", -1.0)):
            d = side * y[band] - W / 2
            d = d[np.abs(d) < 0.03 * W + 0.01]
            if len(d) >= 50:
                out[key] = 1000 * float(np.median(d))
    roof = mid & (np.abs(y) < 0.3 * W) & (np.abs(z - H) < 0.03 * H)
    if roof.sum() >= 50:
        out["roof_mm"] = 1000 * float(np.median(z[roof] - H))
    return out


def budget(run_dir: Path, scene_dir: Path) -> dict:
    """The error split of one truck (see the module docstring)."""
    truth = json.loads((scene_dir / "truth.json").read_text())
    fps = float(truth.get("fps", 15.0))
    s, R, t = align_trajectories(read_tum(run_dir / "poses.txt", fps=fps), read_tum(scene_dir / "poses_gt.txt", fps=fps))
    T_wt = np.asarray(truth["truck"]["T_world_truck"], dtype=np.float64)
    world = s * (read_cloud(run_dir / "cloud.ply") @ R.T) + t
    truck = (world - T_wt[:3, 3]) @ T_wt[:3, :3]
    L, W, H = truth["length_m"], truth["width_m"], truth["height_m"]
    body = truth["truck"].get("body", "box")
    faces = face_offsets_mm(truck, L, W, H, walls=body != "flatbed")
    m = json.loads((run_dir / "measurement.json").read_text())
    w_err = 100 * (m["width_m"] / W - 1)
    h_err = 100 * (m["height_m"] / H - 1)
    scale_pct = 100 * (1 / s - 1)  # the run's cloud is 1/s times the true size (trajectory.scale_error)
    walls_pct = 100 * (faces["wall_left_mm"] + faces["wall_right_mm"]) / 1000 / W
    return {"name": run_dir.name, "body": body, "scale_pct": scale_pct, **faces, "width_err_pct": w_err,
            "width_from_walls_pct": walls_pct, "width_measurement_pct": w_err - scale_pct - walls_pct,
            "height_err_pct": h_err, "height_from_roof_pct": 100 * faces["roof_mm"] / 1000 / H}


def _fmt(v: float, unit: str = "") -> str:
    return f"{v:+.2f}{unit}" if np.isfinite(v) else "-"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bench_dir", type=Path)
    args = ap.parse_args()
    runs = sorted((p for p in (args.bench_dir / "runs").glob("*") if (p / "cloud.ply").is_file()),
                  key=lambda p: (not p.name.startswith("table2"), len(p.name), p.name))
    if not runs:
        print(f"{args.bench_dir}: no runs/*/cloud.ply (expected the --out folder of stereo-recon bench)", file=sys.stderr)
        return 2
    rows = []
    print(f"{'truck':13s} {'body':8s} {'scale':>7s} {'wall L':>7s} {'wall R':>7s} {'roof':>7s} | "
          f"{'W err':>7s} = {'scale':>6s} + {'walls':>6s} + {'meas.':>6s} | {'H err':>6s} {'roof':>6s}")
    for rd in runs:
        sd = args.bench_dir / "scenes" / rd.name
        if not (sd / "truth.json").is_file():
            continue
        r = budget(rd, sd)
        rows.append(r)
        f = _fmt
        print(f"{r['name']:13s} {r['body']:8s} {f(r['scale_pct'], '%'):>7s} {f(r['wall_left_mm']):>7s} "
              f"{f(r['wall_right_mm']):>7s} {f(r['roof_mm']):>7s} | {f(r['width_err_pct'], '%'):>7s} = "
              f"{f(r['scale_pct']):>6s} + {f(r['width_from_walls_pct']):>6s} + {f(r['width_measurement_pct']):>6s} | "
              f"{f(r['height_err_pct'], '%'):>6s} {f(r['height_from_roof_pct']):>6s}")
    walls = [r for r in rows if np.isfinite(r["width_from_walls_pct"]) and r["name"].startswith("table2")]
    if walls:
        med = {k: float(np.median([r[k] for r in walls])) for k in
               ("scale_pct", "width_err_pct", "width_from_walls_pct", "width_measurement_pct")}
        print(f"model trucks with side walls ({len(walls)}), medians: width error {med['width_err_pct']:+.2f} % = "
              f"scale {med['scale_pct']:+.2f} + walls {med['width_from_walls_pct']:+.2f} + measurement "
              f"{med['width_measurement_pct']:+.2f} (percentage points; medians do not add up exactly)")
        wl = np.array([[r["wall_left_mm"], r["wall_right_mm"]] for r in walls])
        print(f"  wall offsets (mm, outwards +): median {np.median(wl):+.2f}, per wall from {wl.min():+.2f} to {wl.max():+.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
