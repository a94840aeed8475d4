"""Pin the ZED .conf convention with rendered images, and the raw / already-rectified detection.

A textured fronto-parallel plane is rendered exactly (ray-plane intersection per pixel) through a
ZED-like distorted, slightly misaligned rig; the rig goes through a .conf file and back; the pair
rectified with what was read must have aligned rows and depth f*B/d equal to the plane's.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib.check import detect_rectification_mismatch, epipolar_error, match_features
from calib.io import load_rig, write_zed_conf
from calib.rig import StereoRig, rectify_pair
from calib.synthetic_board import pixel_rays, render_plane

SIZE = (672, 376)          # ZED VGA eye
PLANE_Z_M = 1.5            # plane distance in the left camera frame


def zed_like_rig() -> StereoRig:
    K1 = np.array([[349.2, 0, 338.1], [0, 349.6, 190.3], [0, 0, 1]])
    K2 = np.array([[350.4, 0, 331.7], [0, 350.1, 185.9], [0, 0, 1]])
    # rotation vector in ZED's order [RX, CV, RZ]; RX tilts rows, so a wrong convention shows in dy
    R = cv2.Rodrigues(np.array([0.0075, 0.011, -0.0035]))[0]
    return StereoRig(K1=K1, D1=np.array([-0.172, 0.0268, 0.0004, -0.0003, 0.0]), K2=K2,
                     D2=np.array([-0.168, 0.0251, -0.0002, 0.0005, 0.0]), R=R,
                     T=np.array([-0.11993, 0.00031, -0.00052]), image_size=SIZE)


def plane_texture(rng: np.random.Generator, px_per_m: float = 500.0, size_m=(5.0, 3.5)) -> tuple[np.ndarray, np.ndarray]:
    w, h = int(size_m[0] * px_per_m), int(size_m[1] * px_per_m)
    noise = rng.random((h // 4, w // 4)).astype(np.float32)
    tex = cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC)
    tex = cv2.GaussianBlur(tex, (0, 0), 1.5)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    # plane coordinates (metres) centred on the optical axis
    A = np.array([[px_per_m, 0, w / 2 - 0.5], [0, px_per_m, h / 2 - 0.5], [0, 0, 1]])
    return tex, A


@pytest.fixture(scope="module")
def rendered():
    rig = zed_like_rig()
    tex, A = plane_texture(np.random.default_rng(7))
    R_cp, t_cp = np.eye(3), np.array([0.0, 0.0, PLANE_Z_M])
    left = render_plane(tex, A, R_cp, t_cp, pixel_rays(rig.K1, rig.D1, SIZE, 1))
    right = render_plane(tex, A, rig.R @ R_cp, rig.R @ t_cp + rig.T, pixel_rays(rig.K2, rig.D2, SIZE, 1))
    return rig, left, right


def _true_depth(rect, pts_rect: np.ndarray) -> np.ndarray:
    """Depth (rectified-frame z) of the plane Z_left = PLANE_Z_M seen at rectified left pixels."""
    r = np.column_stack([(pts_rect[:, 0] - rect.cx_px) / rect.focal_px, (pts_rect[:, 1] - rect.cy_px) / rect.P1[1, 1],
                         np.ones(len(pts_rect))])
    r_left = r @ rect.R1  # R1.T @ r per row: direction in the raw left camera frame
    return PLANE_Z_M / r_left[:, 2]


def test_zed_conf_roundtrip_rectifies_rendered_pair(tmp_path, rendered):
    rig, left, right = rendered
    conf = write_zed_conf(rig, tmp_path, serial=28123456)
    read = load_rig(conf, SIZE)
    rect = read.rectification()
    lr, rr = rectify_pair(left, right, rect)
    pl, pr = match_features(lr, rr)
    assert len(pl) > 200
    dy = np.abs(pl[:, 1] - pr[:, 1])
    assert np.median(dy) < 0.1 and np.percentile(dy, 95) < 0.5
    d = pl[:, 0] - pr[:, 0]
    assert np.all(d > 0), "disparities must be positive (right eye to the right)"
    z = rect.focal_px * rect.baseline_m / d
    z_true = _true_depth(rect, pl)
    assert np.median(np.abs(z / z_true - 1)) < 0.01
    assert rect.baseline_m == pytest.approx(0.11993, rel=1e-3)
    # Q gives the same (positive) depth
    xyz = cv2.perspectiveTransform(np.column_stack([pl, d]).reshape(-1, 1, 3).astype(np.float64), rect.Q).reshape(-1, 3)
    assert np.median(np.abs(xyz[:, 2] / z_true - 1)) < 0.01


def test_other_rotation_convention_misaligns_rows(rendered):
    """Using R transposed (Stereolabs' C++ readers' other convention) leaves rows misaligned: the test can fail."""
    rig, left, right = rendered
    wrong = rig.replace(R=rig.R.T)
    stats = epipolar_error(left, right, wrong)
    assert stats["median_dy_px"] > 1.0
    good = epipolar_error(left, right, rig)
    assert good["median_dy_px"] < 0.1 and good["p95_dy_px"] < 0.5


@pytest.mark.slow
def test_detects_already_rectified_and_raw_frames(rendered):
    rig, left, right = rendered
    rect = rig.rectification()
    lr, rr = rectify_pair(left, right, rect)
    rectified_rig = StereoRig.from_rectified(rect.focal_px, rect.P1[1, 1], rect.cx_px, rect.cy_px, rect.baseline_m, SIZE)
    # raw frames with the raw calibration: fits
    v = detect_rectification_mismatch(left, right, rig)
    assert v["verdict"] == "ok", v["message"]
    assert v["raw"]["median_dy_px"] > 1.0 > v["rectified"]["median_dy_px"]
    # already-rectified frames rectified again with the factory calibration: worse, and said so
    v = detect_rectification_mismatch(lr, rr, rig)
    assert v["verdict"] == "already_rectified", v["message"]
    assert v["rectified"]["median_dy_px"] > v["raw"]["median_dy_px"]
    # already-rectified frames with the rectified parameters: fits
    v = detect_rectification_mismatch(lr, rr, rectified_rig)
    assert v["verdict"] == "ok", v["message"]
    # raw frames declared rectified: said so
    v = detect_rectification_mismatch(left, right, rectified_rig)
    assert v["verdict"] == "not_rectified", v["message"]
    # swapped eyes
    v = detect_rectification_mismatch(rr, lr, rectified_rig)
    assert v["verdict"] == "swapped_eyes", v["message"]


@pytest.mark.slow
def test_calib_check_command_on_side_by_side_image(tmp_path, rendered, capsys):
    from stereo_recon.app.cli import main

    rig, left, right = rendered
    conf = write_zed_conf(rig, tmp_path / "SN5.conf")
    cv2.imwrite(str(tmp_path / "raw.png"), np.hstack([left, right]))
    lr, rr = rectify_pair(left, right, rig.rectification())
    cv2.imwrite(str(tmp_path / "rect.png"), np.hstack([lr, rr]))
    assert main(["calib-check", "--calib", str(conf), str(tmp_path / "raw.png")]) == 0
    assert "ok:" in capsys.readouterr().out
    assert main(["calib-check", "--calib", str(conf), str(tmp_path / "rect.png"), "--out", str(tmp_path / "c.json")]) == 1
    assert "already_rectified" in capsys.readouterr().out
    assert (tmp_path / "c.json").exists()
