"""Calibrate the reconstruction error model's ``k_px`` (stereo_recon.app.uncertainty) on tuning runs (not a test).

For every finished run (``run_dir@scene_dir``: a run folder with cloud.ply, poses.txt and run.json, and the
rendered scene with truth.json), the cloud is measured again with the current measure code. A run whose
face gates refuse a dimension is left out of that dimension (it reports no number). For each measured
dimension the disparity error k (px) that would put the truth exactly at the edge of the reported +-2 sigma is

    k = sqrt(max(0, (|error| / 2)^2 - sigma_measurement^2 - (rel_floor x value)^2)) / e_Z

with e_Z = Z^2 / (f B) from run.json, as the model itself computes it (``depth_sigma_m``). The model's k is the q-quantile (default 90 %)
of those, per dimension and depth mode (rig baseline or motion stereo). Runs only from tuning seeds and
tuning scenes: never the evaluation seed or the external renders.

Run:  .venv/bin/python benchmarks/calibrate_depth_sigma.py RUN@SCENE ... [--quantile 0.9]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from measure.cloud_io import read_cloud  # noqa: E402
from measure.limits import DIMENSIONS as DIMS  # noqa: E402
from measure.pipeline import MeasureConfig, measure_points  # noqa: E402
from measure.quality import _CHECK_DIMENSIONS, face_checks  # noqa: E402
from stereo_recon.app.pipeline import RECONSTRUCTION_REL_SIGMA, _camera_centres  # noqa: E402
from stereo_recon.app.uncertainty import ReconstructionErrorModel, depth_sigma_m  # noqa: E402


def needed_k(run: Path, scene: Path) -> dict | None:
    """{mode, Z_m, e_z, k: {dim: px or None}, err: {dim: %}} for one run; None when it cannot be measured."""
    meta = json.loads((run / "run.json").read_text())
    sigma, parts = depth_sigma_m(meta)
    truth = json.loads((scene / "truth.json").read_text())
    if sigma is None or not (run / "cloud.ply").is_file():
        return None
    geo, e_z = parts["geometry"], parts["e_z_m_per_px"]
    cams = _camera_centres(run / "poses.txt")
    try:
        m = measure_points(read_cloud(run / "cloud.ply"), MeasureConfig(), up_hint=meta.get("up"),
                           centre_hint=None if cams is None else cams.mean(axis=0), rng=0)
    except Exception as err:  # noqa: BLE001 - a failed measurement is reported and skipped
        print(f"  {run}: not measured ({str(err)[:80]})")
        return None
    refused = {d for c in face_checks(m) if c["status"] == "fail" for d in _CHECK_DIMENSIONS.get(c["name"], ())}
    out = {"mode": "wide" if geo["motion_stereo"] else "rig", "Z_m": geo["Z_m"], "e_z": e_z, "k": {}, "err": {}}
    for d in DIMS:
        v, t = getattr(m, f"{d}_m"), truth[f"{d}_m"]
        out["err"][d] = 100 * (v / t - 1)
        if d in refused:
            out["k"][d] = None
            continue
        rest = (abs(v - t) / 2) ** 2 - m.uncertainty_m[d] ** 2 - (RECONSTRUCTION_REL_SIGMA[d] * v) ** 2
        out["k"][d] = float(np.sqrt(max(rest, 0.0)) / e_z)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pairs", nargs="+", help="RUN_DIR@SCENE_DIR")
    ap.add_argument("--quantile", type=float, default=0.9)
    args = ap.parse_args()
    rows = []
    for pair in args.pairs:
        run, scene = (Path(x) for x in pair.split("@"))
        r = needed_k(run, scene)
        if r is None:
            continue
        rows.append(r)
        ks = " ".join(f"{d[0].upper()} {r['err'][d]:+6.2f}% k {'-' if r['k'][d] is None else format(r['k'][d], '.3f')}" for d in DIMS)
        print(f"{run}: {r['mode']:4s} Z {r['Z_m']:.2f} m e_Z {1000 * r['e_z']:.2f} mm/px  {ks}")
    base = ReconstructionErrorModel()
    for mode, current in (("rig", base.rig_px), ("wide", base.wide_px)):
        sel = [r for r in rows if r["mode"] == mode]
        if not sel:
            continue
        q = {}
        for d in DIMS:
            ks = [r["k"][d] for r in sel if r["k"][d] is not None]
            q[d] = float(np.quantile(ks, args.quantile)) if ks else float("nan")
        print(f"{mode}: {len(sel)} runs; k_px at the {100 * args.quantile:.0f} % quantile: "
              + ", ".join(f"{d} {q[d]:.3f} (now {current[d]:.3f})" for d in DIMS))


if __name__ == "__main__":
    main()
