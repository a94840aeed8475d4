"""``stereo-recon synth``: render a synthetic ZED2 drone sequence with exact ground truth."""

from __future__ import annotations

from stereo_recon.synthetic.seeds import EVALUATION_SEED, TUNING_SEEDS_TEXT

RANDOM_SEEDS_HELP = f"{TUNING_SEEDS_TEXT} are for tuning, {EVALUATION_SEED} (EVALUATION_SEED) for the next reported figures"
PRESET_HELP = ("model-truck (2.1 x 0.38 x 0.38 m, the paper's scale), full-truck (12 x 2.55 x 4.0 m), over-height (4.3 m tall), "
               "two-vehicles, calibration-board (chessboard video), table2:N (N = 1..20, the paper's Table 2 trucks)")


def register(subparsers) -> None:
    """Add the ``synth`` subcommand."""
    p = subparsers.add_parser(
        "synth",
        help="render a synthetic ZED2 drone stereo video with exact ground truth",
        description="Render a side-by-side stereo video of a synthetic scene as a drone-borne ZED2 records it, plus its "
                    "calibration (SN<serial>.conf, rig.yaml), ground-truth poses (poses_gt.txt) and truth.json. "
                    "World frame: metres, z up, ground z = 0; poses are world-from-left-camera (OpenCV axes).",
    )
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--preset", metavar="NAME", help=PRESET_HELP)
    which.add_argument("--random", type=int, metavar="K", default=None,
                       help="K random scenes of the operating envelope into DIR/draw_000 ... (draw i of seed S is the same whatever K; "
                            f"seeds {RANDOM_SEEDS_HELP})")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (written atomically)")
    p.add_argument("--seed", type=int, default=0, help="random seed; the same seed gives the same bytes (default 0)")
    p.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="with --random: cap each draw's 60-200 frames at N for a quick run (recorded in the draw's spec)")
    p.add_argument("--scale-only", choices=("model", "full"), default=None,
                   help="with --random: only model-scale or only full-scale trucks (the other factors are drawn as usual)")
    p.add_argument("--frames", type=int, default=None, help="number of stereo frames (default: the preset's)")
    p.add_argument("--rectified", action="store_true", help="render ideal rectified pinhole pairs (like an SVO export) instead of raw distorted eyes")
    p.add_argument("--resolution", default="HD720", metavar="RES", help="ZED resolution: HD720 (default), FHD, 2K or VGA")
    p.add_argument("--depth", action="store_true", help="also write left-eye ground-truth z-depth maps (depth/NNNNNN.npy, float32 m)")
    p.add_argument("--format", dest="video_format", default="avi", choices=("avi", "mp4"), help="video container: MJPG AVI (default) or mp4v MP4")
    p.add_argument("--flight", default="orbit", choices=("orbit", "pass"), help="orbit around the truck (default) or a straight pass beside it")
    p.add_argument("--arc", type=float, default=None, metavar="DEG", help="orbit sweep in degrees (default 360)")
    p.add_argument("--quality", type=int, default=90, help="JPEG quality 1..100 of the AVI frames (default 90)")
    p.add_argument("--noise", type=float, default=1.5, metavar="DN", help="sensor noise std in grey levels (default 1.5)")
    p.add_argument("--blur", type=float, default=0.0, metavar="PX", help="Gaussian blur sigma in pixels (default 0)")
    p.add_argument("--no-shadows", action="store_true", help="skip the shadow rays (faster)")
    p.set_defaults(func=_run)


# Options that shape a preset's rendering; a random draw takes all of them from its spec. (``--depth`` is not
# one: it adds the rendered depth maps beside the same video, for ``benchmarks/bench_depth_bias.py``.)
_PRESET_ONLY = (("frames", None), ("rectified", False), ("video_format", "avi"), ("flight", "orbit"), ("arc", None),
                ("quality", 90), ("noise", 1.5), ("blur", 0.0), ("no_shadows", False))


def _run_random(args) -> int:
    from stereo_recon.core.errors import ConfigError
    from stereo_recon.synthetic.envelope import render_random

    given = [n for n, default in _PRESET_ONLY if getattr(args, n) != default]
    if given:
        raise ConfigError(f"--random: {', '.join('--' + n.replace('_', '-') for n in given)} apply to --preset only (a draw's spec sets them)")
    if args.seed < 0:
        raise ConfigError(f"--seed: must be >= 0, got {args.seed}")
    truths = render_random(args.random, args.seed, args.out, max_frames=args.max_frames, scale=args.scale_only, resolution=args.resolution,
                           depth=args.depth)
    for i, t in enumerate(truths):
        sp = t["random_spec"]
        print(f"{args.out}/draw_{i:03d}: {t['frames']} frames, {sp['truck']['scale']} {sp['truck']['kind']} {t['length_m']:.3f} x "
              f"{t['width_m']:.3f} x {t['height_m']:.3f} m, {sp['panel']['texture_class']} paint, radius {sp['flight']['radius_over_length']:.2f} L, "
              f"elevation {sp['flight']['elevation_deg']:.0f} deg, expected verdict {t['over_limit_expectation']['verdict']}")
    return 0


def _run(args) -> int:
    from stereo_recon.core.errors import ConfigError

    if args.random is not None:
        return _run_random(args)
    if args.max_frames is not None or args.scale_only is not None:
        raise ConfigError("--max-frames and --scale-only apply to --random only (use --frames with a preset)")
    from stereo_recon.synthetic.render import RenderConfig
    from stereo_recon.synthetic.sequence import render_sequence

    if args.noise < 0 or args.blur < 0:
        raise ConfigError("--noise and --blur must be >= 0")
    if args.seed < 0:
        raise ConfigError(f"--seed: must be >= 0, got {args.seed}")
    cfg = RenderConfig(noise_sigma_dn=args.noise, blur_sigma_px=args.blur, shadows=not args.no_shadows)
    truth = render_sequence(args.preset, args.out, seed=args.seed, frames=args.frames, rectified=args.rectified, resolution=args.resolution,
                            depth=args.depth, video_format=args.video_format, flight=args.flight, jpeg_quality=args.quality,
                            render_config=cfg, arc_deg=args.arc)
    if truth.get("kind") == "truck":
        verdict = truth["over_limit_expectation"]["verdict"]
        print(f"{args.out}: {truth['frames']} frames of {truth['preset']} (L x W x H = {truth['length_m']:.3f} x {truth['width_m']:.3f} x "
              f"{truth['height_m']:.3f} m, expected verdict {verdict})")
    else:
        b = truth["board"]
        print(f"{args.out}: {truth['frames']} frames of a {b['inner_corners'][0]}x{b['inner_corners'][1]} chessboard, {b['square_m'] * 1000:.0f} mm squares")
    return 0
