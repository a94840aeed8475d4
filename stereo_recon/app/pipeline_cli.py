"""CLI layer for the end-to-end jobs: ``run``, ``batch`` and ``bench``."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from stereo_recon.app.measure_cli import add_case_options, case_fields
from stereo_recon.app.options import add_frame_options, add_pose_options, reconstruct_config
from stereo_recon.core.errors import ConfigError, InputError
from stereo_recon.core.paths import SUMMARY_CSV, RunPaths
from stereo_recon.core.progress import ProgressConfig, StageProgress


def _add_job_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--poses", choices=("vo", "sfm"), default="vo", help="pose back-end: stereo visual odometry (default) or pycolmap SfM")
    p.add_argument("--regulation", default="cn-2016-62", help="regulation table: builtin name (cn-2016-62, gb1589-2016, eu-96-53, us-federal) or a file")
    p.add_argument("--vehicle-class", default=None, help="vehicle class in the regulation table (default: the table's default)")
    p.add_argument("--scale", type=float, default=None, help="model-to-real scale factor (model trucks get a legal verdict only with it)")
    p.add_argument("--config", type=Path, default=None, help="TOML/YAML file with measure parameter overrides")
    p.add_argument("--rectified", action="store_true", default=None, help="frames are already rectified (ZED SDK SVO export)")
    add_pose_options(p)
    add_frame_options(p)
    add_case_options(p)
    p.add_argument("--reconstruction-sigma-pct", default=None, metavar="L,W,H",
                   help="relative standard error of the reconstruction per dimension (%%), added to the measurement's "
                        "uncertainty before the verdict (default: the bench's 0.32,1.44,0.51; 0,0,0 = none)")


class _HelpWithDefaults(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's and examples' lines; gives each option's default where its help does not."""

    def _get_help_string(self, action):
        text = action.help or ""
        if not action.option_strings or action.required or "default" in text or action.default is argparse.SUPPRESS:
            return text
        if isinstance(action, argparse._StoreTrueAction):
            return f"{text} (default: off)"
        return f"{text} (default: {'none' if action.default is None else '%(default)s'})"


def _add_ray_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("Ray (with --executor ray)")
    g.add_argument("--address", default=None, metavar="ADDR",
                   help="Ray cluster to use: auto (the one running on this machine), HOST:PORT or ray://HOST:10001 "
                        "(default: $RAY_ADDRESS, else start a local instance)")
    g.add_argument("--cpus-per-job", type=float, default=1.0, help="CPUs Ray reserves for each recording (default 1)")
    g.add_argument("--memory-per-job-gb", type=float, default=None,
                   help="memory Ray reserves for each recording, GiB: a scheduling hint, not a limit (default: none)")
    g.add_argument("--ship-inputs", choices=("auto", "always", "never"), default="auto",
                   help="send videos and calibration files through Ray to nodes that do not have them at the same "
                        "absolute path: auto (only those nodes), always, never (default: auto)")


def _ray_options(args):
    from stereo_recon.app.batch_ray import RayOptions

    if args.address and args.executor != "ray":
        raise ConfigError(f"--address {args.address}: a Ray cluster is used only with --executor ray")
    return RayOptions(address=args.address, cpus_per_job=args.cpus_per_job, memory_per_job_gb=args.memory_per_job_gb,
                      ship_inputs=args.ship_inputs)


