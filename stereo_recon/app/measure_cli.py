"""``stereo-recon measure CLOUD --out DIR``: truck dimensions and over-limit verdict from a point cloud."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from stereo_recon.core.errors import InputError
from stereo_recon.core.paths import RunPaths

# CLI flag -> MeasureConfig field (overrides of the main parameters).
_OVERRIDES = {
    "resolution": ("resolution_m", float, "point spacing in metres (default: measured median nearest-neighbour distance)"),
    "eps": ("eps_m", float, "FoF friendship distance ε in metres (default: 3 x resolution)"),
    "ground_band": ("ground_band_m", float, "ground band half-thickness ξ in metres (default: 2 x resolution)"),
    "ground_thickness": ("ground_thickness_m", float, "ground removal thickness d_h in metres (default: 3.5 x resolution)"),
    "min_cluster_points": ("min_cluster_points", int, "fewest points of a truck cluster (default 300)"),
    "max_cluster_points": ("max_cluster_points", int, "most points of a truck cluster (default: no limit)"),
    "min_length": ("min_length_m", float, "shortest truck-like cluster in metres (default: 50 x resolution)"),
    "max_length": ("max_length_m", float, "longest truck-like cluster in metres (default: no limit)"),
    "bootstrap": ("bootstrap", int, "bootstrap replicates for the uncertainties (default 30)"),
    "seed": ("seed", int, "random seed (default 0)"),
}


def add_case_options(p: argparse.ArgumentParser) -> None:
    """--site, --operator, --case-id: free text shown on the report's first page and kept in measurement.json."""
    p.add_argument("--site", default=None, help="where the truck was measured, e.g. \"G4 toll gate 12\" (shown in the report)")
    p.add_argument("--operator", default=None, help="who flew/measured (shown in the report)")
    p.add_argument("--case-id", default=None, help="the agency's case or ticket number (shown in the report)")


def case_fields(args) -> dict | None:
    """{site, operator, case_id} from the options above, or None when none was given."""
    case = {k: getattr(args, k, None) for k in ("site", "operator", "case_id")}
    return {k: v for k, v in case.items() if v} or None


def _vec3(text: str) -> tuple[float, float, float]:
    try:
        parts = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z numbers, got {text!r}") from None
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers X,Y,Z, got {text!r}")
    return tuple(parts)  # type: ignore[return-value]


def data_quality_line(dq) -> str:
    """One terminal line for a ``data_quality`` block (absent in older files)."""
    if not dq:
        return "data quality: not recorded"
    bad = [c for c in dq.get("checks", []) if c.get("status") == "fail"]
    warn = [c for c in dq.get("checks", []) if c.get("status") == "warn"]
    if bad:
        return "data quality: FAILED (" + "; ".join(f"{c['name']}: {c['detail']}" for c in bad) + ")"
    return f"data quality: ok ({len(dq.get('checks', []))} checks" + (f", warnings: {', '.join(c['name'] for c in warn)}" if warn else "") + ")"


def register(subparsers) -> None:
    """Add the ``measure`` subcommand."""
    p = subparsers.add_parser(
        "measure",
        help="measure a truck's length, width and height in a point cloud",
        description="Measure the truck in a point cloud (PLY, PCD, XYZ, PTS): ground plane, FoF clustering, "
        "truck cluster, length/width by PCA + KDE, robust height; writes DIR/measurement.json, PNG plots and report.html.",
    )
    p.add_argument("cloud", help="point cloud file (.ply, .pcd, .xyz, .pts), metres")
    p.add_argument("--out", required=True, help="output folder (written only when the measurement succeeds)")
    p.add_argument("--regulation", default="cn-2016-62", help="regulation table: a built-in name or a .toml/.yaml/.json file (default cn-2016-62)")
    p.add_argument("--vehicle-class", default=None, help="vehicle class in the regulation table (default: the table's default)")
    p.add_argument("--scale", type=float, default=None, help="model-to-real scale factor (a scale model gets a legal verdict only with it)")
    p.add_argument("--config", default=None, help="TOML/YAML file of measure parameters (unknown keys are rejected)")
    p.add_argument("--up", type=_vec3, default=None, metavar="X,Y,Z", help="approximate up direction in the cloud's frame (default: estimated); write --up=X,Y,Z when X is negative")
    p.add_argument("--centre", "--center", dest="centre", type=_vec3, default=None, metavar="X,Y,Z", help="a point near the truck (e.g. the orbit centre), to choose among several vehicles; --centre=X,Y,Z when X is negative")
    p.add_argument("--units", choices=("m", "cm", "mm"), default="m", help="length unit of the cloud's coordinates (default m)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots and the HTML report")
    add_case_options(p)
    for flag, (_, typ, help_) in _OVERRIDES.items():
        p.add_argument(f"--{flag.replace('_', '-')}", dest=flag, type=typ, default=None, help=help_)
    p.set_defaults(func=run)


