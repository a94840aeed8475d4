"""The ``stereo-recon`` console command: one entry point, one subcommand per job.

Each command module exposes ``register(subparsers)``, which adds its parser(s) and sets
``func`` to a handler ``(args) -> int``. Library code never configures logging; this does.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from pathlib import Path

from stereo_recon import __version__
from stereo_recon.app.cli_help import finish_help
from stereo_recon.core.errors import StereoReconError
from stereo_recon.core.paths import LOG
from stereo_recon.core.validate import disk_full_message
from stereo_recon.core.progress import NativeOutputToLog, stream_is_tty, abandon_open, quiet_native_libraries, quiet_open3d

# Modules that contribute subcommands, in the order they appear in --help.
COMMAND_MODULES = (
    "stereo_recon.app.pipeline_cli",   # run, bench, batch
    "stereo_recon.app.reconstruct_cli",  # reconstruct
    "stereo_recon.app.measure_cli",                 # measure
    "calib.cli",                   # calibrate, calib-check
    "stereo_recon.synthetic.cli",  # synth
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stereo-recon",
        description="Truck length/width/height and over-limit verdicts from drone stereo video.",
    )
    parser.add_argument("--version", action="version", version=f"stereo-recon {__version__}")
    _add_verbosity(parser, top=True)
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
    for sp in sub.choices.values():
        _add_verbosity(sp, top=False)
    finish_help(parser, sub)
    return parser


def _add_verbosity(parser: argparse.ArgumentParser, top: bool) -> None:
    """-v/-q, on the main parser and again on each subcommand (so ``stereo-recon run -v`` works too)."""
    # On a subcommand the defaults are SUPPRESS, so an absent flag there keeps the main parser's value.
    parser.add_argument("-v", "--verbose", action="count", default=0 if top else argparse.SUPPRESS,
                        help="more log output on the terminal: -v info, -vv debug (log.txt always has debug) (default: warnings)")
    parser.add_argument("-q", "--quiet", action="store_true", default=False if top else argparse.SUPPRESS,
                        help="only errors on the terminal, no progress bars (default: off)")


_LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
# Third-party loggers that flood a debug log with internals (font lookup, PNG chunks).
_NOISY_LOGGERS = ("matplotlib", "PIL", "fontTools", "numba", "ray")


def _configure_logging(verbose: int, quiet: bool) -> None:
    """Terminal: WARNING (-v INFO, -vv DEBUG, -q ERROR), timestamped, written above any progress bar."""
    from stereo_recon.core.progress import TqdmLogHandler

    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    root = logging.getLogger()
    for h in list(root.handlers):
        if getattr(h, "_stereo_recon", False):
            root.removeHandler(h)
    root.setLevel(logging.DEBUG)  # the handlers choose; log.txt takes everything
    for name in _NOISY_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)
    if root.handlers:
        return  # a host (an embedding program, a test harness) already shows log records, as logging.basicConfig
    console = TqdmLogHandler(sys.stderr)
    console.setLevel(level)
    console.setFormatter(logging.Formatter(_LOG_FORMAT, datefmt="%H:%M:%S"))
    console._stereo_recon = True  # type: ignore[attr-defined]
    root.addHandler(console)


def _open_log_file(args, argv: list[str] | None) -> tuple[logging.Handler | None, Path | None, bool]:
    """A debug-level, timestamped ``log.txt`` in the command's output folder (appended; one header per command).

    Returns (handler, folder, whether the folder was created here); commands whose --out is a file get none.
    """
    out = getattr(args, "out", None)
    if out is None:
        return None, None, False
    folder = Path(out)
    if folder.suffix.lower() in _FILE_OUTPUTS:
        return None, None, False  # a file, not an output folder: no log beside it in someone's folder
    created = not folder.exists()
    log_path = folder / LOG
    log_size = log_path.stat().st_size if log_path.is_file() else None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handler = logging.FileHandler(folder / LOG, mode="a", encoding="utf-8")
    except OSError:
        return None, None, False  # the command itself reports an unusable --out
    handler.setLevel(logging.DEBUG)
    handler.setFormatter(logging.Formatter(_LOG_FORMAT.replace("%(asctime)s", "%(asctime)s.%(msecs)03d"),
                                           datefmt="%Y-%m-%dT%H:%M:%S"))
    handler._stereo_recon = True  # type: ignore[attr-defined]
    logging.getLogger().addHandler(handler)
    cmd = " ".join(sys.argv[:1] + list(sys.argv[1:] if argv is None else argv))
    logging.getLogger("stereo_recon.app.cli").debug("stereo-recon %s: %s (cwd %s)", __version__, cmd, Path.cwd())
    handler._folder_before = (_folder_state(folder), log_size)  # type: ignore[attr-defined]
    return handler, folder, created


def _folder_state(folder: Path) -> dict:
    """Names and (size, mtime) of a folder's entries other than log.txt: what a refused command must leave as it was."""
    try:
        return {e.name: (st.st_size, st.st_mtime_ns) for e in os.scandir(folder) if e.name != LOG
                for st in (e.stat(),)}
    except OSError:
        return {}


