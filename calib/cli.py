"""``stereo-recon calibrate`` and ``stereo-recon calib-check``: thin command layers over ``calib``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="calibrate a stereo rig from a board video or image pairs",
        description="Calibrate a stereo rig from a side-by-side video (frames chosen automatically) or a folder "
                    "of left/right image pairs (left01.jpg/right01.jpg, or left/ and right/ subfolders). Writes the "
                    "rig YAML, <out>.report.json and <out>.coverage.png.")
    p.add_argument("input", help="side-by-side video, or folder of left/right image pairs")
    p.add_argument("--board", required=True,
                   help="chessboard:COLSxROWS:SQUARE_M (inner corners) or charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT (squares)")
    p.add_argument("--out", required=True, help="rig file to write (.yaml, .yml or .xml)")
    p.add_argument("--max-frames", type=int, default=40, help="use at most N board views (default 40)")
    p.add_argument("--min-views", type=int, default=6, help="refuse with fewer usable views (default 6)")
    p.add_argument("--rational-model", action="store_true", help="8-coefficient distortion (strong wide-angle lenses)")
    p.add_argument("--fix-intrinsics", action="store_true",
                   help="keep each eye's own intrinsics in the pair solve (default: refine them jointly)")
    p.add_argument("--zed-conf", metavar="PATH", help="also write the result as a ZED-style .conf (a folder gets SN0.conf)")
    p.set_defaults(func=run_calibrate)

    c = subparsers.add_parser(
        "calib-check",
        help="check a calibration against a video (row alignment of matched features)",
        description="Match features between the eyes of a few frames and compare their row offsets raw and after "
                    "rectification with --calib: says whether the calibration fits, whether the video is already "
                    "rectified (do not rectify again) or raw. Exit status (as diff and cmp): 0 when the calibration fits, "
                    "1 when it does not (a mismatch, including a calibration for another aspect ratio; already rectified; "
                    "swapped eyes; too few matches to tell), 2 when the check cannot run (unreadable video or calibration "
                    "file, bad option).")
    c.add_argument("input", help="side-by-side video or image, or folder of left/right image pairs")
    c.add_argument("--calib", required=True,
                   help="ZED .conf, rig YAML/XML, or fx,fy,cx,cy,baseline_m[,width,height] for rectified frames")
    c.add_argument("--frames", type=int, default=8, help="frames spread over the video to check (default 8)")
    c.add_argument("--board", help="also report the epipolar error of board corners (same spec as calibrate)")
    c.add_argument("--out", help="write the check as JSON here")
    c.set_defaults(func=run_calib_check)


def _check_out_path(out: str):
    from stereo_recon.core.errors import ConfigError

    p = Path(out)
    if p.suffix.lower() not in (".yaml", ".yml", ".xml"):
        raise ConfigError(f"--out {out}: the rig file must end in .yaml, .yml or .xml")
    if p.exists() and p.is_dir():
        raise ConfigError(f"--out {out}: is a folder")
    return p


def run_calibrate(args: argparse.Namespace) -> int:
    import cv2

    from calib.boards import parse_board
    from calib.calibrate import CalibConfig, calibrate_source, coverage_image
    from calib.io import save_rig
    from stereo_recon.core.atomic import staged_files, write_bytes_atomic, write_json_atomic
    from stereo_recon.core.errors import ConfigError, InputError, StageError
    from stereo_recon.core.manifest import Stopwatch, run_manifest

    out = _check_out_path(args.out)
    spec = parse_board(args.board)
    if args.zed_conf and args.rational_model:
        raise ConfigError("--zed-conf: a ZED .conf holds k1 k2 p1 p2 k3 only; drop --rational-model or --zed-conf")
    if args.max_frames < 3:
        raise ConfigError(f"--max-frames {args.max_frames}: need at least 3")
    if args.min_views < 3:
        raise ConfigError(f"--min-views {args.min_views}: need at least 3")
    src = Path(args.input)
    if not src.exists():
        raise InputError(f"{src}: not found")
    cfg = CalibConfig(max_frames=args.max_frames, min_views=min(args.min_views, args.max_frames),
                      rational_model=args.rational_model, refine_intrinsics=not args.fix_intrinsics)
    sw = Stopwatch()
    with sw.stage("calibrate"):
        result, col = calibrate_source(src, spec, cfg)
    with sw.stage("coverage"):
        png = coverage_image(result, spec, col.background)
        ok, buf = cv2.imencode(".png", png)
        if not ok:
            raise StageError("calibrate", "could not encode the coverage image")
    rep = result.report
    report_path = out.with_name(out.stem + ".report.json")
    cov_path = out.with_name(out.stem + ".coverage.png")
    rep["files"] = {"rig": str(out), "report": str(report_path), "coverage": str(cov_path)}
    rep["run"] = run_manifest("calibrate", {}, {"board": str(spec), "max_frames": cfg.max_frames,
                                               "min_views": cfg.min_views, "rational_model": cfg.rational_model,
                                               "refine_intrinsics": cfg.refine_intrinsics}, sw.timings_s)
    # write everything to temporary names first, then move into place: no half-written results
    with staged_files(out.parent, prefix=out.name) as tx:
        tx.add(write_json_atomic(tx.temp(report_path.name), rep), report_path)
        tx.add(write_bytes_atomic(tx.temp(cov_path.name), buf.tobytes()), cov_path)
        tx.add(save_rig(result.rig, tx.temp(out.name)), out)
        if args.zed_conf:
            tx.add(_write_zed_conf_temp(result.rig, tx.temp("zed.conf"), args.zed_conf), _zed_conf_path(args.zed_conf))
    _print_calibration(rep, out, report_path, cov_path)
    return 0


def _write_zed_conf_temp(rig, tmp: Path, zed_conf: str) -> Path:
    """Write the rig as a ZED .conf to ``tmp``; an error names the user's ``--zed-conf`` path, not the temporary one."""
    from calib.zedconf import write_zed_conf
    from stereo_recon.core.errors import InputError

    try:
        return write_zed_conf(rig, tmp)
    except InputError as err:
        raise InputError(str(err).replace(str(tmp), f"--zed-conf {zed_conf}")) from None


