"""Evaluation helpers: the Middlebury 2014 stereo benchmark's files (PFM, ``calib.txt``) and its bad-pixel rate.

Used by the tests and ``benchmarks/bench_depth.py`` to score :mod:`stereo_recon.disparity`; nothing in the
pipeline reads these files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereo_recon.core.errors import InputError


def read_pfm(path: str | Path) -> np.ndarray:
    """Read a PFM image (float32, rows top-to-bottom; inf marks unknown in Middlebury GT)."""
    path = Path(path)
    with open(path, "rb") as f:
        kind = f.readline().strip()
        if kind not in (b"Pf", b"PF"):
            raise InputError(f"{path}: not a PFM file (header {kind!r})")
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        ch = 3 if kind == b"PF" else 1
        data = np.frombuffer(f.read(w * h * ch * 4), dtype="<f4" if scale < 0 else ">f4")
    if data.size != w * h * ch:
        raise InputError(f"{path}: truncated PFM ({data.size} of {w * h * ch} values)")
    img = data.reshape(h, w, ch) if ch == 3 else data.reshape(h, w)
    return np.flipud(img).astype(np.float32)  # PFM stores rows bottom-to-top


def read_middlebury_calib(path: str | Path) -> dict[str, str]:
    """Parse a Middlebury ``calib.txt`` into {key: value string} (whitespace around '=' tolerated)."""
    out = {}
    for line in Path(path).read_text().splitlines():
        if "=" in line:
            k, v = line.split("=", 1)
            out[k.strip()] = v.strip()
    return out


@dataclass(frozen=True)
class MiddleburyPair:
    """A Middlebury 2014 scene: images (BGR), GT disparity (NaN unknown), non-occluded mask, ndisp."""

    name: str
    left: np.ndarray
    right: np.ndarray
    gt_disp_px: np.ndarray
    nonocc_mask: np.ndarray
    ndisp: int
    focal_px: float
    baseline_m: float


def load_middlebury_2014(scene_dir: str | Path) -> MiddleburyPair:
    """Load ``im0.png``, ``im1.png``, ``disp0GT.pfm``, ``mask0nocc.png`` and ``calib.txt`` of one scene."""
    import cv2

    d = Path(scene_dir)
    cal = read_middlebury_calib(d / "calib.txt")
    left = cv2.imread(str(d / "im0.png"), cv2.IMREAD_COLOR)
    right = cv2.imread(str(d / "im1.png"), cv2.IMREAD_COLOR)
    mask = cv2.imread(str(d / "mask0nocc.png"), cv2.IMREAD_GRAYSCALE)
    if left is None or right is None or mask is None:
        raise InputError(f"{d}: missing or unreadable im0.png / im1.png / mask0nocc.png")
    gt = read_pfm(d / "disp0GT.pfm")
    gt[~np.isfinite(gt)] = np.nan
    focal = float(cal["cam0"].strip("[]").split()[0])
    return MiddleburyPair(d.name, left, right, gt, mask == 255, int(cal["ndisp"]), focal,
                          float(cal["baseline"]) / 1000.0)


def bad_pixel_rate(disp_px: np.ndarray, gt_disp_px: np.ndarray, mask: np.ndarray, threshold_px: float = 2.0) -> dict:
    """Middlebury bad-pixel rate: share of mask pixels with |d - gt| > threshold or no estimate.

    Returns {"bad_pct", "density_pct", "mae_px" (over valid estimates)}; holes count as bad.
    """
    m = np.asarray(mask, bool) & np.isfinite(gt_disp_px)
    est = np.asarray(disp_px, np.float32)[m]
    gt = gt_disp_px[m]
    valid = np.isfinite(est)
    err = np.abs(np.where(valid, est, 0.0) - gt)
    bad = ~valid | (err > threshold_px)
    return {"bad_pct": float(100.0 * bad.mean()), "density_pct": float(100.0 * valid.mean()),
            "mae_px": float(err[valid].mean()) if valid.any() else float("nan")}
