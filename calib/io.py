"""Rig files: the project's rig YAML, OpenCV FileStorage YAML/XML, ZED ``.conf``; ``--calib`` parsing.

The project's rig YAML is an OpenCV FileStorage file (readable by ``cv2.FileStorage``) with the
names OpenCV's stereo samples use -- ``K1 D1 K2 D2 R T`` (``M1``/``M2`` accepted on reading) --
plus ``image_width``, ``image_height``, ``rectified`` and a ``metadata`` map (source, rms_px, date,
...). Doubles are written with 17 significant digits, so round trips are lossless.
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from calib.rig import StereoRig
from calib.zedconf import read_zed_conf, write_zed_conf  # noqa: F401  (re-exported: calib.io.write_zed_conf)
from stereo_recon.core.errors import InputError
from stereo_recon.core.atomic import write_atomic

log = logging.getLogger(__name__)

RIG_FORMAT = "stereo-recon-rig"
RIG_FORMAT_VERSION = 1
_MATRIX_KEYS = {"K1": ("K1", "M1", "cameraMatrix1", "camera_matrix_left"), "D1": ("D1", "distCoeffs1", "dist_coeffs_left"),
                "K2": ("K2", "M2", "cameraMatrix2", "camera_matrix_right"), "D2": ("D2", "distCoeffs2", "dist_coeffs_right"),
                "R": ("R",), "T": ("T",)}
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_INLINE_RE = re.compile(rf"^\s*{_NUM}(?:\s*,\s*{_NUM})*\s*$")


# -- writing ---------------------------------------------------------------------------------
def _write_value(fs: Any, name: str, value: Any) -> None:
    import cv2

    if value is None:
        return
    if isinstance(value, dict):
        fs.startWriteStruct(name, cv2.FileNode_MAP)
        for k, v in value.items():
            key = re.sub(r"[^A-Za-z0-9_]", "_", str(k)) or "_"
            if key[0].isdigit():
                key = "_" + key
            _write_value(fs, key, v)
        fs.endWriteStruct()
    elif isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray) and value.ndim == 1):
        fs.startWriteStruct(name, cv2.FileNode_SEQ)
        for v in value:
            _write_value(fs, "", v)
        fs.endWriteStruct()
    elif isinstance(value, np.ndarray):
        fs.write(name, np.asarray(value, dtype=np.float64))
    elif isinstance(value, (bool, np.bool_)):
        fs.write(name, int(value))
    elif isinstance(value, (int, np.integer)):
        fs.write(name, int(value))
    elif isinstance(value, (float, np.floating)):
        fs.write(name, float(value))
    else:
        fs.write(name, str(value))


def _write_filestorage(path: Path, entries: dict[str, Any]) -> Path:
    """Write ``entries`` with cv2.FileStorage (format from the suffix) atomically."""
    import cv2

    def write(tmp: str) -> None:
        fs = cv2.FileStorage(tmp, cv2.FILE_STORAGE_WRITE)
        if not fs.isOpened():
            raise InputError(f"{path}: cannot open for writing")
        for k, v in entries.items():
            _write_value(fs, k, v)
        fs.release()

    return write_atomic(path, write, suffix=".xml" if path.suffix.lower() == ".xml" else ".yaml")


def save_rig(rig: StereoRig, path: str | os.PathLike) -> Path:
    """Write the project's rig YAML (or XML when ``path`` ends in .xml), atomically; returns the path."""
    path = Path(path)
    entries: dict[str, Any] = {
        "format": RIG_FORMAT,
        "format_version": RIG_FORMAT_VERSION,
        "image_width": rig.image_size[0],
        "image_height": rig.image_size[1],
        "rectified": int(rig.rectified),
        "K1": rig.K1, "D1": rig.D1.reshape(1, -1), "K2": rig.K2, "D2": rig.D2.reshape(1, -1),
        "R": rig.R, "T": rig.T.reshape(3, 1),
        "baseline_m": rig.baseline_m,  # informational (= |T|); ignored on reading
    }
    # The rectification this project applies (alpha 0, zero disparity at infinity), under OpenCV's stereo-sample
    # names, so other tools can rectify and triangulate without recomputing it; informational, ignored on reading.
    rect = rig.rectification(0.0)
    entries.update({"R1": rect.R1, "R2": rect.R2, "P1": rect.P1, "P2": rect.P2, "Q": rect.Q})
    if rig.metadata:
        entries["metadata"] = dict(rig.metadata)
    return _write_filestorage(path, entries)