def _zed_conf_path(zed_conf: str) -> Path:
    """Where ``--zed-conf`` puts the .conf: the path itself, or ``SN0.conf`` inside a folder."""
    zp = Path(zed_conf)
    if zp.is_dir() or zed_conf.endswith(("/", "\\")) or zp.suffix.lower() != ".conf":
        zp = zp / "SN0.conf"
    return zp


def _print_calibration(rep: dict, out: Path, report_path: Path, cov_path: Path) -> None:
    """The terminal summary of a calibration: errors, baseline, coverage, per-view RMS, files written."""
    rms, epi = rep["rms_px"], rep["epipolar_error_px"]
    print(f"calibrated from {rep['views_used']} views ({rep['views_rejected']} rejected as outliers; "
          f"board found in both eyes in {rep['found_in_both_eyes']} of {rep['looked_at']} looked at)")
    print(f"RMS reprojection error: pair {rms['pair']:.3f} px, left {rms['left']:.3f} px, right {rms['right']:.3f} px")
    print(f"rectified epipolar error: median {epi['median']:.3f} px, p95 {epi['p95']:.3f} px")
    print(f"baseline {rep['baseline']:.5g} ({rep['baseline_units']}), rectified focal {rep['rectified']['focal_px']:.2f} px")
    cov = rep["coverage_fraction"]
    print(f"image coverage (8x6 cells with corners): left {100 * cov['left']:.0f}%, right {100 * cov['right']:.0f}%")
    if min(cov.values()) < 0.5:
        print("  hint: the board was seen in less than half of the image; views with the board near the edges and "
              "corners determine the distortion better (see the coverage image)")
    print("per view RMS px (pair / left / right):")
    for v in rep["per_view"]:
        if v.get("used"):
            print(f"  {v['view']}: {v['rms_px']:.3f} / {v['left_rms_px']:.3f} / {v['right_rms_px']:.3f}")
        elif "outlier" in v.get("reason", ""):
            print(f"  {v['view']}: rejected, {v['reason']}")
        else:
            log.info("  %s: not used (%s)", v["view"], v.get("reason", ""))
    print(f"wrote {out}, {report_path.name}, {cov_path.name}")


