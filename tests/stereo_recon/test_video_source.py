"""Stereo input: side-by-side videos and image folders, ranges, corrupt frames, rig validation, keyframes."""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from stereo_recon.core.errors import ConfigError, InputError  # noqa: E402
from stereo_recon.video import (  # noqa: E402
    KeyframeConfig,
    KeyframeSelector,
    open_stereo_source,
    parse_frame_range,
    validate_against_rig,
)

EYE = (336, 188)  # a quarter of ZED VGA per eye keeps the files tiny


def _frame(i, eye=EYE):
    w, h = eye
    f = np.zeros((h, 2 * w, 3), np.uint8)
    f[:, :w] = (40 + 5 * i) % 256          # left half
    f[:, w:] = (200 - 5 * i) % 256         # right half
    return f


def _write_video(path, n=12, eye=EYE, fourcc="MJPG"):
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10.0, (2 * eye[0], eye[1]))
    assert vw.isOpened()
    for i in range(n):
        vw.write(_frame(i, eye))
    vw.release()
    return path


def test_video_stream_range_step_and_halves(tmp_path):
    src = open_stereo_source(_write_video(tmp_path / "v.avi"), frame_range="2:10", step=3)
    assert src.eye_size == EYE and src.fps == pytest.approx(10.0) and src.frame_count == 12
    frames = list(src)
    assert [f.index for f in frames] == [2, 5, 8]
    for f in frames:
        assert f.timestamp_s == pytest.approx(f.index / 10.0)
        assert f.left.shape == (EYE[1], EYE[0], 3) and f.right.shape == f.left.shape
        # MJPG is lossy: compare the mean grey level of each half with what was written.
        assert abs(float(f.left.mean()) - (40 + 5 * f.index)) < 3
        assert abs(float(f.right.mean()) - (200 - 5 * f.index)) < 3
    assert src.bad_frames == [] and src.frames_read == 3


def test_corrupt_frame_is_skipped_and_counted(tmp_path):
    p = _write_video(tmp_path / "v.avi", n=10)
    data = bytearray(p.read_bytes())
    soi = [i for i in range(len(data) - 1) if data[i] == 0xFF and data[i + 1] == 0xD8]
    assert len(soi) == 10
    data[soi[4]:soi[5] - 16] = bytes(soi[5] - 16 - soi[4])  # wipe frame 4's JPEG data (AVI chunks intact)
    bad = tmp_path / "bad.avi"
    bad.write_bytes(bytes(data))
    src = open_stereo_source(bad)
    idx = [f.index for f in src]
    assert idx == [0, 1, 2, 3, 5, 6, 7, 8, 9]
    assert src.bad_frames == [4]


