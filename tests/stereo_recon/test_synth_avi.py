"""The MJPG AVI writer: OpenCV reads back every frame, the frame rate, and the bytes are deterministic."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereo_recon.core.errors import ConfigError
from stereo_recon.synthetic.avi import MjpegAviWriter


def _frames(n=4, size=(320, 120)):
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8), (0, 0), 2.0)
    return [np.roll(base, 7 * i, axis=1) for i in range(n)]


@pytest.mark.parametrize("fps", [15.0, 29.97])
def test_avi_reads_back_with_opencv(tmp_path, fps):
    frames = _frames()
    path = tmp_path / "v.avi"
    with MjpegAviWriter(path, fps, (320, 120), quality=95) as w:
        for f in frames:
            w.write(f)
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened()
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) == len(frames)
    assert abs(cap.get(cv2.CAP_PROP_FPS) - fps) < 1e-3
    for f in frames:
        ok, g = cap.read()
        assert ok and g.shape == f.shape
        assert np.abs(g.astype(int) - f).mean() < 3.0  # JPEG at quality 95
    assert not cap.read()[0]


def test_avi_bytes_are_deterministic_and_quality_matters(tmp_path):
    sizes = {}
    for name, q in (("a", 90), ("b", 90), ("c", 40)):
        with MjpegAviWriter(tmp_path / f"{name}.avi", 15, (320, 120), quality=q) as w:
            for f in _frames():
                w.write(f)
        sizes[name] = (tmp_path / f"{name}.avi").read_bytes()
    assert sizes["a"] == sizes["b"]
    assert len(sizes["c"]) < 0.8 * len(sizes["a"])


def test_avi_rejects_bad_frames_and_settings(tmp_path):
    with pytest.raises(ConfigError):
        MjpegAviWriter(tmp_path / "q.avi", 15, (320, 120), quality=0)
    w = MjpegAviWriter(tmp_path / "s.avi", 15, (320, 120))
    with pytest.raises(ConfigError):
        w.write(np.zeros((100, 320, 3), np.uint8))
    w.release()
