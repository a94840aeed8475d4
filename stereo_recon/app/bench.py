"""The paper's Table 2 as a benchmark: render the 20 model trucks, run the pipeline, compare.

Also the full-scale presets with their verdicts, and the paper's parameter studies
(ground thickness d_h, Fig. 9; FoF epsilon, Fig. 10) on the reconstructed clouds.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import fields, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from stereo_recon.core.errors import ConfigError, InputError
from stereo_recon.core.paths import RunPaths
from stereo_recon.core.atomic import write_json_atomic

log = logging.getLogger(__name__)

# Table 2 of the paper: average relative errors (%) of ZEDfu + their measurement.
PAPER_AVERAGE_ERROR_PCT = {"length": 2.37, "width": 2.32, "height": 1.47, "overall": 2.05}
DIMS = ("length", "width", "height")


def parse_truck_range(text: str) -> list[int]:
    """'1-20', '3', '1,4,7-9' -> sorted truck numbers in 1..20."""
    out: set[int] = set()
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part:
                a, b = part.split("-", 1)
                out.update(range(int(a), int(b) + 1))
            elif part:
                out.add(int(part))
    except ValueError as err:
        raise ConfigError(f"--trucks: cannot read '{text}' (use e.g. 1-20 or 1,4,7-9)") from err
    if not out or min(out) < 1 or max(out) > 20:
        raise ConfigError(f"--trucks: '{text}' must name trucks between 1 and 20")
    return sorted(out)


def _scene_files(scene_dir: Path) -> tuple[Path, Path, dict]:
    videos = sorted(p for p in scene_dir.glob("video.*"))
    calibs = sorted(scene_dir.glob("SN*.conf")) or sorted(scene_dir.glob("rig.yaml"))
    truth_path = scene_dir / "truth.json"
    if not videos or not calibs or not truth_path.is_file():
        raise InputError(f"{scene_dir}: rendered scene is incomplete (video, calibration or truth.json missing)")
    return videos[0], calibs[0], json.loads(truth_path.read_text())


def bench_one(preset: str, scene_dir: str, run_dir: str, seed: int, frames: int | None, reconstruct=None) -> dict:
    """Render (if needed) one preset, run the full pipeline on it and compare with its truth.

    reconstruct: the ReconstructConfig of every truck (None: the defaults).
    """
    from stereo_recon.app.pipeline import RunConfig, run_video
    from stereo_recon.synthetic import render_sequence

    scene = Path(scene_dir)
    t0 = time.perf_counter()
    if not (scene / "truth.json").is_file():
        render_sequence(preset, scene, seed=seed, frames=frames)
    render_s = time.perf_counter() - t0
    video, calib, truth = _scene_files(scene)
    rcfg = {} if reconstruct is None else {"reconstruct": reconstruct}
    summary = run_video(video, calib, run_dir, RunConfig(resume=True, quiet=True, **rcfg))
    err_pct = {d: 100.0 * abs(summary[f"{d}_m"] - truth[f"{d}_m"]) / truth[f"{d}_m"] for d in DIMS}
    err_pct["overall"] = float(np.mean([err_pct[d] for d in DIMS]))
    return {
        **summary,
        "preset": preset,
        "truth": {d: truth[f"{d}_m"] for d in DIMS},
        "expected_verdict": (truth.get("over_limit_expectation") or {}).get("verdict"),
        "error_pct": err_pct,
        "render_time_s": render_s,
    }


# truth.json's over-limit expectation (synthetic presets) -> the measure's overall verdict.
_EXPECTED_TO_VERDICT = {"over-limit": "over", "within-limits": "within", "not-applicable": "not-applicable"}


# How an ``undecided`` dimension is judged (``verdict_matches``): "truth-near-limit", issue 12's letter, counts it
# right only where the truth lies within the measurement's k sigma of the limit; "interval-covers-truth" counts it
# right where the reported +-k sigma interval holds the truth (it holds the limit by construction). With a calibrated
# sigma the first is a coin toss for a truth near k sigma from the limit: a measurement erring towards the limit by
# any amount makes it undecided (P = 0.5 at exactly k sigma), so a check built on it depends on the error's sign, not
# on whether the verdict was honest. The second fails only a dishonest interval, and a confident verdict (over or
# within) on the wrong side fails both.
UNDECIDED_RULES = ("truth-near-limit", "interval-covers-truth")


def verdict_matches(expected: str | None, verdict: dict | str | None, truth_m: dict | None = None,
                    undecided: str = "truth-near-limit") -> bool | None:
    """Whether the measured verdict is right for the scene's truth (None: the truth expects nothing).

    expected: truth.json's over-limit expectation ("over-limit", "within-limits", "not-applicable").
    verdict: the measurement's verdict (its "overall", and per dimension value_m, uncertainty_m,
    limit_m, verdict; "k_sigma") or just the overall word. truth_m: true length/width/height (m).
    With the dimensions and the truth, every dimension's verdict must be right: "over" only above
    the limit, "within" only at or below it, and "undecided" only where the true value lies within
    the measurement's own k-sigma interval of the limit (a truck built exactly to a limit: no
    measurement this precise can tell, and "undecided" is the honest answer, not an error). undecided: how an
    ``undecided`` dimension is judged (``UNDECIDED_RULES``): with "interval-covers-truth" it is right where the true
    value lies within the measurement's own k-sigma interval.
    """
    if undecided not in UNDECIDED_RULES:
        raise ValueError(f"undecided={undecided!r}: one of {UNDECIDED_RULES}")
    if expected is None:
        return None
    overall = verdict.get("overall") if isinstance(verdict, dict) else verdict
    want = _EXPECTED_TO_VERDICT.get(expected, expected)
    dims = verdict.get("dimensions") if isinstance(verdict, dict) else None
    if want == "not-applicable" or not dims or truth_m is None:
        return want == overall
    k = float(verdict.get("k_sigma", 2.0))
    for d, e in dims.items():
        lim, status, true = e.get("limit_m"), e.get("verdict"), truth_m.get(d)
        if lim is None or true is None or status == "no-limit":
            continue
        u, value = e.get("uncertainty_m"), e.get("value_m")
        ref = lim if undecided == "truth-near-limit" else value
        right = {"over": true > lim, "within": true <= lim,
                 "undecided": u is not None and ref is not None and abs(true - ref) <= k * u}.get(status, False)
        if not right:
            return False
    return overall == want or (overall == "undecided" and want in ("within", "over"))


def table_markdown(results: Sequence[dict]) -> str:
    """The paper's Table 2 layout: standard size, predicted size, relative errors, average error."""
    lines = [
        "| Subject | L std (m) | W std (m) | H std (m) | L pred (m) | W pred (m) | H pred (m) | L err | W err | H err | Avg err | Time (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    ok = [r for r in results if r.get("ok")]
    for r in results:
        if not r.get("ok"):
            lines.append(f"| {r['name']} | failed: {r.get('error')} |||||||||||")
            continue
        t, e = r["truth"], r["error_pct"]
        lines.append(
            f"| {r['name']} | {t['length']:.3f} | {t['width']:.3f} | {t['height']:.3f} | "
            f"{r['length_m']:.3f} | {r['width_m']:.3f} | {r['height_m']:.3f} | "
            f"{e['length']:.2f}% | {e['width']:.2f}% | {e['height']:.2f}% | {e['overall']:.2f}% | {r['time_s']:.1f} |"
        )
    if ok:
        avg = {k: float(np.mean([r["error_pct"][k] for r in ok])) for k in (*DIMS, "overall")}
        lines.append(f"| **Average (ours)** | | | | | | | {avg['length']:.2f}% | {avg['width']:.2f}% | {avg['height']:.2f}% | {avg['overall']:.2f}% | |")
    p = PAPER_AVERAGE_ERROR_PCT
    lines.append(f"| Average (paper, ZEDfu) | | | | | | | {p['length']:.2f}% | {p['width']:.2f}% | {p['height']:.2f}% | {p['overall']:.2f}% | |")
    return "\n".join(lines) + "\n"


def bench_summary(results: Sequence[dict]) -> dict:
    ok = [r for r in results if r.get("ok") and "error_pct" in r]
    avg = {k: float(np.mean([r["error_pct"][k] for r in ok])) for k in (*DIMS, "overall")} if ok else {}
    worst = max((max(r["error_pct"][d] for d in DIMS) for r in ok), default=None)
    return {
        "n_ok": len(ok),
        "n_failed": len(results) - len(ok),
        "average_error_pct": avg,
        "worst_single_dimension_error_pct": worst,
        "paper_average_error_pct": PAPER_AVERAGE_ERROR_PCT,
        "median_time_s": float(np.median([r["time_s"] for r in ok])) if ok else None,
    }


def write_bench(out_dir: Path, results: Sequence[dict], name: str = "table2") -> tuple[Path, Path]:
    md = Path(out_dir) / f"{name}.md"
    md.parent.mkdir(parents=True, exist_ok=True)
    tmp = md.with_suffix(".md.tmp")
    tmp.write_text(table_markdown(results))
    tmp.replace(md)
    js = write_json_atomic(Path(out_dir) / f"{name}.json", {"summary": bench_summary(results), "results": list(results)})
    return md, js


# ---------------------------------------------------------------- parameter studies (Figs. 9, 10)

def study_values(study: str) -> tuple[str, np.ndarray]:
    """The paper's sweeps: d_h 0.06-0.08 m step 0.002 (Fig. 9); eps 0.03-0.12 m step 0.01 (Fig. 10)."""
    if study == "ground-thickness":
        return "ground_thickness_m", np.round(np.arange(0.060, 0.0801, 0.002), 4)
    if study == "fof-eps":
        return "eps_m", np.round(np.arange(0.03, 0.1201, 0.01), 3)
    raise ConfigError(f"--study: unknown study '{study}' (use ground-thickness or fof-eps)")


def run_study(study: str, clouds: Sequence[tuple[str, Path, dict]], out_dir: Path, up_hints: dict | None = None) -> dict:
    """Re-measure reconstructed clouds over the paper's parameter sweep.

    Parameters
    ----------
    clouds : (name, cloud.ply path, truth dict with length_m/width_m/height_m) per training truck.
    Returns per-value mean MSE (Eq. 4, m^2) and mean time per truck (s); writes a table and a plot.
    """
    import open3d as o3d

    from measure.pipeline import MeasureConfig, measure_points

    field_name, values = study_values(study)
    names = {f.name for f in fields(MeasureConfig)}
    if field_name not in names:
        raise ConfigError(f"--study {study}: MeasureConfig has no field '{field_name}'")
    # Clouds are read once; the last row (value None) is our scale-free default, resolved per cloud.
    loaded = [(name, np.asarray(o3d.io.read_point_cloud(str(path)).points), truth) for name, path, truth in clouds]
    rows = []
    for v in [*values, None]:
        mses, times, resolved = [], [], []
        for name, pts, truth in loaded:
            cfg = MeasureConfig() if v is None else replace(MeasureConfig(), **{field_name: float(v)})
            t0 = time.perf_counter()
            try:
                m = measure_points(pts, cfg, up_hint=(up_hints or {}).get(name))
                pred = np.array([m.length_m, m.width_m, m.height_m])
                true = np.array([truth["length_m"], truth["width_m"], truth["height_m"]])
                mses.append(float(np.sum((pred - true) ** 2)))  # Eq. 4
                resolved.append(float(m.parameters["resolved"][field_name]))
            except Exception as err:  # a parameter that breaks measurement is a result of the study
                log.info("study %s=%s on %s failed: %s", field_name, v, name, err)
                mses.append(float("nan"))
            times.append(time.perf_counter() - t0)
        rows.append({"value_m": None if v is None else float(v), "mean_mse_m2": float(np.nanmean(mses)) if np.isfinite(mses).any() else None,
                     "n_failed": int(np.sum(~np.isfinite(mses))), "mean_time_s": float(np.mean(times)),
                     "resolved_m": [round(r, 5) for r in resolved]})
    default = rows.pop()
    valid = [r for r in rows if r["mean_mse_m2"] is not None]
    best_mse = min(valid, key=lambda r: r["mean_mse_m2"]) if valid else None
    fastest = min(rows, key=lambda r: r["mean_time_s"])
    # Fig. 9 picks d_h by accuracy; Fig. 10 compares eps by time per truck: its optimum is the fastest.
    best = best_mse if study == "ground-thickness" else fastest
    result = {"study": study, "parameter": field_name, "rows": rows, "optimum_m": best["value_m"] if best else None,
              "most_accurate_m": best_mse["value_m"] if best_mse else None, "fastest_m": fastest["value_m"],
              "default": default}
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / f"study-{study}.json", result)
    md = ["| value (m) | mean MSE (m^2) | failed | mean time (s) |", "|---|---|---|---|"]
    for r in [*rows, default]:
        mse = "n/a" if r["mean_mse_m2"] is None else f"{r['mean_mse_m2']:.3e}"
        label = (f"{r['value_m']:.3f}" if r["value_m"] is not None else
                 f"default (scale-free: {min(r['resolved_m'], default=0):.4f}-{max(r['resolved_m'], default=0):.4f})")
        md.append(f"| {label} | {mse} | {r['n_failed']} | {r['mean_time_s']:.3f} |")
    md.append("")
    md.append(f"optimum: {result['optimum_m']} m (most accurate {result['most_accurate_m']} m, fastest {result['fastest_m']} m)")
    if best_mse is not None and default["mean_mse_m2"] is not None:
        md.append(f"default vs most accurate: MSE {default['mean_mse_m2']:.3e} vs {best_mse['mean_mse_m2']:.3e} m^2 "
                  f"({default['mean_mse_m2'] / best_mse['mean_mse_m2']:.2f}x)")
    (out_dir / f"study-{study}.md").write_text("\n".join(md) + "\n")
    _plot_study(out_dir / f"study-{study}.png", result)
    return result