# Commands that import Open3D (its own warnings would reach the terminal).
_FUSING_COMMANDS = {"run", "reconstruct", "bench", "batch"}
# --out values that name a file, not a folder (calibrate's rig file, calib-check's JSON).
_FILE_OUTPUTS = {".yaml", ".yml", ".xml", ".json", ".conf"}


def _close_log_file(handler, folder: Path | None, created: bool, code: int, refused: bool) -> None:
    """Close log.txt; a folder this command created and left with nothing but the log of a refused input, option
    or failed stage is removed (a failure leaves no output folder behind; the error line says what went wrong)."""
    if handler is None:
        return
    logging.getLogger("stereo_recon.app.cli").debug("exit code %d", code)
    logging.getLogger().removeHandler(handler)
    handler.close()
    if not refused or folder is None:
        return
    before, log_size = getattr(handler, "_folder_before", (None, None))
    if _folder_state(folder) != before:
        return  # the command changed the folder (e.g. a kept reconstruction): its log stays with it
    # A refused command leaves the folder exactly as it was: its log lines go too.
    log_path = folder / LOG
    if log_size is None:
        log_path.unlink(missing_ok=True)
    else:
        with open(log_path, "r+b") as f:
            f.truncate(log_size)
    if created and not any(folder.iterdir()):
        folder.rmdir()


def main(argv: list[str] | None = None) -> int:
    native = NativeOutputToLog()
    if stream_is_tty(sys.stderr):
        # On a terminal the libraries' own messages are taken into the log (below), so FFmpeg may speak up to
        # its warnings there; elsewhere it stays quiet.
        os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "24")   # AV_LOG_WARNING
    quiet_native_libraries()  # before any cv2/open3d import: FFmpeg and Open3D messages stay off the terminal
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    if not stream_is_tty(sys.stderr):
        # Piped or redirected, what COLMAP (glog) prints reaches stderr unfiltered (on a terminal it goes to the
        # log, below): its per-image INFO lines only with -vv, its warnings not with -q. glog reads this when
        # pycolmap is first imported, which no command has done yet.
        os.environ.setdefault("GLOG_minloglevel", "2" if args.quiet else ("0" if args.verbose >= 2 else "1"))
    with native:   # before logging and progress take their streams: C/C++ output goes to log.txt
        return _run_command(args, argv)


def _run_command(args, argv: list[str] | None) -> int:
    """Configure logging and log.txt, run the subcommand, turn user errors into one line and an exit code."""
    _configure_logging(args.verbose, args.quiet)
    handler, folder, created = _open_log_file(args, argv)
    code, refused = 1, False
    if args.command in _FUSING_COMMANDS:
        quiet_open3d()
    try:
        code = int(args.func(args) or 0)
    except (StereoReconError, OSError) as err:
        # A user error, or a disk that ran out of space (the command could not do its job: exit 2, as for a
        # failed stage): one line. Any other OSError is a bug to report, with its traceback.
        if isinstance(err, StereoReconError):
            msg = " ".join(str(err).split())  # one line, always
        else:
            msg = disk_full_message(err, folder if folder is not None else Path.cwd())
        abandon_open()
        if msg is None:
            logging.getLogger("stereo_recon.app.cli").exception("unexpected failure")
            raise
        refused = True
        logging.getLogger("stereo_recon.app.cli").debug("error", exc_info=True)
        print(f"stereo-recon {args.command}: error: {msg}", file=sys.stderr)
        code = getattr(err, "exit_code", 2)
    except KeyboardInterrupt:
        abandon_open()
        print(f"stereo-recon {args.command}: interrupted", file=sys.stderr)
        code = 130
    except BaseException:
        abandon_open()
        logging.getLogger("stereo_recon.app.cli").exception("unexpected failure")
        raise
    finally:
        _close_log_file(handler, folder, created, code, refused)
    return code


if __name__ == "__main__":
    sys.exit(main())