def register(sub) -> None:
    p = sub.add_parser("run", help="video -> reconstruction -> measurement -> report (defaults to the bundled sample)",
                       description="Reconstruct a truck from side-by-side stereo video, measure it and write report.html. "
                                   "With no VIDEO it runs on the bundled sample_data/ demo.")
    p.add_argument("video", nargs="?", type=Path, help="side-by-side video or folder of left/right images")
    p.add_argument("--calib", default=None, help="ZED .conf, rig YAML, or fx,fy,cx,cy,baseline_m (required with VIDEO)")
    p.add_argument("--out", type=Path, default=Path("out/run"), help="output folder (default: out/run)")
    p.add_argument("--resume", action="store_true", help="reuse finished stages whose inputs are unchanged")
    _add_job_options(p)
    p.set_defaults(func=_cmd_run)

    b = sub.add_parser(
        "batch", help="process many recordings (local process pool or Ray)",
        description="Run the whole pipeline (reconstruct, measure, report) on many recordings with one calibration:\n"
                    "OUT/<video name>/ per recording and OUT/summary.csv with one row per recording. One line is\n"
                    "printed per recording as it finishes; a failed recording is reported and does not stop the others.\n"
                    "Exit 0 when all succeed, 1 when any failed, 2 on bad options.",
        epilog="examples:\n"
               "  stereo-recon batch flights/*.avi --calib SN28000001.conf --out season --workers 2\n"
               "  stereo-recon batch flights/*.avi --calib SN28000001.conf --out season --executor ray --address auto\n"
               "  stereo-recon batch flights/day2/*.avi --calib SN28000001.conf --out season --resume  "
               "# merges into season/summary.csv",
        formatter_class=_HelpWithDefaults)
    b.add_argument("videos", nargs="+", type=Path, help="side-by-side videos (or folders of left/right images)")
    b.add_argument("--calib", required=True, help="ZED .conf, rig YAML, or fx,fy,cx,cy,baseline_m, used for every video")
    b.add_argument("--out", type=Path, required=True, help="output folder: OUT/<name>/ per video and OUT/summary.csv")
    b.add_argument("--workers", type=int, default=None,
                   help="jobs at once (default: 1 with --executor local; with ray, as many as the cluster's CPUs allow)")
    b.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local process pool, or Ray: an existing cluster (--address / RAY_ADDRESS) or a local instance (default: local)")
    b.add_argument("--resume", action="store_true",
                   help="reuse finished reconstructions whose video and settings are unchanged, and merge rows into summary.csv")
    _add_ray_options(b)
    _add_job_options(b)
    b.set_defaults(func=_cmd_batch)

    c = sub.add_parser("bench", help="the paper's Table 2 on rendered model trucks, full-scale presets, parameter studies",
                       description="Render each truck of the paper's Table 2 (and two full-scale presets) with known "
                                   "dimensions, run the whole pipeline on it and compare with the truth: writes "
                                   "OUT/table2.md and .json (errors per dimension, times) and OUT/full-scale.md.")
    c.add_argument("--trucks", default="1-20", help="truck numbers of Table 2, e.g. 1-20 or 1,4,7-9")
    c.add_argument("--poses", choices=("vo", "sfm"), default="vo", help="pose back-end: stereo VO or pycolmap SfM")
    c.add_argument("--out", type=Path, default=Path("out/bench"), help="output folder (scenes/, runs/, tables)")
    c.add_argument("--frames", type=int, default=None, help="frames per orbit (default: the preset's)")
    c.add_argument("--seed", type=int, default=0, help="random seed of the renders (truck N uses seed + N)")
    c.add_argument("--workers", type=int, default=1, help="trucks processed at the same time")
    c.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local process pool, or a Ray cluster (pip install .[ray])")
    _add_ray_options(c)
    c.add_argument("--no-full-scale", action="store_true", help="skip the full-scale presets (full-truck, over-height)")
    add_pose_options(c)
    c.add_argument("--study", choices=("ground-thickness", "fof-eps"), default=None,
                   help="re-measure the reconstructed training trucks (1-6) over the paper's sweep")
    _add_random_bench_options(c)
    c.set_defaults(func=_cmd_bench)


RANDOM_BENCH_HELP = ("with --random K: K random scenes of the operating envelope (stereo_recon.synthetic.envelope), each run through "
                     "the full pipeline with default settings; writes envelope.md, envelope.json and envelope.png. Seeds {tuning} "
                     "(the latter: past reports' seeds) are for tuning; the next figures we report come from the evaluation seed "
                     "{seed}, never run.")


def _add_random_bench_options(c: argparse.ArgumentParser) -> None:
    from stereo_recon.synthetic.seeds import EVALUATION_SEED, TUNING_SEEDS_TEXT

    c.description = "The paper's Table 2 on rendered model trucks (default), or " + RANDOM_BENCH_HELP.format(
        seed=EVALUATION_SEED, tuning=TUNING_SEEDS_TEXT)
    c.add_argument("--random", type=int, default=None, metavar="K",
                   help=f"benchmark K random draws of --seed over the operating envelope instead of Table 2 (seeds {TUNING_SEEDS_TEXT}: "
                        f"tuning; {EVALUATION_SEED}: evaluation)")
    c.add_argument("--max-frames", type=int, default=None, metavar="N", help="with --random: cap each draw's 60-200 frames at N")
    c.add_argument("--scale-only", choices=("model", "full"), default=None,
                   help="with --random: only model-scale or only full-scale trucks")
    c.add_argument("--resolution", default="HD720", metavar="RES", help="with --random: ZED resolution rendered (default HD720)")
    c.add_argument("--draws", type=Path, default=None, metavar="DIR",
                   help="with --random: folder of the rendered draws, reused when it holds the same draws (default OUT/draws)")


