"""Terminal progress for the CLI: stage k/N, a tqdm bar with %, rate and ETA, and log lines that do not garble it.

Library code only calls a ``ProgressFn`` ``(stage, done, total or None)`` it was given; this module
turns those calls into what a person at the terminal sees. On a terminal each stage gets a tqdm bar
(an elapsed-time line, refreshed every second, for stages without a count); when stderr is not a
terminal (a pipe, a CI log, ``nohup``) it writes plain lines instead, one per update at most every
``plain_interval_s`` seconds, so a log file is readable. Log records go through :class:`TqdmLogHandler`,
which writes above the bar instead of into it.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
import weakref
from dataclasses import dataclass
from typing import Sequence

from tqdm import tqdm

# Stage names the reconstruction and the run report, in pipeline order; how the terminal names them.
RUN_STAGES = ("depth", "poses", "sfm", "motion stereo", "fusion", "extract", "measure", "plots", "report")
STAGE_LABELS = {
    "depth": "decode, rectify, depth + VO",
    "poses": "poses",
    "sfm": "SfM bundle adjustment",
    "motion stereo": "motion stereo",
    "fusion": "TSDF fusion",
    "extract": "extract cloud",
    "measure": "measure (ground, clusters, dimensions)",
    "plots": "plots",
    "report": "report",
    "bench": "bench: trucks rendered, reconstructed and measured",
}
STAGE_UNITS = {"depth": "frame", "fusion": "view", "motion stereo": "view", "bench": "truck"}


@dataclass(frozen=True)
class ProgressConfig:
    """How progress is shown."""

    enabled: bool = True            # False: nothing at all (-q)
    tty: bool | None = None         # None: ask the stream; True: tqdm bars; False: plain lines
    plain_interval_s: float = 10.0  # plain mode: at most one line per stage this often (plus start and end)
    tick_s: float = 1.0             # how often an open stage's elapsed time is refreshed


class StageProgress:
    """A ``ProgressFn`` that shows stage k/N with a bar (tqdm) on a terminal, plain lines elsewhere.

    stages: the stage names in order (k/N counts in this list; a name not in it is shown without k/N).
    stream: where progress goes (default ``sys.stderr``).
    """

    def __init__(self, stages: Sequence[str] = RUN_STAGES, stream=None, config: ProgressConfig = ProgressConfig()):
        self.stages = list(stages)
        self.stream = stream or sys.stderr
        self.config = config
        isatty = getattr(self.stream, "isatty", lambda: False)()
        self.tty = isatty if config.tty is None else config.tty
        self._lock = threading.RLock()
        self._stage: str | None = None
        self._bar: tqdm | None = None
        self._t0 = 0.0
        self._done = 0
        self._total: int | None = None
        self._last_line = 0.0
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    # -- the ProgressFn interface ------------------------------------------------------------
    def __call__(self, stage: str, done: int, total: int | None) -> None:
        if not self.config.enabled:
            return
        with self._lock:
            if stage != self._stage:
                self._open(stage, total)
            self._done, self._total = int(done), (int(total) if total else None)
            if self._bar is not None:
                if self._total is not None and self._bar.total != self._total:
                    self._bar.total = self._total
                self._bar.update(self._done - self._bar.n)
            elif time.perf_counter() - self._last_line >= self.config.plain_interval_s:
                self._plain_line()

    def start(self, stage: str, total: int | None = None) -> None:
        """Open a stage that may not report a count (elapsed time is shown while it runs)."""
        self(stage, 0, total)

    def write(self, line: str) -> None:
        """A line of text above the bar (e.g. a finished job)."""
        with self._lock:
            if self._bar is not None:
                self._bar.write(line, file=self.stream)
            else:
                self.stream.write(line + "\n")
                self.stream.flush()

    def close(self, failed: bool = False) -> None:
        """Finish the open stage (its line stays) and stop the ticker; ``failed``: no 'done' line, the bar is cleared
        (the error message that follows is the only line a refused input gives)."""
        _OPEN.discard(self)
        with self._lock:
            self._finish(failed)
        self._stop.set()
        if self._ticker is not None and self._ticker is not threading.current_thread():
            self._ticker.join(timeout=2.0)
        self._ticker = None

    def __enter__(self) -> "StageProgress":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(failed=exc_type is not None)

    # -- internals ---------------------------------------------------------------------------
    def _desc(self, stage: str) -> str:
        label = STAGE_LABELS.get(stage, stage)
        if stage in self.stages and len(self.stages) > 1:
            return f"[{self.stages.index(stage) + 1}/{len(self.stages)}] {label}"
        return label

    def _open(self, stage: str, total: int | None) -> None:
        self._finish()
        _OPEN.add(self)
        self._stage, self._t0, self._done, self._total = stage, time.perf_counter(), 0, total
        self._last_line = self._t0  # plain mode: the first line after plain_interval_s (a quick stage: only 'done')
        if self.tty:
            # A count-less stage shows only its elapsed time; a counted one bar, %, rate and ETA.
            fmt = None if total else ("{desc}: {n_fmt} {unit}s, {elapsed} elapsed" if stage in STAGE_UNITS
                                      else "{desc}: {elapsed} elapsed")
            self._bar = tqdm(total=total or None, desc=self._desc(stage), file=self.stream, unit=STAGE_UNITS.get(stage, "it"),
                             leave=True, dynamic_ncols=True, mininterval=0.2, smoothing=0.1, bar_format=fmt)
        if self._ticker is None:
            self._stop.clear()
            self._ticker = threading.Thread(target=self._tick, name="progress-ticker", daemon=True)
            self._ticker.start()

    def _finish(self, failed: bool = False) -> None:
        if self._stage is None:
            return
        if failed:
            if self._bar is not None:
                self._bar.leave = False
                self._bar.close()
                self._bar = None
            self._stage = None
            return
        if self._bar is not None:
            if self._total is None:
                self._bar.bar_format = "{desc}: done in {elapsed}"
            self._bar.refresh()
            self._bar.close()
            self._bar = None
        else:
            self._plain_line(finished=True)
        self._stage = None

    def _plain_line(self, finished: bool = False) -> None:
        """One line: '[k/N] stage: 12/48 frames 25% 3.8 frames/s, ETA 0:09' (tqdm's own formatting)."""
        elapsed = time.perf_counter() - self._t0
        unit = STAGE_UNITS.get(self._stage, "it")
        if self._total:
            text = tqdm.format_meter(self._done, self._total, elapsed, unit=unit,
                                     bar_format="{n_fmt}/{total_fmt} {unit}s {percentage:3.0f}% {rate_fmt}, "
                                                "elapsed {elapsed}, ETA {remaining}")
        elif self._stage in STAGE_UNITS:
            text = tqdm.format_meter(self._done, None, elapsed, unit=unit, bar_format="{n_fmt} {unit}s, elapsed {elapsed}")
        else:
            text = f"elapsed {tqdm.format_interval(elapsed)}"
        if finished:
            text = f"done in {tqdm.format_interval(elapsed)}" + (f" ({self._done}/{self._total} {unit}s)" if self._total else "")
        self.stream.write(f"{self._desc(self._stage)}: {text}\n")
        self.stream.flush()
        self._last_line = time.perf_counter()

    def _tick(self) -> None:
        """Keep an open stage's elapsed time (and ETA) moving while the work between updates is silent."""
        while not self._stop.wait(self.config.tick_s):
            with self._lock:
                if self._stage is None:
                    continue
                if self._bar is not None:
                    self._bar.refresh()
                elif time.perf_counter() - self._last_line >= self.config.plain_interval_s:
                    self._plain_line()


# Progress displays with an open stage: the CLI abandons them when a command fails.
_OPEN: "weakref.WeakSet[StageProgress]" = weakref.WeakSet()


def abandon_open() -> None:
    """Close every open progress display as failed (no 'done' line), before the CLI prints an error."""
    for p in list(_OPEN):
        p.close(failed=True)


class TqdmLogHandler(logging.StreamHandler):
    """A log handler that writes through ``tqdm.write``: lines appear above an open bar, never glued to it."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            tqdm.write(self.format(record), file=self.stream)
        except Exception:  # logging must never raise into the pipeline
            self.handleError(record)


def quiet_native_libraries() -> None:
    """Keep FFmpeg's (via OpenCV) and Open3D's own messages off the terminal.

    OpenCV reads its log levels from the environment when it is first imported, so this runs
    before any ``import cv2``; for a cv2 already imported the runtime setter is used as well.
    Undecodable frames are still counted and logged by ``stereo_recon.video``.
    """
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    if "cv2" in sys.modules:
        try:
            import cv2

            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        except Exception:  # an OpenCV build without the logging module
            pass
    if "open3d" in sys.modules:
        quiet_open3d()


def quiet_open3d() -> None:
    """Open3D prints warnings/info to stdout itself; keep only its errors."""
    try:
        import open3d as o3d

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    except Exception:  # open3d missing or without the utility module
        pass


class NativeOutputToLog:
    """While a command runs on a terminal, what C/C++ libraries write straight to file descriptors 1 and 2
    (FFmpeg through OpenCV, Open3D) goes to the log at debug level (so into log.txt), not onto the screen.

    Python's own ``sys.stdout``/``sys.stderr`` are re-opened on copies of the terminal's descriptors, so
    results, progress bars and one-line errors still reach it; enter this before logging and progress
    are configured (their streams are taken from ``sys.stderr`` then). Off when stderr is not a terminal
    (pipes, CI, tests): nothing is redirected there.
    """

    def __init__(self, enabled: bool | None = None, logger: str = "stereo_recon.native"):
        self.enabled = enabled
        self.log = logging.getLogger(logger)
        self._saved: dict[int, int] = {}
        self._streams = None
        self._reader: threading.Thread | None = None

    def __enter__(self) -> "NativeOutputToLog":
        on = self.enabled if self.enabled is not None else stream_is_tty(sys.stderr)
        if not on:
            return self
        try:
            sys.stdout.flush()
            sys.stderr.flush()
            self._saved = {fd: os.dup(fd) for fd in (1, 2)}
            r, w = os.pipe()
            self._streams = (sys.stdout, sys.stderr)
            sys.stdout = os.fdopen(os.dup(self._saved[1]), "w", buffering=1, encoding="utf-8", errors="replace")
            sys.stderr = os.fdopen(os.dup(self._saved[2]), "w", buffering=1, encoding="utf-8", errors="replace")
            os.dup2(w, 1)
            os.dup2(w, 2)
            os.close(w)
        except (OSError, ValueError):  # no usable descriptors: leave everything as it was
            self._restore()
            return self
        self._reader = threading.Thread(target=self._pump, args=(r,), name="native-output", daemon=True)
        self._reader.start()
        return self

    def _pump(self, fd: int) -> None:
        with os.fdopen(fd, "rb") as pipe:
            for raw in pipe:
                line = raw.decode("utf-8", "replace").rstrip()
                if line:
                    self.log.debug("%s", line)

    def _restore(self) -> None:
        if not self._saved:
            return
        for fd, saved in self._saved.items():
            os.dup2(saved, fd)   # also closes the pipe's write ends held on 1 and 2: the reader sees EOF
            os.close(saved)
        self._saved = {}
        if self._streams is not None:
            for s in (sys.stdout, sys.stderr):
                try:
                    s.close()
                except OSError:
                    pass
            sys.stdout, sys.stderr = self._streams
            self._streams = None

    def __exit__(self, *exc) -> None:
        self._restore()
        if self._reader is not None:
            self._reader.join(timeout=2.0)
            self._reader = None


def stream_is_tty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False
