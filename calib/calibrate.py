"""Stereo calibration from board views: frame sources, frame selection, calibration, report, coverage image.

Steps (``calibrate_stereo``): each eye alone (``cv2.calibrateCamera``), then the pair
(``cv2.stereoCalibrateExtended`` starting from those intrinsics and refining them), then views whose
reprojection error stands out are dropped and the pair is solved again. Quality figures: RMS
reprojection error per eye and for the pair, per-view errors, and the rectified epipolar error
(|y_left - y_right| of the board corners after rectification).
"""

from __future__ import annotations

import logging
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from calib.boards import BoardSpec, DetectConfig, Detection, detect_board, reverse_if_flipped
from calib.rig import StereoRig
from stereo_recon.core.errors import InputError
from stereo_recon.core.frames import split_side_by_side

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm")


@dataclass(frozen=True)
class CalibConfig:
    """Settings of ``stereo-recon calibrate``."""

    max_frames: int = 40            # at most this many board views are calibrated on
    min_views: int = 6              # fewer usable views: refuse (too little to constrain 2 x 9 intrinsics + pose)
    scan_frames: int = 600          # a video is sampled at most this often when looking for the board
    scan_width_px: int = 640        # quick board search on eyes downscaled to this width
    blur_ratio: float = 0.35        # views sharper than this fraction of the median candidate are kept
    outlier_factor: float = 3.0     # a view is an outlier when its RMS > factor * median view RMS ...
    outlier_floor_px: float = 1.0   # ... and above this floor (px); good views are never dropped
    outlier_rounds: int = 3         # re-solve at most this many times after dropping outliers
    refine_intrinsics: bool = True  # the pair solve refines per-eye intrinsics (CALIB_USE_INTRINSIC_GUESS)
    rational_model: bool = False    # 8-coefficient distortion (only for strong wide-angle lenses)
    detect: DetectConfig = field(default_factory=DetectConfig)


@dataclass(frozen=True)
class PairView:
    """One stereo view of the board."""

    name: str                 # file name or "frame 123"
    left: Detection
    right: Detection
    sharpness: float = float("nan")   # Laplacian variance inside the board (left eye)


# -- sources -------------------------------------------------------------------------------------------
def _natural_key(s: str) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", s)]


