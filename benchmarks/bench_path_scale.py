"""How far each reconstructed camera path is off in scale, for one or two `stereo-recon bench --random` folders.

Every dimension of a far scene moves with the path's scale: the trajectory is rescaled to the rig's depth
(``MotionStereoConfig.scale_mode``), so this is the share of each dimension the reconstruction's scale explains.
For every draw with a ``runs/draw_*/poses.txt`` and the rendered path ``draws/draw_*/poses_gt.txt``, the
similarity (Umeyama) that best maps the run's camera centres onto the rendered ones gives the scale error
(+: the path, and the cloud, too large), printed per draw with the run's recorded rig ratio, then summarized
(mean |error|, bias, max) per scale (model, full). Given two folders (the same seed run with two versions),
the draws are set side by side.

Run:  .venv/bin/python benchmarks/bench_path_scale.py OUT [OTHER_OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stereo_recon.trajectory import align_trajectories, read_tum  # noqa: E402


def path_scale(run: Path, draw: Path) -> dict | None:
    """{scale_error_pct, rig_ratio, scale, kind, far} of one run against its draw (None: no poses)."""
    if not ((run / "poses.txt").is_file() and (draw / "poses_gt.txt").is_file()):
        return None
    truth = json.loads((draw / "truth.json").read_text())
    fps = float(truth.get("fps", 15.0))
    s, _, _ = align_trajectories(read_tum(run / "poses.txt", fps=fps), read_tum(draw / "poses_gt.txt", fps=fps))
    counts = json.loads((run / "run.json").read_text()).get("counts", {}) if (run / "run.json").is_file() else {}
    return {"scale_error_pct": 100 * (1 / s - 1), "rig_ratio": counts.get("trajectory_scale_from_rig"),
            "scale": truth.get("scale", "?"), "kind": (truth.get("random_spec") or {}).get("truck", {}).get("kind", truth.get("kind", "?")),
            "far": bool(counts.get("far_scene"))}


def folder(out: Path) -> dict[str, dict]:
    """Every draw's ``path_scale`` in a bench --random folder, by draw name."""
    res = {}
    for run in sorted((out / "runs").glob("draw_*")):
        r = path_scale(run, out / "draws" / run.name)
        if r is not None:
            res[run.name] = r
    return res


def summary(rows: list[dict]) -> str:
    """mean |error| / bias / max |error| (%) of the rows' scale errors."""
    e = np.array([r["scale_error_pct"] for r in rows])
    if not len(e):
        return "-"
    return f"n {len(e)}: mean |error| {np.abs(e).mean():.2f} %, bias {e.mean():+.2f} %, max |error| {np.abs(e).max():.2f} %"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="a `stereo-recon bench --random` output folder")
    ap.add_argument("other", type=Path, nargs="?", help="a second one (the same seed, another version)")
    args = ap.parse_args(argv)
    outs = [args.out] + ([args.other] if args.other else [])
    for o in outs:
        if not (o / "runs").is_dir():
            print(f"{o}: not a `stereo-recon bench --random` output folder (no runs/ in it)", file=sys.stderr)
            return 2
    res = [folder(o) for o in outs]
    names = sorted(set(res[0]) & set(res[-1]))
    if not names:
        print("no draw with a path in every folder", file=sys.stderr)
        return 2
    print(f"{'draw':10s} {'scale':5s} {'kind':8s} " + " | ".join(f"{str(o)[-24:]:>24s} (rig ratio)" for o in outs))
    for n in names:
        r0 = res[0][n]
        cells = []
        for r in res:
            x = r[n]
            rig = "-" if x["rig_ratio"] is None else f"{x['rig_ratio']:.4f}"
            cells.append(f"{x['scale_error_pct']:+23.2f}% ({rig:>6s})")
        print(f"{n:10s} {r0['scale']:5s} {r0['kind']:8s} " + " | ".join(cells))
    for o, r in zip(outs, res):
        print(f"{o}:")
        for sc in ("model", "full"):
            rows = [r[n] for n in names if r[n]["scale"] == sc]
            print(f"  {sc:5s} {summary(rows)}")
            far = [x for x in rows if x["far"]]
            if far and len(far) != len(rows):
                print(f"        far scenes only: {summary(far)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
