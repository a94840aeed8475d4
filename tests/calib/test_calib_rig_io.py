"""StereoRig, rectification and rig file formats: round trips, conventions, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib.io import load_rig, parse_calib_arg, save_opencv_stereo, save_rig, write_zed_conf
from calib.rig import StereoRig, rectify_pair
from calib.zedconf import read_zed_conf
from stereo_recon.core.errors import InputError


def make_rig(size=(1280, 720), **meta) -> StereoRig:
    w, h = size
    s = w / 1280
    K1 = np.array([[700.3 * s, 0, 641.7 * s], [0, 700.9 * s, 359.2 * s], [0, 0, 1]])
    K2 = np.array([[701.1 * s, 0, 637.4 * s], [0, 701.5 * s, 362.8 * s], [0, 0, 1]])
    R = cv2.Rodrigues(np.array([0.0021, -0.0093, 0.0017]))[0]
    return StereoRig(K1=K1, D1=np.array([-0.171, 0.0273, 0.00031, -0.00022, 0.0011]), K2=K2,
                     D2=np.array([-0.169, 0.0261, -0.0002, 0.00015, 0.0009]), R=R,
                     T=np.array([-0.11987, 0.000288, -0.000614]), image_size=size, metadata=meta)


def test_rig_stores_float64_readonly_copies():
    K = np.eye(3, dtype=np.float32)
    K[0, 0] = K[1, 1] = 500
    rig = StereoRig(K1=K, D1=[0, 0, 0, 0], K2=K, D2=np.zeros(5), R=np.eye(3), T=[-0.1, 0, 0], image_size=(640, 480))
    K[0, 0] = 1.0
    assert rig.K1.dtype == np.float64 and rig.K1[0, 0] == 500
    assert rig.D1.shape == (4,)
    with pytest.raises(ValueError):
        rig.K1[0, 0] = 3
    assert rig.baseline_m == pytest.approx(0.1)


@pytest.mark.parametrize("bad", [dict(K1=np.eye(2)), dict(D1=np.zeros(6)), dict(R=np.diag([1, 1, -1.0])),
                                 dict(T=[1, 2]), dict(image_size=(0, 10)), dict(K2=[[1, 0, 0], [0, 1, 0], [0, 0, 2]])])
def test_rig_rejects_bad_shapes(bad):
    kw = dict(K1=np.diag([500, 500, 1.0]), D1=np.zeros(5), K2=np.diag([500, 500, 1.0]), D2=np.zeros(5), R=np.eye(3),
              T=[-0.1, 0, 0], image_size=(640, 480))
    kw.update(bad)
    with pytest.raises(InputError):
        StereoRig(**kw)


def test_rectification_rows_align_and_depth_scale():
    rig = make_rig()
    rect = rig.rectification()
    # A 3D point seen by both eyes must land on the same rectified row, with Z = f B / d.
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-0.5, 0.5, 50), rng.uniform(2, 8, 50)])
    xl = cv2.projectPoints(X, np.zeros(3), np.zeros(3), rig.K1, rig.D1)[0].reshape(-1, 2)
    rv = cv2.Rodrigues(rig.R)[0]
    xr = cv2.projectPoints(X, rv, rig.T, rig.K2, rig.D2)[0].reshape(-1, 2)
    yl = rect.rectify_points(xl, "left", rig)
    yr = rect.rectify_points(xr, "right", rig)
    assert np.abs(yl[:, 1] - yr[:, 1]).max() < 1e-3
    d = yl[:, 0] - yr[:, 0]
    assert np.all(d > 0)
    Z = rect.focal_px * rect.baseline_m / d
    Xl_rect = (rect.R1 @ X.T).T
    np.testing.assert_allclose(Z, Xl_rect[:, 2], rtol=1e-6)
    # Q reprojects disparities to the same depth (sign included)
    pts = cv2.perspectiveTransform(np.column_stack([yl, d]).reshape(-1, 1, 3), rect.Q).reshape(-1, 3)
    np.testing.assert_allclose(pts[:, 2], Xl_rect[:, 2], rtol=1e-6)
    assert rect.baseline_m == pytest.approx(rig.baseline_m, rel=1e-9)
    np.testing.assert_allclose(rect.K_rect, rect.P1[:, :3])


def test_rectify_pair_maps_images_and_identity_for_rectified():
    rig = make_rig((320, 180))
    left = np.random.default_rng(1).integers(0, 255, (180, 320, 3), dtype=np.uint8)
    right = left.copy()
    for mt in ("32FC1", "16SC2"):
        l2, r2 = rectify_pair(left, right, rig.rectification(map_type=mt))
        assert l2.shape == left.shape and not np.array_equal(l2, left)
    rr = StereoRig.from_rectified(300, 300, 160, 90, 0.12, (320, 180))
    rect = rr.rectification()
    assert rect.map_left is None and rect.identity
    l2, r2 = rectify_pair(left, right, rect)
    assert l2 is left and r2 is right
    assert rect.Q[3, 2] == pytest.approx(1 / 0.12)
    assert rect.P2[0, 3] == pytest.approx(-300 * 0.12)
    with pytest.raises(InputError, match="320x180"):
        rectify_pair(left[:100], right[:100], rect)


def test_scaled_same_aspect_and_refuses_other_aspect():
    rig = make_rig()
    half = rig.scaled((640, 360))
    assert half.K1[0, 0] == pytest.approx(rig.K1[0, 0] / 2)
    assert half.K1[0, 2] == pytest.approx((rig.K1[0, 2] + 0.5) / 2 - 0.5)
    np.testing.assert_array_equal(half.T, rig.T)
    back = half.scaled((1280, 720))
    np.testing.assert_allclose(back.K1, rig.K1, rtol=1e-12)
    with pytest.raises(InputError, match="aspect"):
        rig.scaled((640, 480))


def test_swapped_eyes_are_refused():
    rig = make_rig().replace(T=np.array([0.12, 0, 0]))
    with pytest.raises(InputError, match="swapped"):
        rig.rectification()


@pytest.mark.parametrize("suffix", [".yaml", ".yml", ".xml"])
def test_rig_file_roundtrip_lossless(tmp_path, suffix):
    rig = make_rig(source="unit test", rms_px=0.2345678901234567, date="2026-11-22T00:00:00Z", per_view=[0.1, 0.2])
    p = save_rig(rig, tmp_path / f"rig{suffix}")
    back = load_rig(p)
    assert back == rig
    for n in ("K1", "D1", "K2", "D2", "R", "T"):
        assert np.array_equal(getattr(back, n), getattr(rig, n))
    assert back.metadata["rms_px"] == rig.metadata["rms_px"]
    assert back.metadata["source"] == "unit test" and back.metadata["per_view"] == [0.1, 0.2]
    # OpenCV itself reads the names its samples use
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    np.testing.assert_array_equal(fs.getNode("K1").mat(), rig.K1)
    assert int(fs.getNode("image_width").real()) == 1280


def test_rectified_rig_roundtrip(tmp_path):
    rig = StereoRig.from_rectified(700.5, 700.5, 640.25, 360.75, 0.12, (1280, 720))
    back = load_rig(save_rig(rig, tmp_path / "r.yaml"))
    assert back.rectified and back == rig


def test_opencv_sample_names_and_plain_yaml(tmp_path):
    rig = make_rig()
    p = save_opencv_stereo(rig, tmp_path / "extr.yml")
    back = load_rig(p)
    assert back == rig
    # a hand-written plain YAML with lists works too
    plain = tmp_path / "hand.yaml"
    plain.write_text("image_size: [1280, 720]\nK1: %s\nD1: %s\nK2: %s\nD2: %s\nR: %s\nT: %s\n" % tuple(
        str(np.asarray(getattr(rig, n)).tolist()) for n in ("K1", "D1", "K2", "D2", "R", "T")))
    assert load_rig(plain) == rig


def test_zed_conf_roundtrip_all_resolutions(tmp_path):
    rig = make_rig()
    p = write_zed_conf(rig, tmp_path, serial=12345)
    assert p.name == "SN12345.conf"
    text = p.read_text()
    for key in ("[LEFT_CAM_2K]", "[RIGHT_CAM_VGA]", "Baseline=119.87", "CV_HD=", "RX_FHD=", "RZ_VGA=", "TY_HD=", "TZ="):
        assert key in text
    back = read_zed_conf(p, (1280, 720))
    np.testing.assert_allclose(back.K1, rig.K1, rtol=1e-15)
    np.testing.assert_allclose(back.D2, rig.D2, rtol=1e-15)
    np.testing.assert_allclose(back.R, rig.R, atol=1e-14)
    np.testing.assert_allclose(back.T, rig.T, rtol=1e-12)
    assert back.metadata["serial"] == "12345"
    for res, size in (("2K", (2208, 1242)), ("FHD", (1920, 1080)), ("VGA", (672, 376))):
        r = load_rig(p, size)
        assert r.image_size == size and r.metadata["zed_resolution"] == res
        np.testing.assert_allclose(r.K1[0, 0], rig.K1[0, 0] * size[0] / 1280, rtol=1e-12)


ZED_SAMPLE = """[LEFT_CAM_HD]
fx=700.5
fy=700.1
cx=639.2
cy=361.8
k1=-0.171
k2=0.0273
k3=0
p1=0.0001
p2=-0.0002

