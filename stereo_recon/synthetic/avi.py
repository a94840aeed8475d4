"""A minimal Motion-JPEG AVI (RIFF, AVI 1.0) writer with libjpeg frames from ``cv2.imencode``.

OpenCV's built-in MJPEG writer ignores chroma subsampling and compresses about 2.5x worse than
libjpeg at the same visual quality; its FFmpeg writer does not take a quality setting. This
writer stores standard baseline JPEG frames (4:2:0, chosen quality) in a plain AVI that
``cv2.VideoCapture``/FFmpeg read; the bytes depend only on the frames (deterministic).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import cv2
import numpy as np

from stereo_recon.core.errors import ConfigError

_AVIF_HASINDEX = 0x10
_AVIIF_KEYFRAME = 0x10
_MAX_BYTES = 1 << 30  # AVI 1.0 (no OpenDML index) stays well below 2 GB


class MjpegAviWriter:
    """Write BGR uint8 frames of ``size`` (width, height) as an MJPG AVI at ``fps`` with JPEG ``quality`` (1..100)."""

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int], quality: int = 90):
        self.path = Path(path)
        self.size = (int(size[0]), int(size[1]))
        self.quality = int(quality)
        if not 1 <= self.quality <= 100:
            raise ConfigError(f"{self.path}: JPEG quality must be 1..100, got {quality}")
        if fps <= 0:
            raise ConfigError(f"{self.path}: fps must be > 0, got {fps}")
        # Rate/scale: exact for integer frame rates, millihertz otherwise.
        if abs(fps - round(fps)) < 1e-9:
            self._rate, self._scale = int(round(fps)), 1
        else:
            self._rate, self._scale = int(round(fps * 1000)), 1000
        self._f = open(self.path, "wb")
        self._index: list[tuple[int, int]] = []  # (offset from 'movi', size)
        self._max_frame = 0
        self._write_headers()

    # Layout: RIFF('AVI ' LIST('hdrl' avih LIST('strl' strh strf)) LIST('movi' 00dc...) idx1)
    def _write_headers(self) -> None:
        w, h = self.size
        f = self._f
        f.write(b"RIFF\0\0\0\0AVI ")
        hdrl = bytearray()
        avih = struct.pack("<14I", int(round(1e6 * self._scale / self._rate)), 0, 0, _AVIF_HASINDEX, 0, 0, 1, 0, w, h, 0, 0, 0, 0)
        hdrl += b"avih" + struct.pack("<I", len(avih)) + avih
        strh = b"vidsMJPG" + struct.pack("<IHHIIIIIIII4h", 0, 0, 0, 0, self._scale, self._rate, 0, 0, 0, 0xFFFFFFFF, 0, 0, 0, w, h)
        strf = struct.pack("<IiiHH4sIiiII", 40, w, h, 1, 24, b"MJPG", w * h * 3, 0, 0, 0, 0)
        strl = b"strl" + b"strh" + struct.pack("<I", len(strh)) + strh + b"strf" + struct.pack("<I", len(strf)) + strf
        hdrl += b"LIST" + struct.pack("<I", len(strl)) + strl
        f.write(b"LIST" + struct.pack("<I", len(hdrl) + 4) + b"hdrl" + bytes(hdrl))
        self._avih_frames_pos = 12 + 8 + 4 + 8 + 16  # RIFF hdr, LIST hdr, 'hdrl', avih hdr, 4 dwords -> dwTotalFrames
        self._avih_bufsize_pos = self._avih_frames_pos + 12
        # strh dwLength / dwSuggestedBufferSize: after avih (8 + 56), 'LIST' size 'strl', 'strh' size.
        strh_data = 12 + 8 + 4 + 8 + 56 + 12 + 8
        self._strh_length_pos = strh_data + 32
        self._strh_bufsize_pos = strh_data + 36
        self._movi_pos = f.tell()
        f.write(b"LIST\0\0\0\0movi")

    def write(self, frame: np.ndarray) -> None:
        """Append one BGR uint8 frame (H, W, 3) of the writer's size."""
        if frame.shape[:2] != (self.size[1], self.size[0]):
            raise ConfigError(f"{self.path}: frame is {frame.shape[1]}x{frame.shape[0]}, the video is {self.size[0]}x{self.size[1]}")
        ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            raise ConfigError(f"{self.path}: JPEG encoding failed")
        data = buf.tobytes()
        off = self._f.tell() - (self._movi_pos + 8)
        self._f.write(b"00dc" + struct.pack("<I", len(data)) + data + (b"\0" if len(data) % 2 else b""))
        self._index.append((off, len(data)))
        self._max_frame = max(self._max_frame, len(data))
        if self._f.tell() > _MAX_BYTES:
            raise ConfigError(f"{self.path}: video over 1 GB; use --format mp4 or fewer frames")

    def release(self) -> None:
        """Write the index and patch the header sizes; the file is complete after this."""
        if self._f.closed:
            return
        f = self._f
        end_movi = f.tell()
        idx = b"".join(b"00dc" + struct.pack("<III", _AVIIF_KEYFRAME, off, size) for off, size in self._index)
        f.write(b"idx1" + struct.pack("<I", len(idx)) + idx)
        end = f.tell()
        n = len(self._index)
        for pos, val in ((4, end - 8), (self._movi_pos + 4, end_movi - self._movi_pos - 8), (self._avih_frames_pos, n),
                         (self._avih_bufsize_pos, self._max_frame + 8), (self._strh_length_pos, n), (self._strh_bufsize_pos, self._max_frame + 8)):
            f.seek(pos)
            f.write(struct.pack("<I", val))
        f.close()

    def __enter__(self) -> "MjpegAviWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.release()
