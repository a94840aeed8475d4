"""Re-measure finished run folders with the current measure code, as ``run`` does, against each scene's truth.

Why: a change to the measure stage (a rule, an uncertainty term) is judged on clouds already reconstructed,
without re-running the reconstruction. Each RUN folder (cloud.ply, run.json, poses.txt of ``stereo-recon run``
or ``bench``) is measured with ``run``'s hints and uncertainty terms (the reconstruction's relative error and
its depth geometry, the reconstruction's data-quality checks), nothing is written into it, and the errors
against SCENE/truth.json are summarized: mean absolute error per dimension, the share of dimensions whose
truth lies inside the reported +-2 sigma (all, and for the draws no data-quality gate refused), and the
verdicts.

Usage::

    python benchmarks/remeasure_runs.py OUT/runs/draw_000:OUT/draws/draw_000 ...    # bench --random folders
    python benchmarks/remeasure_runs.py --bench OUT                                   # every draw of a bench --random OUT
    python benchmarks/remeasure_runs.py --bench OUT --measure '{"top_above_roof_sigmas": 3}'   # with measure overrides
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

DIMS = ("length", "width", "height")


def remeasure(run: Path, scene: Path, overrides: dict | None = None) -> dict:
    """One run folder measured as ``run`` measures it: {name, error_pct, z (|error| / sigma), gated, verdict} or {name, failed}.

    overrides: ``measure`` config keys (as in a ``--config`` file's measure section) replacing the defaults.
    """
    from measure.pipeline import config_from_dict, measure_cloud_file
    from stereo_recon.app.bench import verdict_matches
    from stereo_recon.app.pipeline import RunConfig, reconstruction_measure_args

    truth = json.loads((scene / "truth.json").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        try:
            res = measure_cloud_file(run / "cloud.ply", Path(tmp) / "m", config=config_from_dict(overrides or {}),
                                     plots=False, html=False,
                                     **reconstruction_measure_args(run / "run.json", run / "poses.txt", RunConfig()))
        except Exception as err:  # a failure is a result here
            return {"name": run.name, "failed": str(err)}
    err = {d: 100 * (res[f"{d}_m"] / truth[f"{d}_m"] - 1) for d in DIMS}
    z = {d: abs(res[f"{d}_m"] - truth[f"{d}_m"]) / max(res["uncertainty_m"][d], 1e-12) for d in DIMS}
    failing = [c["name"] for c in res.get("data_quality", {}).get("checks", []) if c["status"] == "fail"]
    gated = bool(failing)
    # Judged as `bench` judges a full-scale draw (a model's verdict is not applicable).
    expected = (truth.get("over_limit_expectation") or {}).get("verdict")
    judged = expected in ("over-limit", "within-limits")
    true = {d: truth[f"{d}_m"] for d in DIMS}
    right = verdict_matches(expected, res["verdict"], true) if judged else None
    sound = verdict_matches(expected, res["verdict"], true, undecided="interval-covers-truth") if judged else None
    return {"name": run.name, "error_pct": err, "z": z, "gated": gated, "failing_checks": failing,
            "rules": res.get("rules", {}), "rounded_top_drop": res.get("rounded_top_drop"),
            "body_brightness": res.get("body_brightness"),
            "width_walls_m": res.get("width_walls_m"), "verdict": res["verdict"]["overall"], "verdict_right": right,
            "verdict_sound": sound}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pairs", nargs="*", help="RUN:SCENE folder pairs")
    ap.add_argument("--bench", help="a `stereo-recon bench --random` output folder: all its runs/draw_* with draws/draw_*")
    ap.add_argument("--json", help="also write the rows to this file")
    ap.add_argument("--measure", default="{}", help="measure config overrides as JSON, e.g. '{\"top_above_roof_sigmas\": 3}'")
    args = ap.parse_args(argv)
    try:
        overrides = json.loads(args.measure)
    except json.JSONDecodeError as err:
        ap.error(f"--measure: not JSON ({err})")
    pairs = []
    for p in args.pairs:
        run, _, scene = p.partition(":")
        if not (Path(run, "cloud.ply").is_file() and Path(scene, "truth.json").is_file()):
            ap.error(f"{p}: expected RUN:SCENE, a run folder with cloud.ply and a scene folder with truth.json")
        pairs.append((Path(run), Path(scene)))
    if args.bench:
        b = Path(args.bench)
        if not (b / "runs").is_dir():
            ap.error(f"--bench {b}: not a `stereo-recon bench --random` output folder (no runs/ in it)")
        pairs += [(r, b / "draws" / r.name) for r in sorted((b / "runs").glob("draw_*")) if (r / "cloud.ply").exists()]
    if not pairs:
        ap.error("no run folders given")
    rows = []
    for run, scene in pairs:
        r = remeasure(run, scene, overrides)
        rows.append(r)
        if "failed" in r:
            print(f"{r['name']:16s} failed: {r['failed'][-100:]}")
        else:
            print(f"{r['name']:16s} " + "  ".join(f"{d[0].upper()} {r['error_pct'][d]:+6.2f} % ({r['z'][d]:.1f} sigma)" for d in DIMS)
                  + f"  {r['verdict']}{'  [gated]' if r['gated'] else ''}"
                  + ("" if r["verdict_right"] is None else ("  (right)" if r["verdict_right"] else "  (WRONG)")))
    ok = [r for r in rows if "failed" not in r]
    if ok:
        E = np.abs([[r["error_pct"][d] for d in DIMS] for r in ok])
        Z = np.array([[r["z"][d] for d in DIMS] for r in ok])
        ug = np.array([not r["gated"] for r in ok])
        print(f"{len(ok)} measured, {len(rows) - len(ok)} failed; mean |error| L {E[:, 0].mean():.2f} W {E[:, 1].mean():.2f} "
              f"H {E[:, 2].mean():.2f} all {E.mean():.2f} %; truth in +-2 sigma L {100 * np.mean(Z[:, 0] <= 2):.0f} "
              f"W {100 * np.mean(Z[:, 1] <= 2):.0f} H {100 * np.mean(Z[:, 2] <= 2):.0f} all {100 * np.mean(Z <= 2):.1f} %"
              + (f" (not gated: {100 * np.mean(Z[ug] <= 2):.1f} % of {ug.sum()} draws)" if ug.any() else ""))
        judged = [r for r in ok if r["verdict_right"] is not None]
        if judged:
            print(f"full-scale verdicts of the measured draws: {sum(r['verdict_right'] for r in judged)} of {len(judged)} right "
                  f"(undecided only with the truth within 2 sigma of a limit), {sum(r['verdict_sound'] for r in judged)} sound "
                  "(undecided with the truth inside its own 2 sigma)")
        if ug.any():
            Eu = E[ug]
            print("draws no data-quality gate refused, absolute error mean / median / p90 / max: " + "; ".join(
                f"{d[0].upper()} {Eu[:, i].mean():.2f} / {np.median(Eu[:, i]):.2f} / {np.percentile(Eu[:, i], 90):.2f} / {Eu[:, i].max():.1f} %"
                for i, d in enumerate(DIMS)))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