[RIGHT_CAM_HD]
FX=701.0
fy=700.6
cx=641.5
cy=360.2
k1=-0.169
k2=0.0261
k3=0

[STEREO]
BaseLine=119.87
ty=0.5
TZ_HD=-0.7
TZ=3.0
cv_hd=0.0021
RX_HD=-0.0009
RZ_HD=0.0004
"""


def test_zed_conf_keys_any_case_and_suffixes(tmp_path):
    p = tmp_path / "SN1000.conf"
    p.write_text(ZED_SAMPLE)
    rig = load_rig(p, (1280, 720))
    # T = [-Baseline, TY, TZ] mm -> m; TZ_HD beats TZ; R = Rodrigues([RX, CV, RZ])
    np.testing.assert_allclose(rig.T, [-0.11987, 0.0005, -0.0007])
    np.testing.assert_allclose(rig.R, cv2.Rodrigues(np.array([-0.0009, 0.0021, 0.0004]))[0])
    np.testing.assert_allclose(rig.D2, [-0.169, 0.0261, 0, 0, 0])
    assert rig.K2[0, 0] == 701.0
    # scaled from HD when the video is another size of the same aspect
    assert load_rig(p, (640, 360)).K1[0, 0] == pytest.approx(350.25)
    with pytest.raises(InputError, match="aspect"):
        load_rig(p, (640, 480))


def test_zed_conf_k4_refused_and_missing_keys(tmp_path):
    p = tmp_path / "SN2.conf"
    p.write_text(ZED_SAMPLE.replace("k3=0\np1", "k3=0\nk4=0.01\np1"))
    with pytest.raises(InputError, match="k4"):
        load_rig(p, (1280, 720))
    p.write_text(ZED_SAMPLE.replace("k3=0\np1", "k3=0\nk4=0\np1"))  # a zero k4 is harmless
    load_rig(p, (1280, 720))
    p.write_text(ZED_SAMPLE.replace("cx=641.5\n", ""))
    with pytest.raises(InputError, match=r"RIGHT_CAM_HD.*'cx'"):
        load_rig(p, (1280, 720))
    p.write_text(ZED_SAMPLE.replace("BaseLine=119.87\n", ""))
    with pytest.raises(InputError, match="baseline"):
        load_rig(p, (1280, 720))
    p.write_text("garbage without sections\n")
    with pytest.raises(InputError):
        load_rig(p, (1280, 720))


def test_corrupt_and_incomplete_rig_files(tmp_path):
    rig = make_rig()
    p = save_rig(rig, tmp_path / "rig.yaml")
    text = p.read_text()
    # drop K2 entirely
    start = text.index("K2:")
    end = text.index("D2:")
    (tmp_path / "nok2.yaml").write_text(text[:start] + text[end:])
    with pytest.raises(InputError, match="'K2'"):
        load_rig(tmp_path / "nok2.yaml")
    (tmp_path / "trunc.yaml").write_text(text[: len(text) // 3])
    with pytest.raises(InputError, match="trunc.yaml"):
        load_rig(tmp_path / "trunc.yaml")
    (tmp_path / "empty.yaml").write_text("")
    with pytest.raises(InputError, match="empty"):
        load_rig(tmp_path / "empty.yaml")
    with pytest.raises(InputError, match="not found"):
        load_rig(tmp_path / "nope.yaml")
    nosize = text.replace("image_width: 1280\n", "")
    (tmp_path / "nosize.yaml").write_text(nosize)
    with pytest.raises(InputError, match="image_width"):
        load_rig(tmp_path / "nosize.yaml")
    assert load_rig(tmp_path / "nosize.yaml", (1280, 720)) == rig


def test_parse_calib_arg(tmp_path):
    rig = parse_calib_arg("700,701,640,360,0.12,1280,720")
    assert rig.rectified and rig.image_size == (1280, 720) and rig.K1[1, 1] == 701
    assert parse_calib_arg("700,700,640,360,0.12", image_size=(1280, 720)).image_size == (1280, 720)
    assert parse_calib_arg("700,700,640,360,0.12,1280,720", image_size=(640, 360)).K1[0, 0] == pytest.approx(350)
    with pytest.raises(InputError, match="width,height"):
        parse_calib_arg("700,700,640,360,0.12")
    with pytest.raises(InputError, match="5 or 7"):
        parse_calib_arg("700,700,640")
    with pytest.raises(InputError, match="baseline"):
        parse_calib_arg("700,700,640,360,-0.12,1280,720")
    with pytest.raises(InputError, match="not found"):
        parse_calib_arg(str(tmp_path / "x.conf"))
    p = save_rig(make_rig(), tmp_path / "r.yaml")
    assert parse_calib_arg(str(p)) == make_rig()


def test_rig_yaml_carries_the_rectification(tmp_path):
    """R1 R2 P1 P2 Q in the rig YAML (as OpenCV's stereo sample writes them) are the rectification the pipeline uses."""
    import cv2

    from calib.io import load_rig, save_rig

    rig = make_rig()
    path = save_rig(rig, tmp_path / "rig.yaml")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    rect = rig.rectification(0.0)
    for name in ("R1", "R2", "P1", "P2", "Q"):
        assert np.allclose(fs.getNode(name).mat(), getattr(rect, name)), name
    # rectifying a point with the file's matrices alone gives the same row in both eyes (a point 5 m away)
    X = np.array([[0.3, -0.2, 5.0]])
    pl, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), fs.getNode("K1").mat(), fs.getNode("D1").mat())
    pr, _ = cv2.projectPoints(X, cv2.Rodrigues(fs.getNode("R").mat())[0], fs.getNode("T").mat(), fs.getNode("K2").mat(),
                              fs.getNode("D2").mat())
    ul = cv2.undistortPoints(pl, fs.getNode("K1").mat(), fs.getNode("D1").mat(), R=fs.getNode("R1").mat(), P=fs.getNode("P1").mat())
    ur = cv2.undistortPoints(pr, fs.getNode("K2").mat(), fs.getNode("D2").mat(), R=fs.getNode("R2").mat(), P=fs.getNode("P2").mat())
    assert abs(float(ul[0, 0, 1] - ur[0, 0, 1])) < 1e-3
    fs.release()
    assert np.allclose(load_rig(path).R, rig.R)  # the reader still takes K1 D1 K2 D2 R T
