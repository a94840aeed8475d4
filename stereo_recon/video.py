"""Stereo input: side-by-side videos (ZED SVO exports, UVC captures) or folders of left/right images.

A source streams ``StereoFrame`` objects one at a time (memory does not grow with the video's
length), honours a frame range and a step, skips isolated undecodable frames (counted in
``bad_frames``), and checks its eye size against a calibration (``validate_against_rig``).
Keyframe selection (by pose or by image motion) is in ``views``.

Side-by-side frames hold the left eye in the left half (:mod:`stereo_recon.core.conventions`).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from stereo_recon.core.frames import EYE_ASPECT_RANGE, split_side_by_side  # noqa: F401 (public here)
from stereo_recon.core.errors import ConfigError, InputError

log = logging.getLogger(__name__)

# Side-by-side frame sizes the ZED cameras write, and the resolution names of the factory .conf.
ZED_FRAME_SIZES: dict[tuple[int, int], str] = {
    (4416, 1242): "2K",
    (3840, 1080): "FHD",
    (2560, 720): "HD",
    (1344, 376): "VGA",
}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


@dataclass(frozen=True)
class StereoFrame:
    """One stereo frame: index in the source, timestamp (index / fps, s), BGR uint8 eye images (H, W, 3)."""

    index: int
    timestamp_s: float
    left: np.ndarray
    right: np.ndarray


def parse_frame_range(text: str | None) -> tuple[int, int | None] | None:
    """Parse ``"A:B"`` (half-open, either side optional) into ``(A, B)``; None/"" -> None."""
    if text is None or text == "":
        return None
    m = re.fullmatch(r"\s*(\d*)\s*:\s*(\d*)\s*", text)
    if not m:
        raise ConfigError(f"--frames {text!r}: expected START:STOP (e.g. 100:400, :300, 50:)")
    a = int(m.group(1)) if m.group(1) else 0
    b = int(m.group(2)) if m.group(2) else None
    if b is not None and b <= a:
        raise ConfigError(f"--frames {text!r}: STOP must be greater than START")
    return a, b


def _to_bgr(img: np.ndarray) -> np.ndarray:
    import cv2

    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


class StereoSource:
    """Base class: an iterable of ``StereoFrame`` with the source's properties.

    path: the video file or image folder. fps: frames per second (timestamps = index / fps).
    eye_size: (width, height) of one eye, px. frame_count: frames in the source (before range/step;
    may be approximate for some video containers). bad_frames: indices that could not be decoded
    in the last iteration. frames_read: frames yielded in the last iteration.
    """

    def __init__(self, path: Path, fps: float, eye_size: tuple[int, int], frame_count: int,
                 frame_range: tuple[int, int | None] | None, step: int):
        if step < 1:
            raise ConfigError(f"step={step}: must be >= 1")
        self.path = Path(path)
        self.fps = float(fps)
        self.eye_size = (int(eye_size[0]), int(eye_size[1]))
        self.frame_count = int(frame_count)
        self.start = frame_range[0] if frame_range else 0
        self.stop = frame_range[1] if frame_range and frame_range[1] is not None else None
        self.step = int(step)
        self.bad_frames: list[int] = []
        self.frames_read = 0
        if self.frame_count > 0 and self.start >= self.frame_count:
            raise InputError(f"{self.path}: frame range starts at {self.start} but the source has "
                             f"{self.frame_count} frames")

    def select(self, frame_range: tuple[int, int | None] | None = None, step: int = 1, fps: float | None = None,
               max_consecutive_bad: int | None = None) -> "StereoSource":
        """This source with another frame range, step, frame rate or bad-frame limit, without opening it again.

        The arguments mean what they mean for ``open_stereo_source``; the container is not read again.
        """
        import copy

        out = copy.copy(self)
        StereoSource.__init__(out, self.path, fps or self.fps, self.eye_size, self.frame_count, frame_range, step)
        if max_consecutive_bad is not None and hasattr(out, "max_consecutive_bad"):
            out.max_consecutive_bad = int(max_consecutive_bad)
        return out

    def selected_indices(self) -> range:
        """The frame indices this source will try to yield (range and step applied)."""
        stop = self.frame_count if self.stop is None else min(self.stop, self.frame_count or self.stop)
        return range(self.start, stop, self.step)

    def __len__(self) -> int:
        return len(self.selected_indices())

    def __iter__(self) -> Iterator[StereoFrame]:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> dict:
        """Properties for run manifests."""
        return {"path": str(self.path), "kind": type(self).__name__, "fps": self.fps, "eye_size": list(self.eye_size),
                "frame_count": self.frame_count, "start": self.start, "stop": self.stop, "step": self.step,
                "frames_read": self.frames_read, "bad_frames": list(self.bad_frames)}


class SideBySideVideo(StereoSource):
    """A side-by-side stereo video read with ``cv2.VideoCapture`` (FFmpeg: MJPG/MPEG-4 AVI, H.264 MP4 ...)."""

    def __init__(self, path: Path, frame_range=None, step: int = 1, fps: float | None = None,
                 max_consecutive_bad: int = 10):
        import cv2

        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: video file not found")
        cap = cv2.VideoCapture(str(path))
        try:
            if not cap.isOpened():
                raise InputError(f"{path}: cannot open as a video (unknown format or corrupt file)")
            w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
            h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            vfps = float(cap.get(cv2.CAP_PROP_FPS))
            ok, first = cap.read()
        finally:
            cap.release()
        if not ok or first is None:
            raise InputError(f"{path}: no decodable frame (corrupt or empty video)")
        h, w = first.shape[:2]
        split_side_by_side(first, str(path))  # raises for odd widths / non side-by-side aspect
        if (w, h) not in ZED_FRAME_SIZES:
            log.info("%s: %dx%d is not a ZED frame size; treating it as side-by-side", path, w, h)
        self.max_consecutive_bad = int(max_consecutive_bad)
        super().__init__(path, fps or (vfps if vfps > 0 else 30.0), (w // 2, h), max(n, 0), frame_range, step)

    def __iter__(self) -> Iterator[StereoFrame]:
        import cv2

        self.bad_frames = []
        self.frames_read = 0
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            raise InputError(f"{self.path}: cannot open as a video")
        try:
            index = -1
            bad_run = 0
            pending_bad: list[int] = []
            stop = self.stop if self.stop is not None else None
            while True:
                index += 1
                if stop is not None and index >= stop:
                    break
                wanted = index >= self.start and (index - self.start) % self.step == 0
                # grab() decodes without the colour conversion; frames we skip cost less.
                ok = cap.grab()
                frame = None
                if ok and wanted:
                    ok, frame = cap.retrieve()
                    ok = ok and frame is not None and frame.shape[:2] == (self.eye_size[1], 2 * self.eye_size[0])
                if not ok:
                    # Past the container's frame count, or many failures in a row = end of video;
                    # otherwise an isolated undecodable frame: count it (once decoding resumes) and carry on.
                    bad_run += 1
                    if (self.frame_count > 1 and index >= self.frame_count - 1) or bad_run > self.max_consecutive_bad:
                        if self.frame_count > 1 and index < self.frame_count - 1:
                            log.warning("%s: decoding stopped at frame %d of %d (%d frames decoded)", self.path,
                                        index - bad_run + 1, self.frame_count, self.frames_read)
                        break
                    if wanted:
                        pending_bad.append(index)
                    continue
                if pending_bad:
                    log.warning("%s: frame(s) %s could not be decoded; skipped", self.path, pending_bad)
                    self.bad_frames.extend(pending_bad)
                    pending_bad = []
                bad_run = 0
                if not wanted:
                    continue
                left, right = split_side_by_side(frame, f"{self.path} frame {index}")
                self.frames_read += 1
                yield StereoFrame(index, index / self.fps, np.ascontiguousarray(left), np.ascontiguousarray(right))
        finally:
            cap.release()


def _find_pairs(folder: Path) -> tuple[list[Path], list[Path]] | list[Path]:
    """Left/right image lists of a folder (subfolders left/right, or *left*/*right* names), or side-by-side images."""
    def images(d: Path) -> list[Path]:
        return sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())

    for ln, rn in (("left", "right"), ("image_0", "image_1"), ("image_02", "image_03"), ("L", "R"), ("cam0", "cam1")):
        if (folder / ln).is_dir() and (folder / rn).is_dir():
            lefts, rights = images(folder / ln), images(folder / rn)
            if len(lefts) != len(rights):
                raise InputError(f"{folder}: {len(lefts)} images in {ln}/ but {len(rights)} in {rn}/")
            return lefts, rights
    files = images(folder)
    lefts = [p for p in files if "left" in p.name.lower()]
    if lefts:
        rights = []
        for p in lefts:
            i = p.name.lower().rfind("left")
            cand = [p.with_name(p.name[:i] + r + p.name[i + 4:]) for r in ("right", "Right", "RIGHT")]
            match = next((c for c in cand if c.is_file()), None)
            if match is None:
                raise InputError(f"{p}: no matching right image ({cand[0].name})")
            rights.append(match)
        return lefts, rights
    return files


class ImageFolderSource(StereoSource):
    """Stereo pairs from a folder: ``left/`` + ``right/`` subfolders (same sorted order), files named
    ``*left*``/``*right*``, or side-by-side images."""

    def __init__(self, path: Path, frame_range=None, step: int = 1, fps: float | None = None):
        import cv2

        path = Path(path)
        found = _find_pairs(path)
        if isinstance(found, tuple):
            self.lefts, self.rights = found
            self.side_by_side = False
        else:
            self.lefts, self.rights = found, None
            self.side_by_side = True
        if not self.lefts:
            raise InputError(f"{path}: no images found (expected left/ and right/ subfolders, *left*/*right* files, "
                             "or side-by-side images)")
        first = cv2.imread(str(self.lefts[0]), cv2.IMREAD_COLOR)
        if first is None:
            raise InputError(f"{self.lefts[0]}: unreadable image")
        if self.side_by_side:
            left, _ = split_side_by_side(first, str(self.lefts[0]))
            h, w = left.shape[:2]
        else:
            h, w = first.shape[:2]
        super().__init__(path, fps or 30.0, (w, h), len(self.lefts), frame_range, step)

    def __iter__(self) -> Iterator[StereoFrame]:
        import cv2

        self.bad_frames = []
        self.frames_read = 0
        for index in self.selected_indices():
            lp = self.lefts[index]
            left = cv2.imread(str(lp), cv2.IMREAD_UNCHANGED)
            right = None
            if left is not None and self.side_by_side:
                try:
                    left, right = split_side_by_side(left, str(lp))
                except InputError:
                    left = None
            elif left is not None:
                right = cv2.imread(str(self.rights[index]), cv2.IMREAD_UNCHANGED)
            if left is None or right is None:
                self.bad_frames.append(index)
                log.warning("%s: frame %d unreadable; skipped", self.path, index)
                continue
            left, right = _to_bgr(left), _to_bgr(right)
            if (left.shape[1], left.shape[0]) != self.eye_size or left.shape != right.shape:
                raise InputError(f"{lp}: image size {left.shape[1]}x{left.shape[0]} (right {right.shape[1]}x"
                                 f"{right.shape[0]}) differs from the first frame's {self.eye_size[0]}x{self.eye_size[1]}")
            self.frames_read += 1
            yield StereoFrame(index, index / self.fps, np.ascontiguousarray(left), np.ascontiguousarray(right))


