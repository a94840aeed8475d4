"""ZED factory calibration files (``SN<serial>.conf``): read and write.

The reading follows Stereolabs' own Python sample (stereolabs/zed-opencv-native,
``python/zed_opencv_native.py``): per resolution ``<res>``, K from ``[LEFT_CAM_<res>]`` fx fy cx cy,
D = [k1, k2, p1, p2, k3], ``R = Rodrigues([RX_<res>, CV_<res>, RZ_<res>])`` used as-is, and
``T = [-Baseline, TY, TZ]`` in millimetres (converted to metres here). That matches OpenCV's
``X_right = R X_left + T`` with the right eye to the right. (Stereolabs' C++ readers use
``+Baseline``, which flips the sign of Q and of disparities — not followed.)
"""

from __future__ import annotations

import configparser
import logging
import math
import os
from pathlib import Path

import numpy as np

from calib.rig import StereoRig, same_aspect
from stereo_recon.core.errors import InputError

log = logging.getLogger(__name__)

# Eye sizes (width, height) of each resolution section a ZED .conf may hold.
ZED_RESOLUTIONS: dict[str, tuple[int, int]] = {
    "2K": (2208, 1242),
    "FHD": (1920, 1080),
    "HD": (1280, 720),
    "VGA": (672, 376),
    # ZED X / X Mini sections
    "FHD1200": (1920, 1200),
    "SVGA": (960, 600),
}
# Sections written by write_zed_conf (the ZED2's resolutions).
ZED2_RESOLUTIONS = ("2K", "FHD", "HD", "VGA")
_DIST_KEYS = ("k1", "k2", "p1", "p2", "k3")
# Terms of lens models this reader cannot represent faithfully (refused when non-zero).
_UNSUPPORTED_DIST_KEYS = ("k4", "k5", "k6", "s1", "s2", "s3", "s4", "p3")


def _parse(path: Path) -> dict[str, dict[str, str]]:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str.lower  # keys in any case
    try:
        text = path.read_text(encoding="utf-8", errors="replace").lstrip("\ufeff")
        parser.read_string(text, source=str(path))
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from None
    except configparser.Error as err:
        first = str(err).splitlines()[0]
        raise InputError(f"{path}: not a ZED calibration file ({first})") from None
    sections: dict[str, dict[str, str]] = {}
    for name in parser.sections():
        sections.setdefault(name.strip().upper(), {}).update({k: v for k, v in parser.items(name)})
    return sections


def _float(path: Path, section: str, values: dict[str, str], key: str, default: float | None = None) -> float:
    if key not in values or values[key].strip() == "":
        if default is None:
            raise InputError(f"{path}: [{section}] is missing the key '{key}'")
        return default
    try:
        v = float(values[key].strip())
    except ValueError:
        raise InputError(f"{path}: [{section}] {key} = {values[key]!r} is not a number") from None
    if not math.isfinite(v):
        raise InputError(f"{path}: [{section}] {key} is not finite")
    return v


def available_resolutions(path: str | os.PathLike) -> list[str]:
    """Resolution names ("2K", "HD", ...) that have both LEFT_CAM_ and RIGHT_CAM_ sections in the file."""
    sections = _parse(Path(path))
    return [r for r in ZED_RESOLUTIONS if f"LEFT_CAM_{r}" in sections and f"RIGHT_CAM_{r}" in sections]


