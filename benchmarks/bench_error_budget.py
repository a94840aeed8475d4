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

Flatbeds have no side walls (their width is the deck's edge): their wall columns read "-". A tanker's
"walls" are its tank's flanks at their widest height: each point's offset from the true elliptic shell
(``stereo_recon.synthetic.scene.truck_layout``: semi-axes W/2 and half the tank's height) on the same
stretch of the body, within 15 % of the tank's half height of its widest line. Where the run records its
TSDF voxel (run.json ``voxel_m``), the walls' mean offset is also given in voxels: the fusion's grid is the
scale a surface's offset is judged at (a full-scale voxel is 20-50 mm, a model's 3-10 mm).

Run:  .venv/bin/python benchmarks/bench_error_budget.py DIR   (DIR: the --out of stereo-recon bench,
      a Table 2 bench's runs/ and scenes/ or a ``bench --random`` one's runs/ and draws/)
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


def face_offsets_mm(points_truck: np.ndarray, L: float, W: float, H: float, walls: bool,
                    tank: tuple[float, float] | None = None) -> dict:
    """Median signed offsets (mm) of the left/right walls (outwards +) and the roof (up +) from the truth.

    points_truck: (N, 3) m in the truck frame (x forward, y left, z up, ground z = 0). tank: (centre height,
    vertical semi-axis) of an elliptic tank (m; horizontal semi-axis W/2): its walls are the flanks about the
    widest line, each point's horizontal offset from the shell at its height (None: flat walls at +-W/2).
    """
    x, y, z = points_truck.T
    mid = (x > -0.4 * L) & (x < 0.2 * L)
    out = {"wall_left_mm": np.nan, "wall_right_mm": np.nan, "roof_mm": np.nan}
    if walls and tank is not None:
        zc, b = tank
        u = (z - zc) / b
        band = mid & (np.abs(u) < 0.15)
        shell = 0.5 * W * np.sqrt(np.clip(1.0 - u * u, 0.0, 1.0))
        for key, side in (("wall_left_mm", 1.0), ("wall_right_mm", -1.0)):
            d = side * y[band] - shell[band]
            d = d[(side * y[band] > 0) & (np.abs(d) < 0.03 * W + 0.01)]
            if len(d) >= 50:
                out[key] = 1000 * float(np.median(d))
    elif walls:
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
    faces = face_offsets_mm(truck, L, W, H, walls=body != "flatbed", tank=_tank_axes(truth) if body == "tanker" else None)
    m = json.loads((run_dir / "measurement.json").read_text())
    w_err = 100 * (m["width_m"] / W - 1)
    h_err = 100 * (m["height_m"] / H - 1)
    scale_pct = 100 * (1 / s - 1)  # the run's cloud is 1/s times the true size (trajectory.scale_error)
    walls_pct = 100 * (faces["wall_left_mm"] + faces["wall_right_mm"]) / 1000 / W
    run_json = run_dir / "run.json"
    voxel = json.loads(run_json.read_text()).get("voxel_m") if run_json.is_file() else None
    walls_vox = 0.5 * (faces["wall_left_mm"] + faces["wall_right_mm"]) / 1000 / voxel if voxel else np.nan
    return {"name": run_dir.name, "body": body, "scale_pct": scale_pct, **faces, "walls_voxels": walls_vox, "width_err_pct": w_err,
            "width_from_walls_pct": walls_pct, "width_measurement_pct": w_err - scale_pct - walls_pct,
            "height_err_pct": h_err, "height_from_roof_pct": 100 * faces["roof_mm"] / 1000 / H}


def _tank_axes(truth: dict) -> tuple[float, float]:
    """(centre height, vertical semi-axis) of a rendered tanker's elliptic tank (m), from its truth.json."""
    from stereo_recon.synthetic.scene import TruckSpec, truck_layout

    t = truth["truck"]
    spec = TruckSpec(length_m=truth["length_m"], width_m=truth["width_m"], height_m=truth["height_m"], body="tanker",
                     cab_length_frac=t.get("cab_length_frac"), cab_height_frac=t.get("cab_height_frac"))
    z_floor = truck_layout(spec).z_floor_m
    return 0.5 * (z_floor + spec.height_m), 0.5 * (spec.height_m - z_floor)


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
    print(f"{'truck':13s} {'body':8s} {'scale':>7s} {'wall L':>7s} {'wall R':>7s} {'voxels':>6s} {'roof':>7s} | "
          f"{'W err':>7s} = {'scale':>6s} + {'walls':>6s} + {'meas.':>6s} | {'H err':>6s} {'roof':>6s}")
    for rd in runs:
        # A Table 2 bench keeps its scenes in scenes/, a ``bench --random`` one its draws in draws/.
        sd = next((d / rd.name for d in (args.bench_dir / "scenes", args.bench_dir / "draws")
                   if (d / rd.name / "truth.json").is_file()), None)
        if sd is None or not (rd / "measurement.json").is_file():
            continue
        r = budget(rd, sd)
        rows.append(r)
        f = _fmt
        print(f"{r['name']:13s} {r['body']:8s} {f(r['scale_pct'], '%'):>7s} {f(r['wall_left_mm']):>7s} "
              f"{f(r['wall_right_mm']):>7s} {f(r['walls_voxels']):>6s} {f(r['roof_mm']):>7s} | {f(r['width_err_pct'], '%'):>7s} = "
              f"{f(r['scale_pct']):>6s} + {f(r['width_from_walls_pct']):>6s} + {f(r['width_measurement_pct']):>6s} | "
              f"{f(r['height_err_pct'], '%'):>6s} {f(r['height_from_roof_pct']):>6s}")
    for body in sorted({r["body"] for r in rows}):
        vox = [r["walls_voxels"] for r in rows if r["body"] == body and np.isfinite(r["walls_voxels"])]
        if vox:
            print(f"{body}: walls' mean offset {np.median(vox):+.2f} voxels (median of {len(vox)} trucks, "
                  f"{np.min(vox):+.2f} to {np.max(vox):+.2f})")
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
