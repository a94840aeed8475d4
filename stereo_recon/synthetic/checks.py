"""Self-checks of the synthetic camera: a fronto-parallel plane must show disparity f*B/Z after rectification.

Used by the tests and by ``benchmarks/bench_synth.py`` (which prints the figures).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np

from stereo_recon.synthetic.mesh import quad
from stereo_recon.synthetic.scene import Scene
from stereo_recon.synthetic.texture import Material


def plane_scene(rect_R1: np.ndarray, Z: float) -> Scene:
    """A large textured quad fronto-parallel to the RECTIFIED left camera at depth ``Z`` (m).

    World frame = the raw left camera frame; ``rect_R1`` rotates raw-left into rectified-left
    coordinates (X_rect = R1 X_left), so the quad's corners are R1^T [x, y, Z].
    """
    s = 4 * Z
    corners_rect = np.array([[-s, -s, Z], [s, -s, Z], [s, s, Z], [-s, s, Z]])
    mat = Material("ground", (0.6, 0.55, 0.5), 0.35, 0.0025, 0.4)
    return Scene(mesh=quad(corners_rect @ rect_R1, "ground"), materials={"ground": mat}, sun_dir=np.array([0.0, 0.0, -1.0]), scale_m=1.0)


def window_shifts(gl: np.ndarray, gr: np.ndarray, d0: float, win: int = 48) -> np.ndarray:
    """Per-window sub-pixel (disparity, row offset) between rectified grey images, px.

    SSD scans with bicubic resampling of the right image (0.1 px steps within +-1 px of ``d0``)
    and parabola fits; gains are equalised first. gl, gr: (H, W) float32. Returns (n_windows, 2).
    """
    h, w = gl.shape
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    gr = gr * (gl.mean() / gr.mean())
    blocks = [(y, x) for y in range(30, h - 30 - win, win) for x in range(int(d0) + 30, w - 30 - win, win)]

    def scan(values, dx_of, dy_of):
        cost = np.empty((len(values), len(blocks)))
        for k, val in enumerate(values):
            warped = cv2.remap(gr, xs - np.float32(dx_of(val)), ys + np.float32(dy_of(val)), cv2.INTER_CUBIC)
            e = (warped - gl) ** 2
            cost[k] = [e[y:y + win, x:x + win].mean() for y, x in blocks]
        i = np.clip(np.argmin(cost, axis=0), 1, len(values) - 2)
        c0, c1, c2 = (cost[i + j, np.arange(len(blocks))] for j in (-1, 0, 1))
        step = values[1] - values[0]
        # Parabola vertex; clamped to one step (a minimum at the scan's edge means 'out of range').
        return values[i] + step * np.clip(0.5 * (c0 - c2) / np.maximum(c0 - 2 * c1 + c2, 1e-12), -1.0, 1.0)

    dy = scan(np.arange(-1.0, 1.01, 0.1), lambda v: d0, lambda v: v)
    dy_med = float(np.median(dy))
    d = scan(d0 + np.arange(-1.0, 1.01, 0.1), lambda v: v, lambda v: dy_med)
    return np.c_[d, dy]


def plane_disparity_check(resolution: str = "VGA", rectified: bool = False, Z_m: float = 1.5, noise_sigma_dn: float = 1.5,
                          work_dir: str | Path | None = None, rectify: bool = True) -> dict:
    """Render a fronto-parallel plane, rectify with the calibration AS WRITTEN (the .conf in raw mode,
    the rig YAML in rectified mode), and measure disparity and row offsets against f*B/Z.

    rectify=False skips rectification (shows what an unrectified raw pair would give).
    Returns expected_px, median_err_px, p90_abs_err_px, p90_abs_row_px, windows.
    """
    from calib.io import load_rig, save_rig, write_zed_conf
    from calib.rig import rectify_pair

    from stereo_recon.synthetic.camera import zed2_rig
    from stereo_recon.synthetic.render import RenderConfig, StereoRenderer

    rig = zed2_rig(resolution, rectified=rectified)
    with tempfile.TemporaryDirectory(dir=work_dir) as tmp:
        if rectified:
            loaded = load_rig(save_rig(rig, Path(tmp) / "rig.yaml"))
        else:
            loaded = load_rig(write_zed_conf(rig, Path(tmp) / "SN1.conf", serial=1), image_size=rig.image_size)
    rect = loaded.rectification()
    with StereoRenderer(plane_scene(rect.R1, Z_m), rig, RenderConfig(noise_sigma_dn=noise_sigma_dn, shadows=False)) as r:
        pair = r.render(np.eye(4), rng=0)
    left, right = rectify_pair(pair.left, pair.right, rect) if rectify else (pair.left, pair.right)
    gl = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY).astype(np.float32)
    gr = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY).astype(np.float32)
    d_expected = rect.focal_px * rect.baseline_m / Z_m
    s = window_shifts(gl, gr, d_expected)
    return {"expected_px": float(d_expected), "median_err_px": float(np.median(s[:, 0]) - d_expected),
            "p90_abs_err_px": float(np.percentile(np.abs(s[:, 0] - d_expected), 90)),
            "p90_abs_row_px": float(np.percentile(np.abs(s[:, 1]), 90)), "windows": int(len(s))}