def read_zed_conf(path: str | os.PathLike, image_size: tuple[int, int] | None = None,
                  resolution: str | None = None) -> StereoRig:
    """Read a ZED ``.conf`` for frames of ``image_size`` (width, height of ONE eye).

    The section whose eye size equals ``image_size`` is used; otherwise one with the same aspect is
    scaled; otherwise InputError. Without ``image_size``, ``resolution`` (default "HD") picks it.
    Returns a raw (unrectified) rig; metadata holds source, serial and the section used.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: calibration file not found")
    sections = _parse(path)
    avail = [r for r in ZED_RESOLUTIONS if f"LEFT_CAM_{r}" in sections and f"RIGHT_CAM_{r}" in sections]
    if not avail:
        raise InputError(f"{path}: no [LEFT_CAM_<res>]/[RIGHT_CAM_<res>] sections (res one of {', '.join(ZED_RESOLUTIONS)}); "
                         "not a ZED calibration file")
    if "STEREO" not in sections:
        raise InputError(f"{path}: the [STEREO] section is missing")
    if image_size is not None:
        image_size = (int(image_size[0]), int(image_size[1]))
        res = _section_for_size(path, avail, image_size)
    else:
        res = (resolution or "HD").upper()
        if res not in avail:
            if resolution is not None:
                raise InputError(f"{path}: no [LEFT_CAM_{res}] section (file has {', '.join(avail)})")
            res = avail[0]
    (K1, D1), (K2, D2) = (_eye(path, f"{eye}_CAM_{res}", sections[f"{eye}_CAM_{res}"]) for eye in ("LEFT", "RIGHT"))
    R, T = _stereo_extrinsics(path, sections["STEREO"], res)
    serial = path.stem[2:] if path.stem.upper().startswith("SN") else None
    meta = {"source": f"ZED factory calibration {path.name} [{res}]", "format": "zed-conf", "zed_resolution": res}
    if serial:
        meta["serial"] = serial
    rig = StereoRig(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=ZED_RESOLUTIONS[res], metadata=meta)
    if image_size is not None and image_size != rig.image_size:
        rig = rig.scaled(image_size)
    return rig


def _section_for_size(path: Path, avail: list[str], image_size: tuple[int, int]) -> str:
    """The resolution whose section fits frames of ``image_size`` (w, h of one eye): exact, else the same aspect."""
    exact = [r for r in avail if ZED_RESOLUTIONS[r] == image_size]
    if exact:
        return exact[0]
    same = [r for r in avail if same_aspect(ZED_RESOLUTIONS[r], image_size)]
    if not same:
        sizes = ", ".join(f"{r} {ZED_RESOLUTIONS[r][0]}x{ZED_RESOLUTIONS[r][1]}" for r in avail)
        raise InputError(f"{path}: no calibration for {image_size[0]}x{image_size[1]} frames and none of the same "
                         f"aspect ratio to scale (file has {sizes})")

    # Each ZED resolution is its own crop/binning of the sensor, so the video was most likely
    # resized from the section of exactly its aspect and nearest size.
    def _key(r: str) -> tuple[bool, float]:
        w, h = ZED_RESOLUTIONS[r]
        return (not same_aspect((w, h), image_size, 1e-3), abs(math.log(w / image_size[0])))

    res = min(same, key=_key)
    log.warning("%s: no section for %dx%d frames; scaling [%s] %dx%d (if the video was resized from another "
                "ZED resolution, resize it back or pass a matching calibration)", path, *image_size, res,
                *ZED_RESOLUTIONS[res])
    return res


def _eye(path: Path, sec: str, vals: dict[str, str]) -> tuple[np.ndarray, np.ndarray]:
    """One eye's intrinsics K (3, 3) in pixels and distortion (k1 k2 p1 p2 k3) from its [<EYE>_CAM_<res>] section."""
    fx, fy, cx, cy = (_float(path, sec, vals, k) for k in ("fx", "fy", "cx", "cy"))
    for key, v in (("fx", fx), ("fy", fy)):
        if v <= 0:
            raise InputError(f"{path}: [{sec}] {key} = {v:g}: a focal length must be > 0 pixels")
    for k in _UNSUPPORTED_DIST_KEYS:
        if k in vals and _float(path, sec, vals, k, 0.0) != 0.0:
            raise InputError(f"{path}: [{sec}] uses a lens model with the term '{k}' (beyond k1 k2 p1 p2 k3), which this "
                             "reader does not model; export rectified video with the ZED SDK and pass --calib "
                             "fx,fy,cx,cy,baseline_m instead")
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return K, np.array([_float(path, sec, vals, k, 0.0) for k in _DIST_KEYS])