def _job_config(args, resume: bool):
    """The job's RunConfig, built once per command: its ReconstructConfig and MeasureConfig validated here."""
    from measure.pipeline import MeasureConfig, load_config
    from stereo_recon.app.pipeline import RunConfig
    from stereo_recon.core.validate import check_number

    check_number("--scale", args.scale)
    if getattr(args, "workers", None) is not None:
        check_number("--workers", args.workers, integer=True, minimum=1, strict=False)
    extra = {}
    if getattr(args, "reconstruction_sigma_pct", None) is not None:
        extra["reconstruction_rel_sigma"] = _parse_sigma_pct(args.reconstruction_sigma_pct)
    return RunConfig(reconstruct=reconstruct_config(args), measure=load_config(args.config) if args.config else MeasureConfig(),
                     regulation=args.regulation, vehicle_class=args.vehicle_class, scale=args.scale, resume=resume,
                     quiet=bool(getattr(args, "quiet", False)), case=case_fields(args), **extra)


def _parse_sigma_pct(text: str) -> dict:
    """'L,W,H' in percent -> {length, width, height} as fractions; ConfigError when malformed."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != 3 or not all(math.isfinite(v) and v >= 0 for v in vals):
        raise ConfigError(f"--reconstruction-sigma-pct {text!r}: expected three percentages >= 0, e.g. 0.3,1.4,0.5")
    return dict(zip(("length", "width", "height"), (v / 100.0 for v in vals)))


def _print_summary(s: dict) -> None:
    u = s.get("uncertainty_m") or {}
    v = s.get("verdict") or {}
    print(f"length {s['length_m']:.3f} m ± {u.get('length', float('nan')):.3f}   "
          f"width {s['width_m']:.3f} m ± {u.get('width', float('nan')):.3f}   "
          f"height {s['height_m']:.3f} m ± {u.get('height', float('nan')):.3f}")
    dims = v.get("dimensions") if isinstance(v, dict) and v.get("scale") else None
    if dims:  # the verdict is about the real size: show it, not only the model's
        print(f"real size (x{v['scale']:g}): " + "   ".join(
            f"{d} {(dims.get(d) or {}).get('value_m', float('nan')):.3f} m" for d in ("length", "width", "height")))
    if isinstance(v, dict):
        reg = v.get("regulation", "?")
        reg = reg.get("name", "?") if isinstance(reg, dict) else reg
        print(f"verdict ({reg}): {v.get('overall', '?')}" + (f" — {v['reason']}" if v.get("reason") else ""))
    from stereo_recon.app.measure_cli import data_quality_line

    print(data_quality_line(s.get("data_quality")))
    print(f"report: {RunPaths(Path(s['out_dir'])).report}")


def _cmd_run(args) -> int:
    from stereo_recon.app.pipeline import find_sample, run_video

    if args.video is None:
        video, calib = find_sample()
        calib = args.calib or str(calib)
    else:
        video = args.video
        if args.calib is None:
            raise InputError(f"{video}: --calib is required with a video (a ZED .conf, rig YAML or fx,fy,cx,cy,baseline_m)")
        calib = args.calib
    cfg = _job_config(args, args.resume)
    summary = run_video(video, calib, args.out, cfg)
    _print_summary(summary)
    return 0


def _run_one(video: str, calib: str, out_dir: str, cfg) -> dict:
    from stereo_recon.app.pipeline import run_video

    return run_video(video, calib, out_dir, cfg)


def _cmd_batch(args) -> int:
    import time
    from dataclasses import replace

    from stereo_recon.app.batch import run_jobs, write_summary_csv
    from stereo_recon.app.pipeline import validate_job
    from stereo_recon.core.validate import check_output_dir

    t0 = time.perf_counter()
    cfg = replace(_job_config(args, args.resume), quiet=True)  # parallel jobs: no per-job progress lines
    validate_job(cfg)   # regulation, class, config: once, before any job
    check_output_dir(args.out, foreign_ok=True)   # holds one folder per recording, never replaced as a whole
    jobs = _batch_jobs(args, cfg)
    n_done = 0

    def progress(r):
        nonlocal n_done
        n_done += 1
        where = f" on {r['host']}" if r.get("host") and args.executor == "ray" else ""
        if r["ok"]:
            v = r.get("verdict") or {}
            status = (f"ok  L {r['length_m']:.3f}  W {r['width_m']:.3f}  H {r['height_m']:.3f} m  "
                      f"{v.get('overall', '') if isinstance(v, dict) else v}  {r['time_s']:.1f} s{where}")
        else:
            status = f"FAILED ({r.get('video')}){where}: {r['error']}"
        bar.write(f"[{n_done}/{len(jobs)}] {r['name']}: {status}")
        bar("batch", n_done, len(jobs))

    # One bar over all recordings (%, rate, ETA), each recording's line above it as it finishes.
    bar = StageProgress(("batch",), config=ProgressConfig(enabled=not getattr(args, "quiet", False)))
    with bar:
        bar("batch", 0, len(jobs))
        results = run_jobs(jobs, workers=args.workers, executor=args.executor, progress=progress,
                           ray_options=_ray_options(args))
    csv_path = write_summary_csv(args.out / SUMMARY_CSV, results, merge=args.resume)
    n_ok = sum(r["ok"] for r in results)
    failed = [r["name"] for r in results if not r["ok"]]
    print(f"{n_ok}/{len(results)} recordings measured in {time.perf_counter() - t0:.1f} s; summary: {csv_path}"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 0 if n_ok == len(results) else 1


def _batch_jobs(args, cfg) -> list:
    """One job per video: OUT/<stem>/ (OUT/<stem>-<i>/ when stems repeat); every file it reads is declared."""
    from stereo_recon.app.jobs import Job

    names = [v.stem for v in args.videos]
    dupes = {n for n in names if names.count(n) > 1}
    files = [str(p) for p in (args.calib, cfg.regulation) if p is not None and Path(p).is_file()]
    jobs = []
    for i, v in enumerate(args.videos):
        name = f"{v.stem}-{i}" if v.stem in dupes else v.stem
        out = str(args.out / name)
        jobs.append(Job(name, _run_one, (str(v), args.calib, out, cfg), inputs=(str(v), *files), outputs=(out,),
                        reuse_outputs=args.resume, info={"video": os.path.abspath(v)}))
    return jobs


def _cmd_bench_random(args) -> int:
    from stereo_recon.app.batch import run_jobs
    from stereo_recon.app.jobs import Job
    from stereo_recon.app.bench import bench_random_one, envelope_row, write_envelope
    from stereo_recon.synthetic.envelope import draw_spec

    if args.random < 1:
        raise ConfigError(f"--random: the number of draws must be >= 1, got {args.random}")
    if args.seed < 0:
        raise ConfigError(f"--seed: must be >= 0, got {args.seed}")
    if args.study or args.frames is not None or args.trucks != "1-20":
        raise ConfigError("--random: --study, --frames and --trucks apply to the Table 2 bench only (use --max-frames)")
    specs = [draw_spec(args.seed, i, max_frames=args.max_frames, scale=args.scale_only, resolution=args.resolution) for i in range(args.random)]
    draws = args.draws or (args.out / "draws")
    jobs = [Job(s.name, bench_random_one, (args.seed, s.index, str(draws), str(args.out / "runs" / f"draw_{s.index:03d}"), args.max_frames,
                                          args.scale_only, args.resolution)) for s in specs]

    def progress(r):
        row = envelope_row(r, specs[int(r["name"].rsplit("-", 1)[1])])
        if row["ok"]:
            e = row["error_pct"]
            print(f"[{r['name']}] {row['spec']['scale']} {row['spec']['kind']}: err L {e['length']:+.2f} W {e['width']:+.2f} "
                  f"H {e['height']:+.2f}%  {r['time_s']:.0f}s", file=sys.stderr)
        else:
            print(f"[{r['name']}] FAILED: {row['failure_reason']}", file=sys.stderr)

    results = run_jobs(jobs, workers=args.workers, executor=args.executor, progress=progress,
                       ray_options=_ray_options(args))
    ordered = [envelope_row(r, s) for r, s in zip(results, specs)]
    meta = {"seed": args.seed, "count": args.random, "max_frames": args.max_frames, "scale": args.scale_only, "resolution": args.resolution,
            "draws_dir": str(draws)}
    summary = write_envelope(args.out, meta, ordered)
    o = summary["dimensions"]["overall"]
    v = summary["verdicts"]
    print(f"{summary['draws']} draws, {summary['failed_draws']} failed; overall mean {o['mean_abs_pct'] if o['mean_abs_pct'] is not None else float('nan'):.2f}%, "
          f"p90 {o['p90_abs_pct'] if o['p90_abs_pct'] is not None else float('nan'):.2f}%, max "
          f"{o['max_abs_pct'] if o['max_abs_pct'] is not None else float('nan'):.2f}%, truth in ±2σ "
          f"{100 * (o['within_2sigma'] or 0):.0f}%; full-scale verdicts {v['right']}/{v['n_full_scale']} right, {v['sound']}/{v['n_full_scale']} sound")
    print(f"tables: {args.out / 'envelope.md'} {args.out / 'envelope.json'} {args.out / 'envelope.png'}")
    return 0 if summary["failed_draws"] == 0 else 1


def _cmd_bench(args) -> int:
    from stereo_recon.app.batch import run_jobs
    from stereo_recon.app.jobs import Job
    from stereo_recon.app.bench import bench_one, bench_summary, parse_truck_range, run_study, table_markdown, verdict_matches, write_bench

    from stereo_recon.core.validate import check_number, check_output_dir

    check_number("--workers", args.workers, integer=True, minimum=1, strict=False)
    check_number("--frames", args.frames, integer=True, minimum=3, strict=False)
    if args.random is not None:
        return _cmd_bench_random(args)
    out = check_output_dir(args.out, foreign_ok=True)   # scenes/, runs/, tables: never replaced as a whole
    trucks = parse_truck_range(args.trucks)
    if args.study:
        trucks = [t for t in trucks if t <= 6] or [1, 2, 3, 4, 5, 6]  # the paper's six training trucks
    rcfg = reconstruct_config(args)
    jobs = [Job(f"table2:{n}", bench_one, (f"table2:{n}", str(out / "scenes" / f"table2-{n}"), str(out / "runs" / f"table2-{n}"),
                                          args.seed + n, args.frames, rcfg),
                outputs=(str(out / "scenes" / f"table2-{n}"), str(out / "runs" / f"table2-{n}"))) for n in trucks]
    full = [] if (args.no_full_scale or args.study) else ["full-truck", "over-height"]
    jobs += [Job(p, bench_one, (p, str(out / "scenes" / p), str(out / "runs" / p), args.seed, args.frames, rcfg),
                 outputs=(str(out / "scenes" / p), str(out / "runs" / p))) for p in full]

    bar = StageProgress(("bench",), config=ProgressConfig(enabled=not getattr(args, "quiet", False)))
    finished = 0

    def progress(r):
        nonlocal finished
        finished += 1
        if r["ok"]:
            e = r["error_pct"]
            bar.write(f"[{r['name']}] L {r['length_m']:.3f} W {r['width_m']:.3f} H {r['height_m']:.3f}  "
                      f"err {e['length']:.2f}/{e['width']:.2f}/{e['height']:.2f}%  {r['time_s']:.1f}s")
        else:
            bar.write(f"[{r['name']}] FAILED: {r['error']}")
        bar("bench", finished, len(jobs))

    with bar:
        bar("bench", 0, len(jobs))
        results = run_jobs(jobs, workers=args.workers, executor=args.executor, progress=progress,
                           ray_options=_ray_options(args))
    model = [r for r in results if r["name"].startswith("table2:")]
    fullscale = [r for r in results if not r["name"].startswith("table2:")]
    # A study runs only the six training trucks: its table must not overwrite a full Table 2 in the same folder.
    md, js = write_bench(out, model, "table2-training" if args.study else "table2")
    print(table_markdown(model))
    s = bench_summary(model)
    print(json.dumps({k: s[k] for k in ("average_error_pct", "worst_single_dimension_error_pct", "median_time_s")}, indent=1))
    if fullscale:
        write_bench(out, fullscale, "full-scale")
        for r in fullscale:
            if r["ok"]:
                got = (r.get("verdict") or {}).get("overall")
                match = verdict_matches(r.get("expected_verdict"), r.get("verdict"), r.get("truth"))
                check = "no expectation" if match is None else ("right" if match else "WRONG")
                print(f"{r['name']}: L {r['length_m']:.2f} W {r['width_m']:.2f} H {r['height_m']:.2f} m, "
                      f"errors {r['error_pct']['overall']:.2f}% avg, verdict {got} (truth expects "
                      f"{r.get('expected_verdict')}: {check})")
    if args.study:
        clouds = []
        for r in model:
            if r["ok"]:
                clouds.append((r["name"], RunPaths(Path(r["out_dir"])).cloud, {f"{d}_m": r["truth"][d] for d in ("length", "width", "height")}))
        ups = {}
        for r in model:
            if r["ok"]:
                meta = json.loads(RunPaths(Path(r["out_dir"])).run_json.read_text())
                ups[r["name"]] = meta.get("up")
        res = run_study(args.study, clouds, out, up_hints=ups)
        d = res["default"]
        print(f"study {args.study}: optimum {res['optimum_m']} m (most accurate {res['most_accurate_m']} m, fastest "
              f"{res['fastest_m']} m); our default resolved to {d['resolved_m']} m: MSE {d['mean_mse_m2']}, "
              f"{d['mean_time_s']:.2f} s per truck; table {out / f'study-{args.study}.md'}")
    print(f"tables: {md} {js}")
    return 0 if all(r["ok"] for r in results) else 1