def find_image_pairs(folder: Path) -> list[tuple[str, Path, Path | None]]:
    """Pairs ``(name, left, right)`` in a folder: ``left01.jpg``/``right01.jpg`` (also ``left_1``, ``L1``/``R1``),
    ``left/`` and ``right/`` subfolders with the same file names, or side-by-side images (right is None)."""
    folder = Path(folder)
    if (folder / "left").is_dir() and (folder / "right").is_dir():
        lefts = {p.name: p for p in (folder / "left").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
        rights = {p.name: p for p in (folder / "right").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
        common = sorted(set(lefts) & set(rights), key=_natural_key)
        if not common and len(lefts) == len(rights) and lefts:
            # different names, same count: pair in sorted order
            return [(f"{a}|{b}", lefts[a], rights[b]) for a, b in zip(sorted(lefts, key=_natural_key), sorted(rights, key=_natural_key))]
        missing = sorted(set(lefts) ^ set(rights))
        if missing:
            log.warning("%s: %d images without a partner in the other eye's folder (e.g. %s)", folder, len(missing), missing[0])
        return [(n, lefts[n], rights[n]) for n in common]
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    pat = re.compile(r"^(?:(left|right)[_\-. ]?(.*)|(l|r)[_\-. ]?(\d.*))$", re.I)
    lefts, rights, others = {}, {}, []
    for p in files:
        m = pat.match(p.stem)
        if m:
            side = (m.group(1) or m.group(3)).lower()[0]
            key = ((m.group(2) if m.group(1) else m.group(4)).lower(), p.suffix.lower())
            (lefts if side == "l" else rights)[key] = p
        else:
            others.append(p)
    pairs = [(lefts[k].name, lefts[k], rights[k]) for k in sorted(set(lefts) & set(rights), key=lambda k: _natural_key(k[0]))]
    unpaired = sorted(set(lefts) ^ set(rights))
    if pairs:
        if unpaired:
            log.warning("%s: %d left/right images without a partner (ignored)", folder, len(unpaired))
        return pairs
    # otherwise: side-by-side images
    return [(p.name, p, None) for p in sorted(others, key=lambda p: _natural_key(p.name))]


def read_image(path: Path) -> np.ndarray:
    """One calibration image as uint8 (deeper images are scaled to 0-255); InputError naming an unreadable file."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"{path}: cannot be read as an image")
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(1, int(img.max())))
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


def iter_folder_pairs(folder: Path, max_pairs: int | None = None) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """Yield ``(name, left, right)`` images of a folder (see ``find_image_pairs``); eyes must match in size.

    max_pairs: read only this many pairs, spread evenly over the folder's sorted list.
    """
    pairs = find_image_pairs(folder)
    if max_pairs is not None and len(pairs) > max_pairs:
        pairs = [pairs[i] for i in sorted(set(np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int).tolist()))]
    if not pairs:
        raise InputError(f"{folder}: no images found (expected left01.jpg/right01.jpg pairs, left/ and right/ "
                         "subfolders, or side-by-side images)")
    size = None
    for name, lp, rp in pairs:
        if rp is None:
            left, right = split_side_by_side(read_image(lp), str(lp), check_aspect=False)
        else:
            left, right = read_image(lp), read_image(rp)
            if left.shape[:2] != right.shape[:2]:
                raise InputError(f"{folder}: eyes of different sizes: {lp.name} is {left.shape[1]}x{left.shape[0]} "
                                 f"but {rp.name} is {right.shape[1]}x{right.shape[0]}")
        s = (left.shape[1], left.shape[0])
        if size is None:
            size = s
        elif s != size:
            raise InputError(f"{folder}: {name} is {s[0]}x{s[1]} but earlier images are {size[0]}x{size[1]}")
        yield name, left, right


def video_info(path: Path) -> tuple[int, tuple[int, int], float]:
    """(frame count, eye size (w, h), fps) of a side-by-side video."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(f"{path}: cannot open as a video")
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    cap.release()
    if w <= 0 or h <= 0:
        raise InputError(f"{path}: video has no frames")
    if w % 2:
        raise InputError(f"{path}: a side-by-side video must have an even width, got {w}")
    return n, (w // 2, h), fps


def iter_video_pairs(path: Path, stride: int = 1, indices: set[int] | None = None) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Yield ``(index, left, right)`` for every ``stride``-th frame (or only ``indices``) of a side-by-side video."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(f"{path}: cannot open as a video")
    last = max(indices) if indices else None
    i = 0
    try:
        while True:
            want = (i in indices) if indices is not None else (i % stride == 0)
            if want:
                ok, frame = cap.read()
                if not ok:
                    break
                left, right = split_side_by_side(frame, str(path), check_aspect=False)
                yield i, left, right
            elif not cap.grab():
                break
            i += 1
            if last is not None and i > last:
                break
    finally:
        cap.release()


# -- frame selection ----------------------------------------------------------------------------------
def _gray(img: np.ndarray) -> np.ndarray:
    import cv2

    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def sharpness(gray: np.ndarray, corners: np.ndarray | None = None) -> float:
    """Variance of the Laplacian (inside the corners' bounding box when given): higher is sharper."""
    import cv2

    g = gray
    if corners is not None and len(corners):
        x0, y0 = np.floor(corners.min(0)).astype(int)
        x1, y1 = np.ceil(corners.max(0)).astype(int)
        g = gray[max(0, y0): max(y0 + 2, y1 + 1), max(0, x0): max(x0 + 2, x1 + 1)]
    return float(cv2.Laplacian(g, cv2.CV_64F).var())


def quick_board(gray: np.ndarray, spec: BoardSpec, width_px: int) -> np.ndarray | None:
    """Fast presence test on a downscaled image; corners (N,2) in full-resolution px or None."""
    import cv2

    s = min(1.0, width_px / gray.shape[1])
    small = gray if s == 1.0 else cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    if spec.kind == "charuco":
        det = cv2.aruco.ArucoDetector(spec.charuco_board().getDictionary())
        corners, ids, _ = det.detectMarkers(small)
        if ids is None or len(ids) < 2:
            return None
        pts = np.concatenate([c.reshape(-1, 2) for c in corners])
    else:
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        ok, c = cv2.findChessboardCorners(small, spec.inner_size, flags=flags)
        if not ok:
            return None
        pts = c.reshape(-1, 2)
    return ((pts + 0.5) / s - 0.5).astype(np.float32)


def pose_descriptor(corners: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Where and how the board appears: centre (x, y) / size, apparent size, and perspective tilt cues."""
    import cv2

    w, h = image_size
    c = corners.reshape(-1, 2)
    hull = cv2.convexHull(c.astype(np.float32)).reshape(-1, 2)
    area = max(float(cv2.contourArea(hull)), 1.0)
    centre = c.mean(0) / np.array([w, h])
    size = np.sqrt(area / (w * h))
    # tilt: the minimum-area rectangle's elongation and angle, and the hull's departure from a parallelogram
    (_, _), (rw, rh), ang = cv2.minAreaRect(hull.astype(np.float32))
    elong = np.log(max(rw, 1.0) / max(rh, 1.0))
    cov = np.cov((c - c.mean(0)).T)
    evals, evecs = np.linalg.eigh(cov)
    ecc = np.log(max(evals[1], 1e-9) / max(evals[0], 1e-9))
    a = np.arctan2(evecs[1, 1], evecs[0, 1])
    return np.array([centre[0], centre[1], 2.0 * size, 0.3 * ecc * np.cos(2 * a), 0.3 * ecc * np.sin(2 * a), 0.1 * elong])


def select_views(descriptors: np.ndarray, sharp: np.ndarray, max_views: int, blur_ratio: float) -> list[int]:
    """Indices of at most ``max_views`` sharp views spread over the image and over board poses.

    Views blurrier than ``blur_ratio`` x the median are dropped (motion blur); then farthest-point
    sampling in descriptor space, starting from the sharpest view.
    """
    n = len(descriptors)
    if n == 0:
        return []
    sharp = np.asarray(sharp, dtype=np.float64)
    ok = np.flatnonzero(sharp >= blur_ratio * np.median(sharp))
    if len(ok) <= max_views:
        return sorted(ok.tolist())
    X = descriptors[ok]
    chosen = [int(np.argmax(sharp[ok]))]
    dmin = np.linalg.norm(X - X[chosen[0]], axis=1)
    while len(chosen) < max_views:
        # prefer far-away views, slightly favouring sharper ones
        score = dmin * (0.75 + 0.25 * sharp[ok] / sharp[ok].max())
        j = int(np.argmax(score))
        if dmin[j] <= 0:
            break
        chosen.append(j)
        dmin = np.minimum(dmin, np.linalg.norm(X - X[j], axis=1))
    return sorted(ok[chosen].tolist())


# -- collecting views ---------------------------------------------------------------------------------
@dataclass
class CollectResult:
    views: list[PairView]
    image_size: tuple[int, int]
    looked_at: int                  # frames/pairs in which the board was searched
    found_both: int                 # ... found in both eyes
    notes: list[dict]               # per frame: why it was not used
    background: tuple[np.ndarray, np.ndarray] | None   # a (left, right) frame for the coverage image


def detect_pair(name: str, left: np.ndarray, right: np.ndarray, spec: BoardSpec, cfg: DetectConfig) -> tuple[PairView | None, str]:
    """Detect the board in both eyes of one pair: (PairView, "") or (None, why the pair is unusable)."""
    gl, gr = _gray(left), _gray(right)
    dl = detect_board(gl, spec, cfg)
    dr = detect_board(gr, spec, cfg)
    if dl is None and dr is None:
        return None, "board not found in either eye"
    if dl is None:
        return None, "board not found in the left eye"
    if dr is None:
        return None, "board not found in the right eye"
    dr = reverse_if_flipped(dl, dr, spec)
    if spec.kind == "charuco":
        common = np.intersect1d(dl.ids, dr.ids).size
        if common < 6:  # a pose and the pair geometry need a few corners seen by both eyes
            return None, f"only {common} board corners seen by both eyes"
    return PairView(name, dl, dr, sharpness(gl, dl.corners)), ""


def _thin_views(views: list[PairView], size, max_frames: int, notes: list[dict]) -> list[PairView]:
    """At most max_frames views, spread over board poses (the rest noted as not selected)."""
    if len(views) <= max_frames:
        return views
    desc = np.array([pose_descriptor(v.left.corners, size) for v in views])
    keep = set(select_views(desc, np.array([v.sharpness for v in views]), max_frames, 0.0))
    notes += [{"view": v.name, "used": False, "reason": "not selected (enough similar views)"}
              for k, v in enumerate(views) if k not in keep]
    return [v for k, v in enumerate(views) if k in keep]


def _collect_folder(source: Path, spec: BoardSpec, config: CalibConfig) -> CollectResult:
    """Board views of a folder of left/right pairs (every pair is detected accurately)."""
    notes: list[dict] = []
    views: list[PairView] = []
    background = None
    size = None
    looked = 0
    for name, left, right in iter_folder_pairs(source):
        looked += 1
        size = (left.shape[1], left.shape[0])
        if background is None:
            background = (left, right)
        v, why = detect_pair(name, left, right, spec, config.detect)
        if v is None:
            notes.append({"view": name, "used": False, "reason": why})
        else:
            views.append(v)
    found = len(views)
    views = _thin_views(views, size, config.max_frames, notes)
    return CollectResult(views, size, looked, found, notes, background)


def _scan_video(source: Path, spec: BoardSpec, config: CalibConfig, n: int, size) -> tuple[list, list, list, int, tuple]:
    """Frames of a side-by-side video with the board in both eyes by the quick detector.

    Returns (frame indices, pose descriptors, sharpness, frames looked at, first pair as background).
    A quick search on downscaled eyes; at full resolution again if that finds too few (small boards).
    """
    stride = max(1, int(np.ceil(n / config.scan_frames))) if n > 0 else 1
    widths = [config.scan_width_px] + ([size[0]] if size[0] > config.scan_width_px else [])
    background = None
    for width in widths:
        cand_idx, cand_desc, cand_sharp = [], [], []
        looked = 0
        t0 = time.perf_counter()
        for i, left, right in iter_video_pairs(source, stride=stride):
            looked += 1
            if (left.shape[1], left.shape[0]) != size:
                raise InputError(f"{source}: frame {i} has another size than the video header says")
            if background is None:
                background = (left, right)
            gl, gr = _gray(left), _gray(right)
            ql = quick_board(gl, spec, width)
            if ql is None:
                continue
            qr = quick_board(gr, spec, width)
            if qr is None:
                continue
            cand_idx.append(i)
            cand_desc.append(pose_descriptor(ql, size))
            cand_sharp.append(sharpness(gl, ql))
        log.info("%s: scanned %d frames (every %d-th, %d px wide) in %.1f s, board in both eyes in %d", source, looked,
                 stride, width, time.perf_counter() - t0, len(cand_idx))
        if len(cand_idx) >= config.min_views or looked == 0:
            break
    return cand_idx, cand_desc, cand_sharp, looked, background


def _collect_video(source: Path, spec: BoardSpec, config: CalibConfig) -> CollectResult:
    """Board views of a side-by-side video: scan quickly, choose sharp and varied frames, detect them accurately."""
    if not source.is_file():
        raise InputError(f"{source}: not found")
    notes: list[dict] = []
    views: list[PairView] = []
    n, size, fps = video_info(source)
    cand_idx, cand_desc, cand_sharp, looked, background = _scan_video(source, spec, config, n, size)
    if looked == 0:
        raise InputError(f"{source}: no frames could be decoded")
    found = len(cand_idx)
    if not cand_idx:
        return CollectResult([], size, looked, 0, notes, background)
    # pick more than needed: the accurate detector may still fail on some
    pick = select_views(np.array(cand_desc), np.array(cand_sharp), int(config.max_frames * 1.25) + 2, config.blur_ratio)
    chosen = {cand_idx[k] for k in pick}
    for k, i in enumerate(cand_idx):
        if i not in chosen:
            notes.append({"view": f"frame {i}", "used": False, "reason": "not selected (blurrier or similar to a chosen view)"})
    for i, left, right in iter_video_pairs(source, indices=chosen):
        v, why = detect_pair(f"frame {i}", left, right, spec, config.detect)
        if v is None:
            notes.append({"view": f"frame {i}", "used": False, "reason": why + " (accurate detector)"})
        else:
            views.append(v)
        if len(views) == 1:
            background = (left, right)
    views = _thin_views(views, size, config.max_frames, notes)
    return CollectResult(views, size, looked, found, notes, background)


def collect_views(source: Path, spec: BoardSpec, config: CalibConfig = CalibConfig()) -> CollectResult:
    """Detect the board in a folder of pairs or a side-by-side video, choosing video frames automatically."""
    source = Path(source)
    if source.is_dir():
        return _collect_folder(source, spec, config)
    return _collect_video(source, spec, config)


# -- calibration ----------------------------------------------------------------------------------------
@dataclass
class CalibrationResult:
    rig: StereoRig
    report: dict
    views: list[PairView]          # views used in the final solve
    rejected: list[tuple[PairView, str]]
    residuals: dict                # per used view: (left (N,2), right (N,2)) reprojection residuals px


def _stereo_points(view: PairView, spec: BoardSpec):
    obj = spec.object_points()
    if spec.kind == "chessboard":
        return obj, view.left.corners, view.right.corners
    common, il, ir = np.intersect1d(view.left.ids, view.right.ids, return_indices=True)
    return obj[common], view.left.corners[il], view.right.corners[ir]


def _mono_points(det: Detection, spec: BoardSpec):
    obj = spec.object_points()
    return obj[det.ids], det.corners


def _rms(res: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(res.reshape(-1, 2) ** 2, axis=1)))) if res.size else float("nan")


def _solve(views: list[PairView], spec: BoardSpec, size: tuple[int, int], config: CalibConfig):
    import cv2

    dist_flags = cv2.CALIB_RATIONAL_MODEL if config.rational_model else 0
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-10)
    mono = {}
    for eye in ("left", "right"):
        ops, ips = [], []
        for v in views:
            o, i = _mono_points(getattr(v, eye), spec)
            ops.append(o.reshape(-1, 1, 3).astype(np.float32))
            ips.append(i.reshape(-1, 1, 2).astype(np.float32))
        rms, K, D, _, _ = cv2.calibrateCamera(ops, ips, size, None, None, flags=dist_flags, criteria=crit)
        mono[eye] = (float(rms), K, D)
    ops, ipl, ipr = [], [], []
    for v in views:
        o, a, b = _stereo_points(v, spec)
        ops.append(o.reshape(-1, 1, 3).astype(np.float32))
        ipl.append(a.reshape(-1, 1, 2).astype(np.float32))
        ipr.append(b.reshape(-1, 1, 2).astype(np.float32))
    flags = dist_flags | (cv2.CALIB_USE_INTRINSIC_GUESS if config.refine_intrinsics else cv2.CALIB_FIX_INTRINSIC)
    K1, D1, K2, D2 = mono["left"][1].copy(), mono["left"][2].copy(), mono["right"][1].copy(), mono["right"][2].copy()
    R0, T0 = np.eye(3), np.zeros((3, 1))
    out = cv2.stereoCalibrateExtended(ops, ipl, ipr, K1, D1, K2, D2, size, R0, T0, flags=flags, criteria=crit)
    rms, K1, D1, K2, D2, R, T, E, F, rvecs, tvecs, per_view = out
    # residuals per view and eye, from the solved poses (left camera) and the rig
    res = []
    for o, a, b, rv, tv in zip(ops, ipl, ipr, rvecs, tvecs):
        pl = cv2.projectPoints(o, rv, tv, K1, D1)[0].reshape(-1, 2)
        Rl = cv2.Rodrigues(rv)[0]
        rv2 = cv2.Rodrigues(R @ Rl)[0]
        tv2 = R @ tv.reshape(3, 1) + T.reshape(3, 1)
        pr = cv2.projectPoints(o, rv2, tv2, K2, D2)[0].reshape(-1, 2)
        res.append((pl - a.reshape(-1, 2), pr - b.reshape(-1, 2)))
    n_dist = 8 if config.rational_model else 5  # OpenCV returns 14 slots; the rest are fixed at zero
    return float(rms), mono, (K1, D1.reshape(-1)[:n_dist], K2, D2.reshape(-1)[:n_dist], R, T.reshape(-1)), res


def epipolar_errors(rig: StereoRig, views: list[PairView], spec: BoardSpec) -> np.ndarray:
    """|y_left - y_right| px of every common board corner after rectification with ``rig``."""
    rect = rig.rectification()
    out = []
    for v in views:
        _, a, b = _stereo_points(v, spec)
        yl = rect.rectify_points(a, "left", rig)[:, 1]
        yr = rect.rectify_points(b, "right", rig)[:, 1]
        out.append(np.abs(yl - yr))
    return np.concatenate(out) if out else np.zeros(0)


def calibrate_stereo(views: list[PairView], spec: BoardSpec, image_size: tuple[int, int],
                     config: CalibConfig = CalibConfig(), source: str = "") -> CalibrationResult:
    """Calibrate a stereo rig from board views seen by both eyes; drop outlier views and re-solve.

    Returns the rig (T in the board's units, metres when SQUARE_M is in metres) and a report dict.
    """
    if len(views) < config.min_views:
        raise InputError(f"{source or 'calibrate'}: only {len(views)} usable views of the board in both eyes; "
                         f"calibration needs at least {config.min_views}")
    active = list(views)
    rejected: list[tuple[PairView, str]] = []
    rounds = []
    for rnd in range(config.outlier_rounds + 1):
        rms, mono, params, res = _solve(active, spec, image_size, config)
        view_rms = np.array([_rms(np.concatenate([a, b])) for a, b in res])
        med = float(np.median(view_rms))
        limit = max(config.outlier_factor * med, config.outlier_floor_px)
        rounds.append({"round": rnd, "views": len(active), "rms_px": rms, "median_view_rms_px": med, "limit_px": limit})
        bad = [k for k in np.argsort(-view_rms) if view_rms[k] > limit]
        if not bad or rnd == config.outlier_rounds or len(active) - 1 < config.min_views:
            break
        # drop the worst view only, then re-solve: one bad view inflates the others' errors
        k = int(bad[0])
        rejected.append((active[k], f"outlier: view RMS {view_rms[k]:.3f} px > {limit:.3f} px (3 x median)"))
        log.info("calibrate: dropping %s (view RMS %.3f px)", active[k].name, view_rms[k])
        active.pop(k)
    K1, D1, K2, D2, R, T = params
    rig = StereoRig(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T=T, image_size=image_size)
    rl = np.concatenate([a for a, _ in res])
    rr = np.concatenate([b for _, b in res])
    epi = epipolar_errors(rig, active, spec)
    rect = rig.rectification()
    per_view = []
    for v, (a, b) in zip(active, res):
        per_view.append({"view": v.name, "used": True, "left_rms_px": _rms(a), "right_rms_px": _rms(b),
                         "rms_px": _rms(np.concatenate([a, b])), "corners": int(len(a)),
                         "detector": f"{v.left.method}/{v.right.method}", "sharpness": v.sharpness})
    for v, why in rejected:
        per_view.append({"view": v.name, "used": False, "reason": why})
    cover = {eye: coverage_fraction([getattr(v, eye).corners for v in active], image_size) for eye in ("left", "right")}
    report = {
        "board": str(spec),
        "image_size": list(image_size),
        "views_used": len(active),
        "views_rejected": len(rejected),
        "rms_px": {"pair": rms, "left": _rms(rl), "right": _rms(rr),
                   "left_alone": mono["left"][0], "right_alone": mono["right"][0]},
        "epipolar_error_px": {"median": float(np.median(epi)), "p95": float(np.percentile(epi, 95)),
                              "max": float(epi.max()), "corners": int(epi.size)},
        "coverage_fraction": cover,  # share of an 8 x 6 grid over the image with corners in it, per eye
        "baseline": float(np.linalg.norm(T)),
        "baseline_units": "metres" if spec.square_m < 1.0 else "board units (SQUARE_M as given)",
        "rectified": {"focal_px": rect.focal_px, "cx_px": rect.cx_px, "cy_px": rect.cy_px,
                      "roi_left": list(rect.roi_left), "roi_right": list(rect.roi_right)},
        "solve_rounds": rounds,
        "per_view": per_view,
        "config": {"refine_intrinsics": config.refine_intrinsics, "rational_model": config.rational_model,
                   "outlier_factor": config.outlier_factor, "outlier_floor_px": config.outlier_floor_px},
    }
    meta = {"source": f"stereo-recon calibrate {source}".strip(), "board": str(spec), "rms_px": rms,
            "rms_left_px": report["rms_px"]["left"], "rms_right_px": report["rms_px"]["right"],
            "epipolar_median_px": report["epipolar_error_px"]["median"], "epipolar_p95_px": report["epipolar_error_px"]["p95"],
            "views": len(active), "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    rig = rig.replace(metadata=meta)
    residuals = {v.name: r for v, r in zip(active, res)}
    return CalibrationResult(rig, report, active, rejected, residuals)


# -- coverage image -----------------------------------------------------------------------------------
def coverage_fraction(corner_sets: list[np.ndarray], image_size: tuple[int, int], grid: tuple[int, int] = (8, 6)) -> float:
    """Fraction of the cells of a ``grid`` (cols, rows) over the image that hold at least one corner.

    Distortion is only well determined where corners were seen; edges and corners of the image matter most.
    """
    w, h = image_size
    hit = np.zeros((grid[1], grid[0]), bool)
    for c in corner_sets:
        c = np.asarray(c).reshape(-1, 2)
        ix = np.clip((c[:, 0] / w * grid[0]).astype(int), 0, grid[0] - 1)
        iy = np.clip((c[:, 1] / h * grid[1]).astype(int), 0, grid[1] - 1)
        hit[iy, ix] = True
    return float(hit.mean())


def coverage_image(result: CalibrationResult, spec: BoardSpec, background: tuple[np.ndarray, np.ndarray] | None = None,
                   max_width_px: int = 1600) -> np.ndarray:
    """BGR image: both eyes side by side, the used corners as dots (one colour per view), rejected views
    as red crosses, and the rectified valid regions; shows which parts of the image the calibration saw."""
    import cv2

    w, h = result.rig.image_size
    s = min(1.0, max_width_px / (2 * w))
    W, H = int(round(2 * w * s)), int(round(h * s))
    if background is not None:
        bgs = [cv2.resize(_gray(b), (int(round(w * s)), H)) for b in background]
        bgs = [(b.astype(np.float32) * 0.35 + 40).astype(np.uint8) for b in bgs]
        canvas = cv2.cvtColor(np.hstack(bgs), cv2.COLOR_GRAY2BGR)
    else:
        canvas = np.full((H, W, 3), 40, np.uint8)
    canvas = canvas[:, :W] if canvas.shape[1] >= W else cv2.resize(canvas, (W, H))
    off = int(round(w * s))
    n = max(1, len(result.views))
    for k, v in enumerate(result.views):
        hue = int(180 * k / n)
        col = cv2.cvtColor(np.uint8([[[hue, 220, 255]]]), cv2.COLOR_HSV2BGR)[0, 0].tolist()
        for det, dx in ((v.left, 0), (v.right, off)):
            pts = (det.corners + 0.5) * s - 0.5
            hull = cv2.convexHull(pts.astype(np.float32)).astype(np.int32)
            cv2.polylines(canvas, [hull + [dx, 0]], True, col, 1, cv2.LINE_AA)
            for x, y in pts:
                cv2.circle(canvas, (int(round(x + dx)), int(round(y))), max(1, int(2 * s + 0.5)), col, -1, cv2.LINE_AA)
    for v, _ in result.rejected:
        for det, dx in ((v.left, 0), (v.right, off)):
            for x, y in (det.corners + 0.5) * s - 0.5:
                cv2.drawMarker(canvas, (int(round(x + dx)), int(round(y))), (0, 0, 255), cv2.MARKER_TILTED_CROSS, 5, 1)
    rect = result.rig.rectification()
    for (x, y, rw, rh), dx in ((rect.roi_left, 0), (rect.roi_right, off)):
        cv2.rectangle(canvas, (int(x * s) + dx, int(y * s)), (int((x + rw) * s) + dx - 1, int((y + rh) * s) - 1), (255, 255, 255), 1)
    cv2.line(canvas, (off, 0), (off, H - 1), (200, 200, 200), 1)
    rep = result.report
    txt = (f"{len(result.views)} views, RMS {rep['rms_px']['pair']:.3f} px, epipolar median "
           f"{rep['epipolar_error_px']['median']:.3f} px")
    cv2.putText(canvas, "left", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.putText(canvas, "right", (off + 8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.putText(canvas, txt, (8, H - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas


# -- whole command ------------------------------------------------------------------------------------
def calibrate_source(source: str | os.PathLike, spec: BoardSpec, config: CalibConfig = CalibConfig()) -> tuple[CalibrationResult, CollectResult]:
    """Find board views in a video/folder and calibrate; InputError when the board is missing or too rare."""
    source = Path(source)
    col = collect_views(source, spec, config)
    if col.found_both == 0:
        kind = "pairs" if source.is_dir() else "frames"
        hint = " (COLSxROWS counts inner corners)" if spec.kind == "chessboard" else ""
        raise InputError(f"{source}: no {spec} board found in both eyes in any of the {col.looked_at} {kind} looked at"
                         f"{hint}")
    if len(col.views) < config.min_views:
        raise InputError(f"{source}: the board was usable in both eyes in only {len(col.views)} of {col.looked_at} "
                         f"{'pairs' if source.is_dir() else 'frames looked at'}; calibration needs at least {config.min_views}")
    result = calibrate_stereo(col.views, spec, col.image_size, config, source=str(source))
    result.report["source"] = str(source)
    result.report["looked_at"] = col.looked_at
    result.report["found_in_both_eyes"] = col.found_both
    result.report["per_view"].extend(col.notes)
    return result, col