def _plot_study(path: Path, result: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = [r["value_m"] for r in result["rows"]]
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=110)
    if result["study"] == "ground-thickness":
        ax.plot(x, [np.nan if r["mean_mse_m2"] is None else r["mean_mse_m2"] for r in result["rows"]], "o-")
        ax.set_ylabel("mean MSE (m²), Eq. 4")
        ax.set_xlabel("ground thickness d_h (m)")
    else:
        ax.plot(x, [r["mean_time_s"] for r in result["rows"]], "o-")
        ax.set_ylabel("mean measure time per truck (s)")
        ax.set_xlabel("FoF distance threshold ε (m)")
    if result.get("optimum_m") is not None:
        ax.axvline(result["optimum_m"], color="r", ls="--", label=f"optimum {result['optimum_m']:.3f} m")
    d = result.get("default") or {}
    if d.get("resolved_m"):
        y = d["mean_mse_m2"] if result["study"] == "ground-thickness" else d["mean_time_s"]
        if y is not None:
            ax.plot([float(np.mean(d["resolved_m"]))], [y], "k*", ms=12, label="our scale-free default (mean over trucks)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# ------------------------------------------------------------- random operating-envelope benchmark

# Factor splits of the envelope table: name -> (label, function of a draw's spec -> level).
RADIUS_BINS = ((0.75, 1.0), (1.0, 1.5), (1.5, 2.0001))
ELEVATION_BINS = ((15.0, 25.0), (25.0, 35.0), (35.0, 50.0001))


def _bin(value: float, bins) -> str:
    for lo, hi in bins:
        if lo <= value < hi:
            return f"{lo:g}-{min(hi, round(hi, 2)):g}"
    return "out of range"


def envelope_factors(spec) -> dict[str, str]:
    """The levels of one draw for the factor splits (texture, radius/L, elevation, scale, kind, second vehicle, lens, codec)."""
    return {
        "texture": spec.panel.texture_class,
        "radius/L": _bin(spec.flight.radius_over_length, RADIUS_BINS),
        "elevation (deg)": _bin(spec.flight.elevation_deg, ELEVATION_BINS),
        "scale": spec.truck.scale,
        "kind": spec.truck.kind,
        "second vehicle": "yes" if spec.scene.second is not None else "no",
        "lens": spec.camera.lens_family,
        "codec": spec.camera.codec,
    }


def bench_random_one(seed: int, index: int, draws_dir: str, runs_dir: str, max_frames: int | None, scale: str | None,
                     resolution: str) -> dict:
    """Render (or reuse) draw ``index`` of ``seed`` and run the full pipeline on it with default settings (as ``run``)."""
    from stereo_recon.app.pipeline import RunConfig, run_video
    from stereo_recon.synthetic.envelope import draw_dir, draw_spec, ensure_rendered

    t0 = time.perf_counter()
    scene = draw_dir(draws_dir, index)
    ensure_rendered(draw_spec(seed, index, max_frames=max_frames, scale=scale, resolution=resolution), scene)
    render_s = time.perf_counter() - t0
    video, calib, _ = _scene_files(scene)
    summary = run_video(video, calib, runs_dir, RunConfig(resume=True, quiet=True))
    mpath = RunPaths(Path(runs_dir)).measurement
    measurement = json.loads(mpath.read_text()) if mpath.is_file() else {}
    return {**summary, "data_quality": measurement.get("data_quality"), "render_time_s": render_s}


def _failure_reason(result: dict) -> str | None:
    """Why a draw's run counts as a failure (None: it measured all three dimensions without refusing)."""
    if not result.get("ok"):
        return str(result.get("error") or "failed")
    dq = result.get("data_quality") or {}
    if dq and dq.get("ok") is False:
        fails = [f"{c.get('name')}: {c.get('detail')}" for c in dq.get("checks", []) if c.get("status") == "fail"]
        return "refused (data quality): " + ("; ".join(fails) or "failed checks")
    missing = [d for d in DIMS if not isinstance(result.get(f"{d}_m"), (int, float)) or not np.isfinite(result[f"{d}_m"])]
    if missing:
        return f"not measured: {', '.join(missing)}"
    dims = ((result.get("verdict") or {}).get("dimensions") or {}) if isinstance(result.get("verdict"), dict) else {}
    unmeasured = [d for d, e in dims.items() if isinstance(e, dict) and e.get("verdict") == "not-measured"]
    if unmeasured:
        return f"not measured: {', '.join(unmeasured)}"
    return None


def envelope_row(result: dict, spec, truth: dict | None = None) -> dict:
    """One draw's row of envelope.json: spec summary, truth, measured, sigma, signed error (%), coverage, verdict, failure."""
    t = spec.truck
    true = {d: float(getattr(t, f"{d}_m")) for d in DIMS}
    reason = _failure_reason(result)
    row = {
        "draw": spec.index, "name": spec.name, "ok": reason is None, "failure_reason": reason,
        "spec": {"scale": t.scale, "kind": t.kind, "length_m": t.length_m, "texture_class": spec.panel.texture_class,
                 "texture_strength": spec.panel.panel.texture_strength, "body_paint": t.body_paint,
                 "radius_over_length": spec.flight.radius_over_length, "radius_m": spec.flight.radius_m,
                 "elevation_deg": spec.flight.elevation_deg, "arc_deg": spec.flight.arc_deg, "frames": spec.flight.frames,
                 "lens_family": spec.camera.lens_family, "codec": spec.camera.codec, "noise_sigma_dn": spec.camera.noise_sigma_dn,
                 "blur_sigma_px": spec.camera.blur_sigma_px, "sun_elevation_deg": spec.scene.sun_elevation_deg,
                 "ground_class": spec.scene.ground_class, "second_vehicle": None if spec.scene.second is None else spec.scene.second.relation},
        "factors": envelope_factors(spec), "truth_m": true,
        "measured_m": None, "sigma_m": None, "error_pct": None, "within_2sigma": None,
        "verdict": None, "expected_verdict": None, "verdict_right": None, "verdict_sound": None,
        "time_s": result.get("time_s"), "run_dir": result.get("out_dir"),
    }
    if t.scale == "full":
        row["expected_verdict"] = ((truth or {}).get("over_limit_expectation") or {}).get("verdict") or _expected_verdict(t)
    if reason is not None:
        row["verdict_right"] = row["verdict_sound"] = False if t.scale == "full" else None
        return row
    meas = {d: float(result[f"{d}_m"]) for d in DIMS}
    sig = {d: (result.get("uncertainty_m") or {}).get(d) for d in DIMS}
    row.update(measured_m=meas, sigma_m=sig,
               error_pct={d: 100.0 * (meas[d] - true[d]) / true[d] for d in DIMS},
               within_2sigma={d: sig[d] is not None and abs(meas[d] - true[d]) <= 2.0 * sig[d] for d in DIMS})
    v = result.get("verdict")
    row["verdict"] = v.get("overall") if isinstance(v, dict) else v
    if t.scale == "full":
        row["verdict_right"] = bool(verdict_matches(row["expected_verdict"], v, true))
        row["verdict_sound"] = bool(verdict_matches(row["expected_verdict"], v, true, undecided="interval-covers-truth"))
    return row


def _expected_verdict(t) -> str:
    from stereo_recon.synthetic.presets import CN_2016_62_LIMITS_M

    over = any(getattr(t, k) > lim for k, lim in CN_2016_62_LIMITS_M.items())
    return "over-limit" if over else "within-limits"


def _stats(rows: Sequence[dict], dims: Sequence[str]) -> dict:
    """Failure rate and error statistics (%, absolute relative error) over ``dims`` of ``rows`` pooled."""
    n = len(rows) * len(dims)
    errs = [r["error_pct"][d] for r in rows if r["ok"] for d in dims]
    cover = [r["within_2sigma"][d] for r in rows if r["ok"] for d in dims]
    failed = sum(len(dims) for r in rows if not r["ok"])
    a = np.abs(errs)
    out = {"n": n, "failed": failed, "failure_rate": failed / n if n else None}
    if len(errs):
        out.update(mean_abs_pct=float(a.mean()), median_abs_pct=float(np.median(a)), p90_abs_pct=float(np.percentile(a, 90)),
                   max_abs_pct=float(a.max()), bias_pct=float(np.mean(errs)), within_2sigma=float(np.mean(cover)))
    else:
        out.update(mean_abs_pct=None, median_abs_pct=None, p90_abs_pct=None, max_abs_pct=None, bias_pct=None, within_2sigma=None)
    return out


def envelope_summary(rows: Sequence[dict]) -> dict:
    """Per dimension and overall statistics, the full-scale verdicts, and the same split by factor."""
    per_dim = {d: _stats(rows, (d,)) for d in DIMS}
    per_dim["overall"] = _stats(rows, DIMS)
    full = [r for r in rows if r["spec"]["scale"] == "full"]
    verdicts = {"n_full_scale": len(full), "right": sum(bool(r["verdict_right"]) for r in full),
                "sound": sum(bool(r.get("verdict_sound")) for r in full),
                "wrong": [r["name"] for r in full if r["ok"] and not r["verdict_right"]],
                "failed": [r["name"] for r in full if not r["ok"]]}
    factors: dict[str, dict] = {}
    for name in (rows[0]["factors"] if rows else {}):
        levels = sorted({r["factors"][name] for r in rows})
        factors[name] = {lv: _stats([r for r in rows if r["factors"][name] == lv], DIMS) for lv in levels}
    return {"draws": len(rows), "failed_draws": sum(not r["ok"] for r in rows), "dimensions": per_dim, "verdicts": verdicts,
            "by_factor": factors}


def _pct(v, digits: int = 2) -> str:
    return "–" if v is None else f"{v:.{digits}f}%"


def _stats_cells(s: dict) -> str:
    cover = "–" if s["within_2sigma"] is None else f"{100 * s['within_2sigma']:.0f}%"
    return (f"{s['n']} | {s['failed']} ({100 * s['failure_rate']:.0f}%) | {_pct(s['mean_abs_pct'])} | {_pct(s['median_abs_pct'])} | "
            f"{_pct(s['p90_abs_pct'])} | {_pct(s['max_abs_pct'])} | {_pct(s['bias_pct'])} | {cover}")


def envelope_markdown(meta: dict, summary: dict, rows: Sequence[dict]) -> str:
    """envelope.md: overall and per-dimension figures, verdicts, the split by factor, failures and every draw."""
    from stereo_recon.synthetic.seeds import EVALUATION_SEED, TUNING_SEEDS

    if meta["seed"] == EVALUATION_SEED:
        use = "evaluation seed"
    elif meta["seed"] in TUNING_SEEDS:
        use = "TUNING seed (figures for tuning, not for reporting)"
    else:
        use = "a seed outside the tuning range: report it only if it was never tuned on"
    head = "| n (dimensions) | failed | mean abs | median | p90 | max | bias | truth in ±2σ |"
    lines = [f"# Operating-envelope benchmark: seed {meta['seed']} ({use}), {meta['count']} draws"
             + (f", frames capped at {meta['max_frames']}" if meta.get("max_frames") else ""), "",
             "Errors are relative to the truth, absolute unless 'bias'; a failed draw counts as a failure in every dimension.", "",
             "| dimension | " + head[2:], "|---" * 9 + "|"]
    for d, s in summary["dimensions"].items():
        lines.append(f"| {d} | {_stats_cells(s)} |")
    v = summary["verdicts"]
    lines += ["", f"Full-scale verdicts (cn-2016-62): {v['right']} of {v['n_full_scale']} right"
              + (f"; wrong: {', '.join(v['wrong'])}" if v["wrong"] else "") + (f"; failed: {', '.join(v['failed'])}" if v["failed"] else "")
              + " (`undecided` right only with the truth within 2σ of the limit); "
              + f"{v.get('sound', 0)} of {v['n_full_scale']} sound (`over` and `within` on the truth's side, `undecided` with "
              "the truth inside its own ±2σ)", "",
              "## By factor", "", "| factor | level | " + head[2:], "|---" * 10 + "|"]
    for name, levels in summary["by_factor"].items():
        for lv, s in levels.items():
            lines.append(f"| {name} | {lv} | {_stats_cells(s)} |")
    failed = [r for r in rows if not r["ok"]]
    if failed:
        lines += ["", "## Failures", "", "| draw | scale | kind | texture | r/L | elevation | reason |", "|---|---|---|---|---|---|---|"]
        for r in failed:
            s = r["spec"]
            lines.append(f"| {r['name']} | {s['scale']} | {s['kind']} | {s['texture_class']} | {s['radius_over_length']:.2f} | "
                         f"{s['elevation_deg']:.0f}° | {r['failure_reason']} |")
    lines += ["", "## Draws", "", "| draw | scale | kind | texture | r/L | elev | frames | L err | W err | H err | in ±2σ | verdict (expected) |",
              "|---" * 12 + "|"]
    for r in rows:
        s = r["spec"]
        e = r["error_pct"] or {}
        cov = "–" if r["within_2sigma"] is None else "".join("✓" if r["within_2sigma"][d] else "✗" for d in DIMS)
        verdict = "failed" if not r["ok"] else (r["verdict"] or "–")
        if r["expected_verdict"]:
            verdict += f" ({r['expected_verdict']}: {'right' if r['verdict_right'] else 'WRONG'})"
        lines.append(f"| {r['name']} | {s['scale']} | {s['kind']} | {s['texture_class']} | {s['radius_over_length']:.2f} | "
                     f"{s['elevation_deg']:.0f}° | {s['frames']} | {_signed(e.get('length'))} | {_signed(e.get('width'))} | "
                     f"{_signed(e.get('height'))} | {cov} | {verdict} |")
    return "\n".join(lines) + "\n"


def _signed(v) -> str:
    return "–" if v is None else f"{v:+.2f}%"


def plot_envelope(path: Path, summary: dict, rows: Sequence[dict]) -> Path:
    """envelope.png: per factor, every draw's absolute error per dimension by level (failures as red crosses at the top)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(summary["by_factor"])
    ncol = 4
    nrow = max(1, -(-len(names) // ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.2 * nrow), dpi=100, squeeze=False)
    ok_errs = [abs(r["error_pct"][d]) for r in rows if r["ok"] for d in DIMS]
    # Log scale: errors span 0.01 % to tens of %; the top band holds the failures.
    top = max(5.0, min(200.0, 2.5 * max(ok_errs, default=5.0)))
    floor = 0.01
    colours = {"length": "tab:blue", "width": "tab:orange", "height": "tab:green"}
    for ax, name in zip(axes.ravel(), names):
        levels = list(summary["by_factor"][name])
        for k, lv in enumerate(levels):
            sel = [r for r in rows if r["factors"][name] == lv]
            for j, d in enumerate(DIMS):
                ys = [float(np.clip(abs(r["error_pct"][d]), floor, top)) for r in sel if r["ok"]]
                ax.scatter(np.full(len(ys), k + (j - 1) * 0.18), ys, s=14, color=colours[d], label=d if k == 0 else None)
            nf = sum(not r["ok"] for r in sel)
            if nf:
                ax.scatter([k], [top * 0.7], marker="x", color="red", s=40, label="failed")
                ax.annotate(f"{nf} failed", (k + 0.08, top * 0.7), color="red", fontsize=8)
        ax.set_xticks(range(len(levels)))
        ax.set_xticklabels(levels, fontsize=8)
        ax.set_xlim(-0.6, len(levels) - 0.4)
        ax.set_yscale("log")
        ax.set_ylim(floor, top)
        ax.set_title(name, fontsize=10)
        ax.axhline(1.0, color="grey", lw=0.6, ls="--")
        ax.grid(alpha=0.25)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    axes[0, 0].set_ylabel("|error| (%)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    for ax in axes.ravel()[1:]:  # the first panel may have no failure: collect every label once
        for h, lb in zip(*ax.get_legend_handles_labels()):
            if lb not in labels:
                handles.append(h)
                labels.append(lb)
    fig.legend(handles, labels, fontsize=8, loc="upper right")
    fig.tight_layout(rect=(0.0, 0.0, 0.94, 1.0))  # room for the legend on the right
    fig.savefig(path)
    plt.close(fig)
    return path


def write_envelope(out_dir: Path, meta: dict, rows: Sequence[dict]) -> dict:
    """Write envelope.json (per-draw rows and the summary), envelope.md and envelope.png into ``out_dir``; returns the summary."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = envelope_summary(rows)
    write_json_atomic(out_dir / "envelope.json", {**meta, "summary": summary, "draws": list(rows)})
    tmp = out_dir / "envelope.md.tmp"
    tmp.write_text(envelope_markdown(meta, summary, rows))
    tmp.replace(out_dir / "envelope.md")
    plot_envelope(out_dir / "envelope.png", summary, rows)
    return summary
