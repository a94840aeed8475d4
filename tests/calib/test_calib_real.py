"""OpenCV's 13 real chessboard pairs (9x6 inner corners, square 1.0) through the commands."""

from __future__ import annotations

import json

import cv2
import pytest

from calib.io import load_rig
from calib.rig import rectify_pair
from stereo_recon.app.cli import main

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


def _calibrate(shared_data, out_dir):
    folder = shared_data / "opencv_stereo_calib"
    out = out_dir / "rig.yaml"
    rc = main(["calibrate", str(folder), "--board", "chessboard:9x6:1.0", "--out", str(out)])
    assert rc == 0
    return folder, out, json.loads((out_dir / "rig.report.json").read_text())


def test_real_pairs_calibrate_and_check(shared_data, tmp_path, capsys):
    folder, out, rep = _calibrate(shared_data, tmp_path)
    # all 13 pairs used (a rejected one would be listed with its reason)
    assert rep["looked_at"] == 13 and rep["found_in_both_eyes"] == 13
    assert rep["views_used"] == 13, [v for v in rep["per_view"] if not v.get("used")]
    # measured: 0.271 px (OpenCV reference: classic corners 0.447 px on 13 pairs, SB 0.276 px on 10 pairs)
    assert rep["rms_px"]["pair"] <= 0.35
    assert rep["epipolar_error_px"]["median"] < 0.3
    rig = load_rig(out)
    assert rig.image_size == (640, 480)
    # the pair's baseline, in squares: about 3.3 (OpenCV's own stereo_calib finds |T| = 3.34)
    assert 3.2 < rig.baseline_m < 3.45 and rig.T[0] < 0
    assert (tmp_path / "rig.coverage.png").stat().st_size > 1000
    capsys.readouterr()

    # calib-check: the raw frames fit this calibration
    assert main(["calib-check", "--calib", str(out), str(folder), "--board", "chessboard:9x6:1.0",
                 "--out", str(tmp_path / "check_raw.json")]) == 0
    raw = json.loads((tmp_path / "check_raw.json").read_text())
    assert raw["verdict"] == "ok" and raw["rectified"]["median_dy_px"] < 0.5 < raw["raw"]["median_dy_px"]
    assert raw["board_epipolar_error_px"]["views"] == 8 and raw["board_epipolar_error_px"]["median"] < 0.3

    # frames rectified already (as the ZED SDK exports them), checked with the raw calibration again
    rect = rig.rectification()
    rdir = tmp_path / "rectified"
    small = tmp_path / "small"
    rdir.mkdir()
    small.mkdir()
    for p in sorted(folder.glob("left*.jpg"))[:6]:
        q = folder / p.name.replace("left", "right")
        left, right = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), cv2.imread(str(q), cv2.IMREAD_GRAYSCALE)
        lr, rr = rectify_pair(left, right, rect)
        cv2.imwrite(str(rdir / p.name.replace(".jpg", ".png")), lr)
        cv2.imwrite(str(rdir / q.name.replace(".jpg", ".png")), rr)
        cv2.imwrite(str(small / p.name.replace(".jpg", ".png")), cv2.resize(left, (320, 240), interpolation=cv2.INTER_AREA))
        cv2.imwrite(str(small / q.name.replace(".jpg", ".png")), cv2.resize(right, (320, 240), interpolation=cv2.INTER_AREA))
    capsys.readouterr()
    assert main(["calib-check", "--calib", str(out), str(rdir)]) == 1
    said = capsys.readouterr().out
    assert "already_rectified" in said
    inline = f"{rect.focal_px},{rect.P1[1, 1]},{rect.cx_px},{rect.cy_px},{rect.baseline_m},640,480"
    assert main(["calib-check", "--calib", inline, str(rdir)]) == 0
    # half-size frames: the 640x480 calibration is scaled to them
    assert main(["calib-check", "--calib", str(out), str(small), "--out", str(tmp_path / "check_small.json")]) == 0
    chk = json.loads((tmp_path / "check_small.json").read_text())
    assert chk["image_size"] == [320, 240]