def _sample_pairs(src: Path, n: int):
    from calib.calibrate import IMAGE_SUFFIXES, read_image, iter_folder_pairs, iter_video_pairs, video_info
    from stereo_recon.core.frames import split_side_by_side

    if src.is_file() and src.suffix.lower() in IMAGE_SUFFIXES:  # one side-by-side image
        left, right = split_side_by_side(read_image(src), str(src), check_aspect=False)
        return [(src.name, left, right)], (left.shape[1], left.shape[0])
    if src.is_dir():
        pairs = list(iter_folder_pairs(src, max_pairs=n))
        return pairs, ((pairs[0][1].shape[1], pairs[0][1].shape[0]) if pairs else None)
    count, size, _ = video_info(src)
    if count <= 0:
        count = n
    idx = set(np.linspace(0, max(0, count - 1), n).round().astype(int).tolist())
    pairs = [(f"frame {i}", l, r) for i, l, r in iter_video_pairs(src, indices=idx)]
    return pairs, size


def run_calib_check(args: argparse.Namespace) -> int:
    from calib.boards import DetectConfig, parse_board
    from calib.calibrate import PairView, detect_pair, epipolar_errors
    from calib.check import check_pairs
    from calib.io import parse_calib_arg
    from stereo_recon.core.errors import ConfigError, InputError
    from stereo_recon.core.atomic import write_json_atomic

    src = Path(args.input)
    if not src.exists():
        raise InputError(f"{src}: not found")
    if args.frames < 1:
        raise ConfigError(f"--frames {args.frames}: need at least 1")
    if args.out:
        from stereo_recon.core.validate import check_output_file

        check_output_file(args.out)
    spec = parse_board(args.board) if args.board else None
    pairs, size = _sample_pairs(src, args.frames)
    if not pairs:
        raise InputError(f"{src}: no frames could be read")
    try:
        rig = parse_calib_arg(args.calib, image_size=size)
    except InputError as err:
        if "aspect ratio" not in str(err):
            raise  # unreadable or broken calibration: the check cannot run (2)
        # A calibration for frames of another shape is a finding about the pair (it does not fit: 1), not a broken file.
        print(f"calibration_mismatch: {' '.join(str(err).split())}")
        if args.out:
            write_json_atomic(args.out, {"verdict": "calibration_mismatch", "message": str(err), "calib": args.calib,
                                         "input": str(src), "image_size": list(size)})
        return 1
    result = check_pairs(pairs, rig)
    if spec is not None:
        views: list[PairView] = []
        for name, left, right in pairs:
            v, _ = detect_pair(name, left, right, spec, DetectConfig())
            if v is not None:
                views.append(v)
        if views:
            e = epipolar_errors(rig, views, spec)
            result["board_epipolar_error_px"] = {"views": len(views), "median": float(np.median(e)),
                                                 "p95": float(np.percentile(e, 95))}
        else:
            result["board_epipolar_error_px"] = {"views": 0, "note": f"board not found in both eyes of {len(pairs)} frames"}
    result["calib"] = args.calib
    result["input"] = str(src)
    raw, rec = result["raw"], result["rectified"]
    print(f"checked {len(pairs)} frames of {src} ({rig.image_size[0]}x{rig.image_size[1]} per eye), "
          f"{raw['matches']} feature matches")
    print(f"row offset |dy|: raw median {raw['median_dy_px']:.2f} px / p95 {raw['p95_dy_px']:.2f} px; "
          f"rectified median {rec['median_dy_px']:.2f} px / p95 {rec['p95_dy_px']:.2f} px")
    if "board_epipolar_error_px" in result and result["board_epipolar_error_px"].get("views"):
        b = result["board_epipolar_error_px"]
        print(f"board corners after rectification: median {b['median']:.3f} px, p95 {b['p95']:.3f} px ({b['views']} views)")
    print(f"{result['verdict']}: {result['message']}")
    if args.out:
        write_json_atomic(args.out, result)
    return 0 if result["verdict"] == "ok" else 1