def save_opencv_stereo(rig: StereoRig, path: str | os.PathLike, alpha: float = 0.0) -> Path:
    """Write plain OpenCV stereo-sample names (M1 D1 M2 D2 R T R1 R2 P1 P2 Q + image size) for other tools."""
    import cv2

    w, h = rig.image_size
    if rig.rectified:
        rect = rig.rectification(alpha)
        R1, R2, P1, P2, Q = rect.R1, rect.R2, rect.P1, rect.P2, rect.Q
    else:
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(rig.K1, rig.D1, rig.K2, rig.D2, (w, h), rig.R, rig.T.reshape(3, 1),
                                                    flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha)
    return _write_filestorage(Path(path), {"image_width": w, "image_height": h, "M1": rig.K1, "D1": rig.D1.reshape(1, -1),
                                           "M2": rig.K2, "D2": rig.D2.reshape(1, -1), "R": rig.R, "T": rig.T.reshape(3, 1),
                                           "R1": R1, "R2": R2, "P1": P1, "P2": P2, "Q": Q})


# -- reading ---------------------------------------------------------------------------------
def _node_to_py(node: Any) -> Any:
    if node.empty() or node.isNone():
        return None
    if node.isMap():
        if node.getNode("dt").isString() and node.getNode("data").isSeq():  # an opencv-matrix
            return node.mat()
        return {k: _node_to_py(node.getNode(k)) for k in node.keys()}
    if node.isSeq():
        return [_node_to_py(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def _cv_msg(err: BaseException) -> str:
    """The useful part of a cv2.error (possibly wrapped in a SystemError), on one line."""
    inner = err.__cause__ or err.__context__ or err
    msg = getattr(inner, "err", None) or str(inner)
    return " ".join(str(msg).split())[:200]


def _read_filestorage(path: Path) -> dict[str, Any]:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_FORMAT_AUTO)
    except (cv2.error, SystemError) as err:
        raise InputError(f"{path}: corrupt calibration file ({_cv_msg(err)})") from None
    if not fs.isOpened():
        raise InputError(f"{path}: cannot be read as an OpenCV YAML/XML file")
    try:
        root = fs.root()
        return {k: _node_to_py(root.getNode(k)) for k in root.keys()}
    except (cv2.error, SystemError) as err:
        raise InputError(f"{path}: corrupt calibration file ({_cv_msg(err)})") from None
    finally:
        fs.release()


def _read_plain_yaml(path: Path) -> dict[str, Any]:
    import yaml

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        first = str(err).strip().splitlines()[0]
        raise InputError(f"{path}: corrupt calibration file ({first})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: not a calibration file (expected a mapping with K1 D1 K2 D2 R T)")
    out = {}
    for k, v in data.items():
        if isinstance(v, dict) and "data" in v and "rows" in v and "cols" in v:  # opencv-matrix written by hand
            v = np.asarray(v["data"], dtype=np.float64).reshape(int(v["rows"]), int(v["cols"]))
        out[str(k)] = v
    return out


def _sniff(path: Path) -> str:
    try:
        head = path.read_bytes()[:4096].decode("utf-8", errors="replace").lstrip("\ufeff \t\r\n")
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from None
    if not head:
        raise InputError(f"{path}: the calibration file is empty")
    if head.startswith("<?xml") or head.startswith("<opencv_storage"):
        return "filestorage"
    if head.startswith("%YAML"):
        return "filestorage"
    if head.startswith("[") and re.search(r"^\s*\[(LEFT_CAM_|RIGHT_CAM_|STEREO)", head, re.M | re.I):
        return "zed"
    if path.suffix.lower() == ".conf":
        return "zed"
    return "yaml"


def rig_from_mapping(data: dict[str, Any], path: Path | str, image_size: tuple[int, int] | None = None) -> StereoRig:
    """Build a rig from a parsed file's key -> value mapping (OpenCV names); errors name the missing key."""
    lower = {k.lower(): k for k in data}
    vals: dict[str, np.ndarray] = {}
    for name, aliases in _MATRIX_KEYS.items():
        key = next((lower[a.lower()] for a in aliases if a.lower() in lower and data[lower[a.lower()]] is not None), None)
        if key is None:
            alt = f" (or {aliases[1]})" if len(aliases) > 1 else ""
            raise InputError(f"{path}: calibration is missing the key '{name}'{alt}")
        try:
            vals[name] = np.asarray(data[key], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{path}: '{key}' is not a numeric matrix") from None
    size = None
    if "image_width" in lower and "image_height" in lower:
        size = (data[lower["image_width"]], data[lower["image_height"]])
    else:
        for k in ("image_size", "imagesize", "image_size_wh"):
            if k in lower and data[lower[k]] is not None:
                s = np.asarray(data[lower[k]]).reshape(-1)
                if s.size == 2:
                    size = (s[0], s[1])
                break
    if size is None:
        if image_size is None:
            raise InputError(f"{path}: calibration is missing the keys 'image_width'/'image_height' (the eye size it is for)")
        size = image_size
        log.info("%s: no image size in the file; assuming the frames' %dx%d", path, *image_size)
    try:
        size = (int(size[0]), int(size[1]))
    except (TypeError, ValueError):
        raise InputError(f"{path}: image_width/image_height are not integers") from None
    rectified = bool(data.get(lower.get("rectified", "rectified"), 0) or 0)
    meta = data.get(lower.get("metadata", "metadata")) or {}
    if not isinstance(meta, dict):
        meta = {"metadata": meta}
    meta = dict(meta)
    meta.setdefault("source", str(path))
    try:
        rig = StereoRig(K1=vals["K1"], D1=vals["D1"].reshape(-1), K2=vals["K2"], D2=vals["D2"].reshape(-1),
                        R=vals["R"], T=vals["T"].reshape(-1), image_size=size, rectified=rectified, metadata=meta)
    except InputError as err:
        raise InputError(f"{path}: {str(err).removeprefix('rig: ')}") from None
    if image_size is not None and tuple(image_size) != rig.image_size:
        try:
            rig = rig.scaled(image_size)
        except InputError as err:
            raise InputError(f"{path}: {err}") from None
        log.warning("%s: calibration for %dx%d scaled to %dx%d frames", path, *size, *image_size)
    return rig


def load_rig(path: str | os.PathLike, image_size: tuple[int, int] | None = None) -> StereoRig:
    """Load a rig from a ZED ``.conf``, the project's rig YAML, or OpenCV FileStorage YAML/XML.

    image_size: (width, height) of one eye of the frames it will be used on. For a .conf it picks
    the section; for other files a different size of the same aspect returns ``rig.scaled(image_size)``
    and a different aspect raises InputError.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: calibration file not found")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a calibration file (.conf, .yaml, .xml)")
    kind = _sniff(path)
    if kind == "zed":
        return read_zed_conf(path, image_size=image_size)
    if kind == "filestorage" or path.suffix.lower() == ".xml":
        data = _read_filestorage(path)
    else:
        try:
            data = _read_filestorage(path)
        except InputError:
            data = _read_plain_yaml(path)
    return rig_from_mapping(data, path, image_size)


def parse_calib_arg(text: str, image_size: tuple[int, int] | None = None) -> StereoRig:
    """Interpret a ``--calib`` value: a ZED .conf, a rig YAML/XML, or inline rectified parameters
    ``fx,fy,cx,cy,baseline_m[,width,height]`` (px, px, px, px, metres, px, px) for frames that are
    already rectified. image_size: the frames' eye size (width, height), if known.
    """
    text = str(text).strip()
    if _INLINE_RE.match(text):
        nums = [float(v) for v in text.split(",")]
        if len(nums) not in (5, 7):
            raise InputError(f"--calib {text}: expected fx,fy,cx,cy,baseline_m[,width,height] (5 or 7 numbers), got {len(nums)}")
        fx, fy, cx, cy, b = nums[:5]
        if fx <= 0 or fy <= 0:
            raise InputError(f"--calib {text}: fx and fy must be > 0")
        if b <= 0:
            raise InputError(f"--calib {text}: baseline_m must be > 0 (metres)")
        if len(nums) == 7:
            size = (int(round(nums[5])), int(round(nums[6])))
        elif image_size is not None:
            size = (int(image_size[0]), int(image_size[1]))
        else:
            raise InputError(f"--calib {text}: add the eye size: fx,fy,cx,cy,baseline_m,width,height")
        rig = StereoRig.from_rectified(fx, fy, cx, cy, b, size, source=f"--calib {text}")
        if image_size is not None and tuple(image_size) != rig.image_size:
            rig = rig.scaled(image_size)
        return rig
    if not text:
        raise InputError("--calib: empty value")
    p = Path(text).expanduser()
    if not p.exists():
        raise InputError(f"--calib {text}: file not found (expected a ZED .conf, a rig .yaml/.xml, or "
                         "fx,fy,cx,cy,baseline_m[,width,height] for already-rectified frames)")
    return load_rig(p, image_size=image_size)