def run(args) -> int:
    """Handler: measure, write the outputs, print a short summary."""
    from measure.limits import load_regulation
    from measure.pipeline import MeasureConfig, load_config, measure_cloud_file
    from stereo_recon.app.evidence import keyframe_with_box
    from stereo_recon.core.progress import ProgressConfig, StageProgress
    from stereo_recon.core.validate import check_number, check_output_dir

    # Everything is checked before any work: options, config, regulation and class, output folder.
    for flag, (_, typ, _) in _OVERRIDES.items():
        check_number(f"--{flag.replace('_', '-')}", getattr(args, flag), integer=typ is int,
                     strict=flag not in ("seed", "bootstrap"))
    check_number("--scale", args.scale)
    for flag, vec in (("--up", args.up), ("--centre", args.centre)):
        if vec is not None and not all(map(math.isfinite, vec)):
            raise InputError(f"{flag} {','.join(f'{v:g}' for v in vec)}: must be three finite numbers")
    if args.up is not None and not any(args.up):
        raise InputError("--up 0,0,0: not a direction")
    cfg = load_config(args.config) if args.config else MeasureConfig()
    over = {field: getattr(args, flag) for flag, (field, _, _) in _OVERRIDES.items()}
    cfg = cfg.with_overrides(**over)
    load_regulation(args.regulation).limits(args.vehicle_class)
    out = check_output_dir(args.out)
    if not Path(args.cloud).is_file():
        raise InputError(f"{args.cloud}: no such file" if not Path(args.cloud).exists() else f"{args.cloud}: not a file")
    with StageProgress(("measure", "plots", "report"), config=ProgressConfig(enabled=not getattr(args, "quiet", False))) as progress:
        res = measure_cloud_file(args.cloud, out, cfg, up_hint=args.up, centre_hint=args.centre, regulation=args.regulation,
                                 vehicle_class=args.vehicle_class, scale=args.scale, plots=not args.no_plots,
                                 html=not args.no_plots, progress=progress, case=case_fields(args),
                                 units=args.units, centre_strict=args.centre is not None, keyframe=keyframe_with_box)
    u = res["uncertainty_m"]
    v = res.get("verdict") or {}
    print(f"{args.cloud}: truck of {res['clusters']['n_truck_points']} points")
    for d in ("length", "width", "height"):
        vd = (v.get("dimensions") or {}).get(d) or {}
        line = f"  {d:<6} {res[d + '_m']:8.3f} m ± {u[d]:.3f} m"
        if args.scale is not None and vd.get("value_m") is not None:
            # the verdict is about the real size: print that next to it, not the model's
            line += f"  = {vd['value_m']:.3f} m ± {vd.get('uncertainty_m') or 0:.3f} m real (x{args.scale:g})"
        print(f"{line}  [{res['rules'][d]}]  {vd.get('verdict', '')}")
    print(f"  verdict: {v.get('overall')}{' — ' + v['reason'] if v.get('reason') else ''}")
    print(f"  {data_quality_line(res.get('data_quality'))}")
    print(f"  written: {RunPaths(out).measurement}")
    return 0