def open_stereo_source(path, frame_range: tuple[int, int | None] | str | None = None, step: int = 1,
                       fps: float | None = None, max_consecutive_bad: int = 10) -> StereoSource:
    """Open a side-by-side video file or a folder of stereo images as a streaming ``StereoSource``.

    path: video file (any size whose halves are the eyes: ZED 2560x720, 3840x1080, 4416x1242,
        1344x376 ...) or folder (see ``ImageFolderSource``).
    frame_range: (start, stop) half-open frame indices, or "A:B"; None = all.
    step: take every step-th frame of the range. fps: override the video's frame rate (folders: 30).
    max_consecutive_bad: this many undecodable frames in a row end the video.
    Raises InputError for missing/unreadable input or frames that are not side-by-side.
    """
    if isinstance(frame_range, str):
        frame_range = parse_frame_range(frame_range)
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if p.is_dir():
        return ImageFolderSource(p, frame_range, step, fps)
    return SideBySideVideo(p, frame_range, step, fps, max_consecutive_bad)


def validate_against_rig(source: StereoSource, rig):
    """The rig for the source's eye size: unchanged if equal, scaled if the aspect matches, else InputError.

    source: an opened ``StereoSource``. rig: ``calib.rig.StereoRig`` (image_size = one eye).
    """
    if tuple(rig.image_size) == tuple(source.eye_size):
        return rig
    try:
        scaled = rig.scaled(source.eye_size)
    except InputError as err:
        raise InputError(f"{source.path}: eyes are {source.eye_size[0]}x{source.eye_size[1]} but the calibration is "
                         f"for {rig.image_size[0]}x{rig.image_size[1]} ({err})") from err
    log.info("calibration scaled from %dx%d to %dx%d", *rig.image_size, *source.eye_size)
    return scaled


# Keyframe selection lives in ``views`` (one selector by pose or by image motion); these names stay importable here.
from stereo_recon.views import KeyframeConfig, KeyframeSelector  # noqa: E402,F401
