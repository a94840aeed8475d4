"""Calibrate the reconstruction error model's ``k_px`` (stereo_recon.app.uncertainty) on tuning runs (not a test).

For every finished run (``run_dir@scene_dir``: a run folder with cloud.ply, poses.txt and run.json, and the
rendered scene with truth.json), the cloud is measured again with the current measure code, as ``run`` measures it
(its hints, its checks: ``reconstruction_measure_args``). A run that a data-quality gate refuses is left out whole, as
``run`` reports no number for it (any failed gate makes the verdict undecided and the bench counts the draw as failed). For each measured
dimension the disparity error k (px) that would put the truth exactly at the edge of the reported +-2 sigma is

    k = sqrt(max(0, (|error| / 2)^2 - sigma_measurement^2 - (rel_floor x value)^2)) / e_Z

with e_Z = Z^2 / (f B) from run.json, as the model itself computes it (``depth_sigma_m``). The model's k is the q-quantile (default 90 %)
of those, per dimension and depth mode (rig baseline or motion stereo), taken as the order statistic at or above it
(numpy's ``method="higher"``): the smallest k under which at least q of the tuning dimensions have their truth inside
+-2 sigma. (Interpolating between order statistics made k jump where most runs need 0 and a few much more.)
``--leave-one-out`` also prints, per held-out group of runs (the seed folder, e.g. ``envelope-2035``), the share of
its dimensions the k calibrated on the others covers: what to expect on a seed not tuned on. Runs only from tuning seeds and
tuning scenes: never the evaluation seed or the external renders.

Run:  .venv/bin/python benchmarks/calibrate_depth_sigma.py RUN@SCENE ... [--quantile 0.9] [--leave-one-out]
      (in parts: ``... RUN@SCENE ... --rows-out part1.json``, then ``... --rows-in part1.json part2.json``)
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from measure.limits import DIMENSIONS as DIMS  # noqa: E402
from measure.pipeline import MeasureConfig, measure_cloud_file  # noqa: E402
from stereo_recon.app.pipeline import RECONSTRUCTION_REL_SIGMA, RunConfig, reconstruction_measure_args  # noqa: E402
from stereo_recon.app.uncertainty import ReconstructionErrorModel, depth_sigma_m  # noqa: E402


def needed_k(run: Path, scene: Path) -> dict | None:
    """{mode, Z_m, e_z, k: {dim: px}, err: {dim: %}} for one run, measured as ``run`` measures it (its hints and
    checks); None when it cannot be measured or a data-quality gate refuses it."""
    meta = json.loads((run / "run.json").read_text())
    sigma, parts = depth_sigma_m(meta)
    truth = json.loads((scene / "truth.json").read_text())
    if sigma is None or not (run / "cloud.ply").is_file():
        return None
    geo, e_z = parts["geometry"], parts["e_z_m_per_px"]
    with tempfile.TemporaryDirectory() as tmp:
        try:
            res = measure_cloud_file(run / "cloud.ply", Path(tmp) / "m", config=MeasureConfig(), plots=False, html=False,
                                     **reconstruction_measure_args(run / "run.json", run / "poses.txt", RunConfig()))
        except Exception as err:  # noqa: BLE001 - a failed measurement is reported and skipped
            print(f"  {run}: not measured ({str(err)[:80]})")
            return None
    failed = [c["name"] for c in res["data_quality"]["checks"] if c["status"] == "fail"]
    if failed:
        print(f"  {run}: refused by {', '.join(failed)}")
        return None
    out = {"run": str(run), "mode": "wide" if geo["motion_stereo"] else "rig", "Z_m": geo["Z_m"], "e_z": e_z, "k": {}, "err": {}}
    u_meas = res.get("uncertainty_parts", {}).get("measurement_m", res["uncertainty_m"])
    for d in DIMS:
        v, t = res[f"{d}_m"], truth[f"{d}_m"]
        out["err"][d] = 100 * (v / t - 1)
        rest = (abs(v - t) / 2) ** 2 - u_meas[d] ** 2 - (RECONSTRUCTION_REL_SIGMA[d] * v) ** 2
        out["k"][d] = float(np.sqrt(max(rest, 0.0)) / e_z)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pairs", nargs="*", help="RUN_DIR@SCENE_DIR")
    ap.add_argument("--rows-out", type=Path, help="also write the measured runs' needed k (JSON), to combine parts run apart")
    ap.add_argument("--rows-in", type=Path, nargs="*", default=[], help="needed k written by --rows-out, taken as measured")
    ap.add_argument("--quantile", type=float, default=0.9)
    ap.add_argument("--leave-one-out", action="store_true", help="coverage of each seed folder under the k of the others")
    args = ap.parse_args()
    if not args.pairs and not args.rows_in:
        ap.error("give RUN_DIR@SCENE_DIR pairs to measure, or --rows-in files written by --rows-out")
    rows = [r for f in args.rows_in for r in json.loads(f.read_text())]
    for pair in args.pairs:
        run, scene = (Path(x) for x in pair.split("@"))
        r = needed_k(run, scene)
        if r is None:
            continue
        rows.append(r)
        ks = " ".join(f"{d[0].upper()} {r['err'][d]:+6.2f}% k {r['k'][d]:.3f}" for d in DIMS)
        print(f"{run}: {r['mode']:4s} Z {r['Z_m']:.2f} m e_Z {1000 * r['e_z']:.2f} mm/px  {ks}")
    if args.rows_out:
        args.rows_out.write_text(json.dumps(rows))
    base = ReconstructionErrorModel()
    for mode, current in (("rig", base.rig_px), ("wide", base.wide_px)):
        sel = [r for r in rows if r["mode"] == mode]
        if not sel:
            continue
        q = {d: _k_at(sel, d, args.quantile) for d in DIMS}
        print(f"{mode}: {len(sel)} runs; k_px at the {100 * args.quantile:.0f} % quantile: "
              + ", ".join(f"{d} {q[d]:.3f} (now {current[d]:.3f})" for d in DIMS))
    if args.leave_one_out:
        _leave_one_out(rows, args.quantile)


def _k_at(rows: list[dict], d: str, quantile: float) -> float:
    """The smallest k (px) of dimension d under which at least ``quantile`` of the rows have the truth inside +-2 sigma."""
    return float(np.quantile([r["k"][d] for r in rows], quantile, method="higher")) if rows else float("nan")


def _group(run: str) -> str:
    """The folder a run belongs to (``out/envelope-2035/runs/draw_003`` -> ``envelope-2035``)."""
    parts = Path(run).parts
    return parts[-3] if len(parts) >= 3 else parts[0]


def _leave_one_out(rows: list[dict], quantile: float) -> None:
    """Per group: the share of its dimensions inside +-2 sigma under the k calibrated on the other groups."""
    inside_all = []
    for g in sorted({_group(r["run"]) for r in rows}):
        inside = []
        for mode in ("rig", "wide"):
            train = [r for r in rows if r["mode"] == mode and _group(r["run"]) != g]
            test = [r for r in rows if r["mode"] == mode and _group(r["run"]) == g]
            if not train:
                continue
            for d in DIMS:
                k = _k_at(train, d, quantile)
                inside += [r["k"][d] <= k + 1e-12 for r in test]
        if inside:
            print(f"held out {g}: {100 * np.mean(inside):.1f} % of {len(inside)} dimensions inside +-2 sigma")
            inside_all += inside
    print(f"leave-one-out, all: {100 * np.mean(inside_all):.1f} % of {len(inside_all)} dimensions")


if __name__ == "__main__":
    main()
