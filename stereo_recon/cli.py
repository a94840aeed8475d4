"""The ``stereo-recon`` console command: one entry point, one subcommand per job.

Each command module exposes ``register(subparsers)``, which adds its parser(s) and sets
``func`` to a handler ``(args) -> int``. Library code never configures logging; this does.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from stereo_recon import __version__
from stereo_recon.errors import StereoReconError

# Modules that contribute subcommands, in the order they appear in --help.
COMMAND_MODULES = (
    "stereo_recon.pipeline_cli",   # run, bench, batch
    "stereo_recon.reconstruct_cli",  # reconstruct
    "measure.cli",                 # measure
    "calib.cli",                   # calibrate, calib-check
    "stereo_recon.synthetic.cli",  # synth
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stereo-recon",
        description="Truck length/width/height and over-limit verdicts from drone stereo video.",
    )
    parser.add_argument("--version", action="version", version=f"stereo-recon {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("-q", "--quiet", action="store_true", help="only errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as err:
            # A command whose module is not part of this build is simply absent.
            if err.name and name.startswith(err.name):
                continue
            raise
        mod.register(sub)
    return parser


def _configure_logging(verbose: int, quiet: bool) -> None:
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    _configure_logging(args.verbose, args.quiet)
    try:
        return int(args.func(args) or 0)
    except StereoReconError as err:
        msg = " ".join(str(err).split())  # one line, always
        print(f"stereo-recon {args.command}: error: {msg}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print(f"stereo-recon {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