def test_not_side_by_side_and_unreadable(tmp_path):
    # A mono 16:9 video split in two would give 0.89-aspect "eyes": refused with a clear message.
    vw = cv2.VideoWriter(str(tmp_path / "mono.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (320, 180))
    for _ in range(3):
        vw.write(np.zeros((180, 320, 3), np.uint8))
    vw.release()
    with pytest.raises(InputError, match="not side-by-side"):
        open_stereo_source(tmp_path / "mono.avi")
    (tmp_path / "junk.avi").write_bytes(b"not a video at all" * 100)
    with pytest.raises(InputError, match="junk.avi"):
        open_stereo_source(tmp_path / "junk.avi")
    with pytest.raises(InputError, match="no such file"):
        open_stereo_source(tmp_path / "missing.avi")
    odd = tmp_path / "odd"
    odd.mkdir()
    cv2.imwrite(str(odd / "000.png"), np.zeros((100, 401, 3), np.uint8))
    with pytest.raises(InputError, match="odd"):
        open_stereo_source(odd)


def test_image_folders(tmp_path):
    for sub in ("left", "right"):
        (tmp_path / "a" / sub).mkdir(parents=True)
    for i in range(4):
        f = _frame(i)
        cv2.imwrite(str(tmp_path / "a" / "left" / f"{i:04d}.png"), f[:, :EYE[0]])
        cv2.imwrite(str(tmp_path / "a" / "right" / f"{i:04d}.png"), f[:, EYE[0]:])
        cv2.imwrite(str(tmp_path / "a" / f"sbs_{i}.png"), f)  # ignored: subfolders win
    src = open_stereo_source(tmp_path / "a", step=2, fps=5.0)
    frames = list(src)
    assert [f.index for f in frames] == [0, 2]
    assert np.array_equal(frames[1].left, _frame(2)[:, :EYE[0]])
    assert np.array_equal(frames[1].right, _frame(2)[:, EYE[0]:])
    assert frames[1].timestamp_s == pytest.approx(0.4)
    # Named pairs in one folder.
    (tmp_path / "b").mkdir()
    for i in range(3):
        cv2.imwrite(str(tmp_path / "b" / f"img{i}_left.png"), _frame(i)[:, :EYE[0]])
        cv2.imwrite(str(tmp_path / "b" / f"img{i}_right.png"), _frame(i)[:, EYE[0]:])
    assert len(list(open_stereo_source(tmp_path / "b"))) == 3
    # Side-by-side images.
    (tmp_path / "c").mkdir()
    for i in range(2):
        cv2.imwrite(str(tmp_path / "c" / f"{i}.png"), _frame(i))
    c = list(open_stereo_source(tmp_path / "c"))
    assert len(c) == 2 and np.array_equal(c[1].right, _frame(1)[:, EYE[0]:])


def test_frame_range_parsing():
    assert parse_frame_range("10:20") == (10, 20)
    assert parse_frame_range(":5") == (0, 5)
    assert parse_frame_range("7:") == (7, None)
    for bad in ("5", "a:b", "9:3"):
        with pytest.raises(ConfigError):
            parse_frame_range(bad)


def test_validate_against_rig_scales_or_refuses(tmp_path):
    rig_mod = pytest.importorskip("calib.rig")
    src = open_stereo_source(_write_video(tmp_path / "v.avi", n=2))
    rig = rig_mod.StereoRig.from_rectified(700.0, 700.0, 672.0, 376.0, 0.12, (1344, 752))
    scaled = validate_against_rig(src, rig)
    assert scaled.image_size == EYE
    assert scaled.K1[0, 0] == pytest.approx(700.0 * EYE[0] / 1344)
    other = rig_mod.StereoRig.from_rectified(700.0, 700.0, 320.0, 240.0, 0.12, (640, 480))
    with pytest.raises(InputError, match="calibration"):
        validate_against_rig(src, other)


def test_keyframes_follow_motion(rng):
    big = cv2.resize(rng.integers(0, 256, (120, 200), dtype=np.uint8), (800, 480), interpolation=cv2.INTER_CUBIC)
    sel = KeyframeSelector(KeyframeConfig(min_flow_frac=0.02, max_gap_frames=None, work_width_px=400))
    keys = []
    for i in range(12):
        shift = 3 * i  # px per frame at 400 px wide crop -> 0.75 % per frame; 2 % every ~3 frames
        img = np.ascontiguousarray(big[40:400, 100 + shift:500 + shift])
        if sel.is_keyframe(i, img):
            keys.append(i)
    assert keys[0] == 0
    gaps = np.diff(keys)
    assert len(keys) >= 3 and np.all((gaps >= 2) & (gaps <= 4))
    # A static camera gives no new keyframe; a forced gap does.
    sel2 = KeyframeSelector(KeyframeConfig(max_gap_frames=5))
    img = np.ascontiguousarray(big[:360, :400])
    assert [i for i in range(11) if sel2.is_keyframe(i, img)] == [0, 5, 10]


def test_streaming_memory_is_flat(tmp_path):
    # Peak traced memory while iterating must not grow with the number of frames (numpy reports to tracemalloc).
    import tracemalloc

    peaks = []
    for n in (10, 80):
        src = open_stereo_source(_write_video(tmp_path / f"v{n}.avi", n=n))
        tracemalloc.start()
        count = sum(1 for _ in src)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert count == n
    frame_bytes = 2 * EYE[0] * EYE[1] * 3
    assert peaks[1] < peaks[0] + 2 * frame_bytes