def _stereo_extrinsics(path: Path, st: dict[str, str], res: str) -> tuple[np.ndarray, np.ndarray]:
    """R (3, 3) and T (3,) metres of the right eye from the left, from [STEREO] (baseline in mm, Rodrigues angles)."""
    import cv2

    baseline_mm = _float(path, "STEREO", st, "baseline")
    if baseline_mm <= 0:
        raise InputError(f"{path}: [STEREO] Baseline = {baseline_mm} mm; expected a positive distance in millimetres")
    r = res.lower()
    # Recent files write TY/TZ without the resolution suffix; older ones TY_<res>/TZ_<res>.
    ty = _float(path, "STEREO", st, f"ty_{r}", _float(path, "STEREO", st, "ty", 0.0))
    tz = _float(path, "STEREO", st, f"tz_{r}", _float(path, "STEREO", st, "tz", 0.0))
    missing_rot = [k.upper() + f"_{res}" for k in ("rx", "cv", "rz") if f"{k}_{r}" not in st]
    if len(missing_rot) == 3:
        raise InputError(f"{path}: [STEREO] is missing the keys {', '.join(missing_rot)} (the eyes' relative rotation)")
    rvec = np.array([_float(path, "STEREO", st, f"{k}_{r}", 0.0) for k in ("rx", "cv", "rz")])
    R = cv2.Rodrigues(rvec.reshape(3, 1))[0]
    return R, np.array([-baseline_mm, ty, tz]) / 1000.0


def _fmt(v: float) -> str:
    return repr(float(v))


def write_zed_conf(rig: StereoRig, path: str | os.PathLike, serial: int = 0,
                   resolutions: tuple[str, ...] = ZED2_RESOLUTIONS) -> Path:
    """Write ``rig`` as a ZED-style ``.conf`` (atomic), scaled to every resolution of ``resolutions``
    whose aspect matches the rig's (``rig.image_size`` need not be one of them).

    [LEFT_CAM_<res>]/[RIGHT_CAM_<res>]: fx fy cx cy k1 k2 p1 p2 k3. [STEREO]: Baseline (mm, positive),
    TY/TZ and TY_<res>/TZ_<res> (mm), CV_<res>/RX_<res>/RZ_<res> (rad) such that
    ``read_zed_conf`` reproduces rig.R and rig.T. If ``path`` is a folder, writes ``SN<serial>.conf`` in it.
    """
    import cv2

    path = Path(path)
    if path.is_dir():
        path = path / f"SN{int(serial)}.conf"
    for name, D in (("D1", rig.D1), ("D2", rig.D2)):
        if D.size > 5 and np.any(D[5:] != 0):
            raise InputError(f"{path}: cannot write {name} with {D.size} coefficients to a ZED .conf (k1 k2 p1 p2 k3 only)")
    if rig.T[0] >= 0:
        raise InputError(f"{path}: T[0] = {rig.T[0]} m >= 0; a ZED .conf needs the right eye to the right (T ~ [-B, 0, 0])")
    res_list = [r for r in resolutions if same_aspect(ZED_RESOLUTIONS[r], rig.image_size)]
    if not res_list:
        raise InputError(f"{path}: no ZED resolution has the aspect of {rig.image_size[0]}x{rig.image_size[1]} frames")
    rvec = cv2.Rodrigues(rig.R)[0].reshape(3)
    T_mm = rig.T * 1000.0
    lines: list[str] = []
    for eye, K, D in (("LEFT", rig.K1, rig.D1), ("RIGHT", rig.K2, rig.D2)):
        for r in res_list:
            s = rig.scaled(ZED_RESOLUTIONS[r])
            Ks = s.K1 if eye == "LEFT" else s.K2
            d = np.zeros(5)
            d[: min(5, D.size)] = D[:5]
            lines.append(f"[{eye}_CAM_{r}]")
            lines += [f"fx={_fmt(Ks[0, 0])}", f"fy={_fmt(Ks[1, 1])}", f"cx={_fmt(Ks[0, 2])}", f"cy={_fmt(Ks[1, 2])}"]
            lines += [f"{k}={_fmt(v)}" for k, v in zip(_DIST_KEYS, d)]
            lines.append("")
    lines.append("[STEREO]")
    lines.append(f"Baseline={_fmt(-T_mm[0])}")
    lines.append(f"TY={_fmt(T_mm[1])}")
    lines.append(f"TZ={_fmt(T_mm[2])}")
    for r in res_list:
        lines += [f"CV_{r}={_fmt(rvec[1])}", f"RX_{r}={_fmt(rvec[0])}", f"RZ_{r}={_fmt(rvec[2])}",
                  f"TY_{r}={_fmt(T_mm[1])}", f"TZ_{r}={_fmt(T_mm[2])}"]
    lines.append("")
    lines.append("[MISC]")
    lines.append("Sensor_ID=0")
    lines.append("")
    from stereo_recon.core.atomic import write_text_atomic

    return write_text_atomic(path, "\n".join(lines))
