"""Optional GPU path: batched rectification (remap) and depth back-projection with torch.

Installed with the ``[gpu]`` extra (kornia, torch). Nothing here imports torch at module import
time, so the CPU install never loads it; ``cuda_available()`` is the guard the CLI uses.

Rectification samples the same ``cv2.initUndistortRectifyMap`` tables as the CPU path, with
exact bilinear interpolation (``grid_sample``, align_corners=True maps pixel centres i -> i), so
sample positions agree with the maps to float32 precision; OpenCV's remap quantises positions
to 1/32 px, which bounds the CPU/GPU difference in position to 1/64 px on average.
"""

from __future__ import annotations

import importlib.util
import logging

import numpy as np

from stereo_recon.core.errors import ConfigError

log = logging.getLogger(__name__)


def torch_available() -> bool:
    """True when torch can be imported (without importing it)."""
    return importlib.util.find_spec("torch") is not None


def cuda_available() -> bool:
    """True when torch is installed and sees a CUDA device."""
    if not torch_available():
        return False
    import torch

    return bool(torch.cuda.is_available())


def _torch():
    if not torch_available():
        raise ConfigError("GPU path: torch is not installed (pip install 'stereo-recon[gpu]')")
    import torch

    return torch


def _normalised_grid(map_x: np.ndarray, map_y: np.ndarray, device, src_size: tuple[int, int] | None = None):
    """cv2 remap tables (H, W) float32 px -> grid_sample grid (1, H, W, 2) in [-1, 1] (align_corners=True).

    src_size: (width, height) of the images sampled from; default the maps' own size.
    """
    torch = _torch()
    w, h = src_size if src_size is not None else (map_x.shape[1], map_x.shape[0])
    mx = torch.as_tensor(np.asarray(map_x, np.float32), device=device)
    my = torch.as_tensor(np.asarray(map_y, np.float32), device=device)
    gx = 2.0 * mx / (w - 1) - 1.0
    gy = 2.0 * my / (h - 1) - 1.0
    return torch.stack([gx, gy], dim=-1)[None]


def remap_batch(images, map_x: np.ndarray, map_y: np.ndarray, device: str = "cuda"):
    """Bilinear remap of a batch, as ``cv2.remap(img, map_x, map_y, INTER_LINEAR)`` with zero borders.

    images: (B, H, W) or (B, H, W, C) numpy array or torch tensor (any dtype; computed in float32).
    map_x, map_y: (H, W) float32 source coordinates in px (``cv2.initUndistortRectifyMap`` with CV_32FC1).
    Returns a float32 torch tensor on ``device`` with the input's layout.
    """
    torch = _torch()
    x = torch.as_tensor(images, device=device).float()
    squeeze = x.ndim == 3
    if squeeze:
        x = x[..., None]
    b = x.shape[0]
    grid = _normalised_grid(map_x, map_y, x.device, (x.shape[2], x.shape[1])).expand(b, -1, -1, -1)
    out = torch.nn.functional.grid_sample(x.permute(0, 3, 1, 2), grid, mode="bilinear", padding_mode="zeros",
                                          align_corners=True).permute(0, 2, 3, 1)
    return out[..., 0] if squeeze else out


def backproject_batch(depth_m, K: np.ndarray, device: str = "cuda"):
    """Camera-frame 3-D points (B, H, W, 3) m from depth maps (B, H, W) m and pinhole K (3, 3) px.

    X = (u - cx) Z / fx, Y = (v - cy) Z / fy (OpenCV camera frame); NaN depth gives NaN points.
    """
    torch = _torch()
    z = torch.as_tensor(depth_m, device=device).double()
    _, h, w = z.shape
    v, u = torch.meshgrid(torch.arange(h, device=z.device, dtype=z.dtype),
                          torch.arange(w, device=z.device, dtype=z.dtype), indexing="ij")
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    return torch.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], dim=-1)


def backproject_cpu(depth_m: np.ndarray, K: np.ndarray) -> np.ndarray:
    """The numpy reference of ``backproject_batch`` for one (H, W) depth map -> (H, W, 3)."""
    h, w = depth_m.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = depth_m.astype(np.float64)
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)


class GpuRectifier:
    """Rectification of stereo pairs on a CUDA device with a rig's float remap tables."""

    def __init__(self, rect, device: str = "cuda"):
        if not cuda_available():
            raise ConfigError("--gpu: torch with a CUDA device is not available (install the [gpu] extra)")
        import cv2

        self.device = device
        self.rect = rect
        maps = []
        for m in (rect.map_left, rect.map_right):
            m1, m2 = m
            if m2 is not None and m2.size and m1.dtype != np.float32:
                m1, m2 = cv2.convertMaps(m1, m2, cv2.CV_32FC1)
            maps.append((m1, m2))
        self._grids = [_normalised_grid(mx, my, device) for mx, my in maps]

    def rectify_batch(self, lefts: np.ndarray, rights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B, H, W[, C]) uint8 raw left and right batches -> rectified batches of the same shapes."""
        torch = _torch()
        out = []
        for imgs, grid in ((lefts, self._grids[0]), (rights, self._grids[1])):
            x = torch.as_tensor(np.ascontiguousarray(imgs), device=self.device).float()
            grey = x.ndim == 3
            if grey:
                x = x[..., None]
            y = torch.nn.functional.grid_sample(x.permute(0, 3, 1, 2), grid.expand(x.shape[0], -1, -1, -1),
                                                mode="bilinear", padding_mode="zeros", align_corners=True)
            y = y.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1)
            out.append((y[..., 0] if grey else y).cpu().numpy())
        return out[0], out[1]

    def rectify_pair(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One raw pair ((H, W) or (H, W, C) uint8 each) -> rectified pair."""
        lb, rb = self.rectify_batch(left[None], right[None])
        return lb[0], rb[0]
