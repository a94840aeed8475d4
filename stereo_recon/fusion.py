"""Fusion stage: metric depth maps + world-from-camera poses -> TSDF volume -> coloured point cloud / mesh.

Uses Open3D's tensor ``VoxelBlockGrid`` (the legacy ``ScalableTSDFVolume`` returned no points
with Open3D 0.20; see NOTES). The grid's hash map has a fixed capacity and Open3D crashes when
an integration touches more blocks than it holds, so ``TSDFFusion`` counts the blocks each
frame touches *before* integrating, grows the map when needed and refuses clearly (StageError)
past a memory budget. Memory per block = block_resolution³ × 20 bytes (tsdf, weight, RGB float32).

Frames: camera frame OpenCV (x right, y down, z forward); ``T_wc`` world-from-camera, metres.
Open3D's ``extrinsic`` is camera-from-world, i.e. ``inv(T_wc)``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from stereo_recon.core.errors import ConfigError, InputError, StageError

log = logging.getLogger(__name__)

_BYTES_PER_VOXEL = 4 * (1 + 1 + 3)  # tsdf, weight, colour (float32)


@dataclass(frozen=True)
class FusionConfig:
    """Every parameter of the TSDF fusion."""

    # Voxel edge (m). None: derived from the first frame, voxel_footprint_px pixel footprints at its median depth.
    voxel_m: float | None = None
    # Derived voxel = this many pixel footprints (median depth / focal) - finer than 1-2 px only adds noise.
    voxel_footprint_px: float = 2.0
    # Bounds for the derived voxel (m).
    min_voxel_m: float = 0.002
    max_voxel_m: float = 0.25
    # SDF truncation distance in voxels (Open3D's default 8): thicker = more robust to depth noise, rounder edges.
    trunc_voxels: float = 8.0
    # Depth range integrated (m); farther depth is noisier (error grows with Z²) and costs blocks.
    depth_min_m: float = 0.3
    depth_max_m: float = math.inf   # no fixed cap: reconstruct derives one from the rig and the scene
    # Voxels per block edge. 8 rather than Open3D's 16: the truncation shell around a surface fills
    # small blocks better, so fewer idle voxels are updated (measured on the synthetic HD720 orbit:
    # 0.56 vs 0.98 CPU s per frame, half the memory).
    block_resolution: int = 8
    # Initial hash-map capacity in blocks; None = 4x the blocks the first frame touches.
    block_count: int | None = None
    # The grid grows up to this memory (GiB), then fusion stops with a StageError naming the remedy.
    max_memory_gib: float = 6.0
    # Extraction keeps voxels observed with at least this total weight (one frame = weight 1).
    min_weight: float = 3.0
    # Depth-edge filter (``depth_edge_mask``): pixels within edge_window_px // 2 of a depth step (second
    # difference along a row or column > edge_step_rel x depth; slopes pass) are not integrated
    # (None = off). Why: Open3D integrates a
    # voxel whenever its SDF is above -truncation and clamps large positive SDFs, so a depth that is too
    # FAR (background bleeding over a silhouette, hole filling, a mismatch) carves every voxel in front of
    # it, while a depth too NEAR is ignored behind the truncation band. That asymmetry moves surfaces
    # away from the cameras; most such outliers sit at depth edges.
    # Measured on the synthetic model-truck orbit (HD720, GT poses, 24 views): walls -5.7/-7.1 mm and roof
    # -6.5 mm without the filter; 0.1: -5.4/-6.2/-6.0; 0.05: -4.7/-4.5/-4.1 mm, but at VGA (1 % depth
    # noise per view) 0.05 drops a third of the surface, so the default stays at 0.1.
    edge_step_rel: float | None = 0.1
    edge_window_px: int = 5
    # Drop only the far side of a step (see ``depth_edge_mask``): the near side cannot carve the surface
    # behind it and holds thin parts. Measured (``stereo-recon bench --trucks 1-20``, VO): truck 12's
    # flatbed width -3.55 % -> -2.24 %, every dimension of the 20 trucks within 2.5 % (worst 2.44 %),
    # overall 0.70 % instead of 0.72 %; the 12 m truck W -0.97 % -> -0.94 %.
    edge_far_side_only: bool = True
    # Optional world-frame axis-aligned box (min xyz, max xyz) in m; depth outside it is not integrated.
    roi_min_m: tuple[float, float, float] | None = None
    roi_max_m: tuple[float, float, float] | None = None
    # Open3D device ("CPU:0", or "CUDA:0" with a CUDA build of Open3D).
    device: str = "CPU:0"

    def __post_init__(self) -> None:
        if self.voxel_m is not None and not self.voxel_m > 0:
            raise ConfigError(f"voxel_m={self.voxel_m}: must be > 0")
        if not 0 <= self.depth_min_m < self.depth_max_m:
            raise ConfigError(f"depth range [{self.depth_min_m}, {self.depth_max_m}] m is empty")
        if (self.roi_min_m is None) != (self.roi_max_m is None):
            raise ConfigError("roi_min_m and roi_max_m must be given together")
        if self.edge_step_rel is not None and not self.edge_step_rel > 0:
            raise ConfigError(f"edge_step_rel={self.edge_step_rel}: must be > 0 or None")
        if self.edge_window_px < 3 or self.edge_window_px % 2 == 0:
            raise ConfigError(f"edge_window_px={self.edge_window_px}: must be an odd number >= 3")
        if self.block_resolution not in (8, 16, 32):
            raise ConfigError(f"block_resolution={self.block_resolution}: must be 8, 16 or 32")


def voxel_size_from_depth(depth_m: np.ndarray, focal_px: float, footprint_px: float = 2.0,
                          min_voxel_m: float = 0.002, max_voxel_m: float = 0.25) -> float:
    """Voxel edge (m) = footprint_px × (median valid depth / focal_px), clipped to [min, max].

    depth_m: (H, W) metres, NaN/0 invalid; focal_px: focal length of the depth camera in px.
    """
    z = np.asarray(depth_m)
    z = z[np.isfinite(z) & (z > 0)]
    if z.size == 0:
        raise StageError("fusion", "cannot derive a voxel size: the first depth map has no valid pixel")
    v = footprint_px * float(np.median(z)) / float(focal_px)
    return float(min(max(v, min_voxel_m), max_voxel_m))


def depth_edge_mask(depth_m: np.ndarray, step_rel: float, window_px: int = 5, far_side_only: bool = False) -> np.ndarray:
    """Pixels near a depth discontinuity: (H, W) bool.

    A discontinuity is where the second difference of depth along a row or a column (three valid pixels)
    exceeds step_rel x the depth: a step, not a slope, so surfaces seen at grazing angles (large but
    linear depth changes) are kept. Every valid pixel within ``window_px // 2`` of one is flagged, which
    covers both sides of the step (background bleeding a few pixels over a silhouette); with
    ``far_side_only`` only those deeper than the nearest depth across the step by step_rel x depth.
    depth_m: (H, W) float metres, 0 = invalid.
    """
    import cv2

    z = np.asarray(depth_m, dtype=np.float32)
    valid = z > 0
    thr = np.float32(step_rel) * z
    step = np.zeros(z.shape, bool)
    ok = valid[:, :-2] & valid[:, 1:-1] & valid[:, 2:]
    step[:, 1:-1] |= ok & (np.abs(z[:, :-2] - 2 * z[:, 1:-1] + z[:, 2:]) > thr[:, 1:-1])
    ok = valid[:-2] & valid[1:-1] & valid[2:]
    step[1:-1] |= ok & (np.abs(z[:-2] - 2 * z[1:-1] + z[2:]) > thr[1:-1])
    r = max(int(window_px) // 2 - 1, 0)  # the second difference already marks one pixel on each side
    if r > 0:
        step = cv2.dilate(step.view(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)).view(bool)
    if far_side_only:
        # Keep the near side: a too-near depth lies behind the truncation band of the true surface and
        # changes nothing there, while a too-far one carves it; and the near side of a step is often a
        # thin part worth keeping (a flatbed deck's 15 mm edge face is ~3 px at the fusion resolution).
        k = 2 * r + 5  # reaches the nearest pixel across the step from any flagged pixel
        zmin = cv2.erode(np.where(valid, z, np.float32(np.inf)), np.ones((k, k), np.uint8))
        step &= z - zmin > thr
    return valid & step


def consistent_depth_mask(depth_m: np.ndarray, K: np.ndarray, T_wc: np.ndarray,
                          others: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                          rel_tol: float = 0.01, min_agree: int = 1, fb_px_m: float | None = None,
                          disparity_tol_px: float | None = None) -> np.ndarray:
    """Pixels of a depth map that other views confirm (the geometric consistency check of MVS fusion).

    depth_m: (H, W) z-depth in m of one view (NaN or 0 = invalid); K: (3, 3) its pinhole intrinsics
    (px, OpenCV centres); T_wc: (4, 4) its world-from-camera pose (m). others: (depth_m, K, T_wc) of
    other views, same conventions. A pixel's 3-D point agrees with another view when it projects
    inside it onto a valid depth within ``rel_tol`` x its depth there; points hidden or unseen there
    neither agree nor disagree. With fb_px_m (the rig's focal x baseline, px m) and disparity_tol_px, agreement
    is judged in disparity instead, within disparity_tol_px of fb / depth (as the rig measured it). Returns (H, W)
    bool: valid and agreed by at least ``min_agree`` views.

    Stereo on weakly textured panels interpolates, and what it interpolates differs from view to
    view (a truck side +1 cm from one view, -4 cm from another); averaging those in the TSDF moves
    the fused surface, while depths that several views reproduce are the ones worth fusing.
    """
    if (fb_px_m is None) != (disparity_tol_px is None):
        raise ValueError("consistent_depth_mask: give fb_px_m and disparity_tol_px together")
    z = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(z) & (z > 0)
    v, u = np.nonzero(valid)
    zz = z[v, u]
    pc = np.stack([(u - K[0, 2]) / K[0, 0] * zz, (v - K[1, 2]) / K[1, 1] * zz, zz], 1)
    pw = pc @ T_wc[:3, :3].T + T_wc[:3, 3]
    agree = np.zeros(len(zz), dtype=np.int32)
    for dj, Kj, Tj in others:
        dj = np.asarray(dj)
        hj, wj = dj.shape
        Rcw = Tj[:3, :3].T
        pj = (pw - Tj[:3, 3]) @ Rcw.T
        zj = pj[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uj = np.rint(Kj[0, 0] * pj[:, 0] / zj + Kj[0, 2])
            vj = np.rint(Kj[1, 1] * pj[:, 1] / zj + Kj[1, 2])
        inside = (zj > 0) & (uj >= 0) & (uj < wj) & (vj >= 0) & (vj < hj)
        idx = np.flatnonzero(inside)
        seen = dj[vj[idx].astype(np.intp), uj[idx].astype(np.intp)]
        if disparity_tol_px is None:
            ok = np.isfinite(seen) & (np.abs(seen - zj[idx]) <= rel_tol * zj[idx])
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                ok = np.abs(fb_px_m / seen.astype(np.float64) - fb_px_m / zj[idx]) <= disparity_tol_px
        agree[idx[ok]] += 1
    mask = np.zeros(z.shape, dtype=bool)
    mask[v, u] = agree >= min_agree
    return mask


def depth_agreement(T_wc: np.ndarray, depths_m: list, K: np.ndarray, fb_px_m: float, tol_px: float = 1.0,
                    step_px: int = 8) -> np.ndarray:
    """How well consecutive views' depth maps agree under the given poses: one fraction per consecutive pair.

    T_wc: (N, 4, 4) world-from-camera poses (m) of N views; depths_m: their N z-depth maps (H, W) in metres
    (NaN or <= 0 where invalid), each in its own camera; K (3, 3) px the cameras' intrinsics; fb_px_m: the rig's
    focal x baseline (px m), so that agreement is judged in disparity, as the rig measured it. For each pair
    (k, k+1), the valid pixels of view k on a grid of step_px are moved into view k+1 (``consistent_depth_mask``);
    the fraction of them that land inside view k+1 on a valid depth within tol_px of disparity of their own is
    returned ((N-1,)). Poses that put two views in the wrong place relative to each other move the points off
    their surfaces, out of the view, or behind it, and their pair's fraction drops towards 0 (issue 12,
    fifty-sixth round: a full-scale tanker whose odometry broke at four of its twelve pairs read 0.00 there and
    0.45-0.55 elsewhere).
    """
    K = np.asarray(K, np.float64)
    K_grid = K.copy()   # the grid's pixel (i, j) is the view's (i * step, j * step)
    K_grid[:2] /= step_px
    out = np.zeros(max(len(depths_m) - 1, 0))
    for k in range(len(out)):
        z = np.asarray(depths_m[k])[::step_px, ::step_px]
        n_valid = int((np.isfinite(z) & (z > 0)).sum())
        if n_valid:
            agreed = consistent_depth_mask(z, K_grid, T_wc[k], [(depths_m[k + 1], K, T_wc[k + 1])],
                                           fb_px_m=fb_px_m, disparity_tol_px=tol_px)
            out[k] = float(agreed.sum()) / n_valid
    return out


def pixel_centre_intrinsics(K: np.ndarray) -> np.ndarray:
    """Intrinsics to hand to Open3D's TSDF integration so that its truncating pixel lookup is a nearest-pixel one.

    K: (3, 3) OpenCV intrinsics (pixel centres at integer coordinates), px. Open3D reads the depth at
    ``(int(u), int(v))``; with cx, cy moved by +0.5 px, ``int(u + 0.5)`` is the pixel nearest to the
    voxel's true projection u. Returns a new (3, 3) float64 array.
    """
    Kc = np.array(K, dtype=np.float64, copy=True)
    Kc[0, 2] += 0.5
    Kc[1, 2] += 0.5
    return Kc


def _check_pose(T_wc: np.ndarray) -> np.ndarray:
    T = np.asarray(T_wc, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"fusion: pose must be a finite 4x4 matrix, got shape {T.shape}")
    return T


@dataclass
class FusionStats:
    """Counts for the run manifest."""

    frames_integrated: int = 0
    frames_skipped_empty: int = 0
    pixels_integrated: int = 0
    blocks_allocated: int = 0
    capacity_blocks: int = 0
    grow_events: int = 0
    voxel_m: float | None = None
    memory_gib: float = 0.0
    notes: list[str] = field(default_factory=list)


class TSDFFusion:
    """Incremental TSDF fusion of coloured depth frames into an Open3D ``VoxelBlockGrid``.

    Usage: ``f = TSDFFusion(cfg); f.integrate(bgr, depth_m, K, T_wc) ...; pts, rgb = f.extract_cloud()``.
    """

    def __init__(self, config: FusionConfig = FusionConfig()):
        self.config = config
        self.stats = FusionStats()
        self._vbg = None
        self._o3c = None
        self.voxel_m: float | None = config.voxel_m

    # -- grid management ----------------------------------------------------------------------
    @property
    def bytes_per_block(self) -> int:
        return self.config.block_resolution ** 3 * _BYTES_PER_VOXEL

    def _create(self, capacity: int) -> None:
        import open3d as o3d
        import open3d.core as o3c

        self._o3c = o3c
        cap_max = self._max_blocks()
        capacity = int(min(max(capacity, 16), cap_max))
        self._device = o3c.Device(self.config.device)
        self._vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=float(self.voxel_m),
            block_resolution=int(self.config.block_resolution),
            block_count=capacity,
            device=self._device,
        )
        self.stats.voxel_m = self.voxel_m
        log.info("TSDF grid: voxel %.4f m, block capacity %d (%.2f GiB)", self.voxel_m, capacity,
                 capacity * self.bytes_per_block / 2**30)

    def _max_blocks(self) -> int:
        return int(self.config.max_memory_gib * 2**30 // self.bytes_per_block)

    def _ensure_capacity(self, n_new: int) -> None:
        """Grow the hash map so that ``n_new`` more blocks fit (Open3D segfaults otherwise)."""
        hm = self._vbg.hashmap()
        size, cap = int(hm.size()), int(hm.capacity())
        if size + n_new <= cap:
            return
        need = size + n_new
        limit = self._max_blocks()
        if need > limit:
            raise StageError("fusion", f"the TSDF grid needs more than {limit} blocks ({self.config.max_memory_gib:g} GiB "
                                       f"at {self.voxel_m * 1000:.1f} mm voxels); use a larger --voxel-m, a smaller "
                                       "--depth-max-m or a region of interest")
        new_cap = int(min(max(2 * cap, need + need // 4), limit))
        hm.reserve(new_cap)
        self.stats.grow_events += 1
        log.info("TSDF grid grown to %d blocks (%.2f GiB)", new_cap, new_cap * self.bytes_per_block / 2**30)

    # -- integration --------------------------------------------------------------------------
    def _mask_depth(self, depth_m: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> np.ndarray:
        c = self.config
        z = np.array(depth_m, dtype=np.float32, copy=True)
        bad = ~np.isfinite(z) | (z < c.depth_min_m) | (z > c.depth_max_m)
        z[bad] = 0.0
        if c.edge_step_rel is not None:
            z[depth_edge_mask(z, c.edge_step_rel, c.edge_window_px, c.edge_far_side_only)] = 0.0
        if c.roi_min_m is not None:
            h, w = z.shape
            v, u = np.nonzero(z > 0)
            zz = z[v, u].astype(np.float64)
            x = (u - K[0, 2]) / K[0, 0] * zz
            y = (v - K[1, 2]) / K[1, 1] * zz
            pw = np.stack([x, y, zz], 1) @ T_wc[:3, :3].T + T_wc[:3, 3]
            inside = np.all((pw >= np.asarray(c.roi_min_m)) & (pw <= np.asarray(c.roi_max_m)), axis=1)
            z[v[~inside], u[~inside]] = 0.0
        return z

    def integrate(self, color_bgr: np.ndarray, depth_m: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> int:
        """Fuse one frame; returns the number of blocks it touched (0 if it has no valid depth).

        color_bgr: (H, W, 3) uint8 BGR image registered with the depth (the rectified left image).
        depth_m: (H, W) float metres, NaN/0 invalid. K: (3, 3) pinhole intrinsics of that camera, px.
        T_wc: (4, 4) world-from-camera pose, metres.
        """
        import open3d as o3d

        K = np.asarray(K, dtype=np.float64)
        T_wc = _check_pose(T_wc)
        if depth_m.shape[:2] != color_bgr.shape[:2]:
            raise InputError(f"fusion: depth {depth_m.shape[:2]} and colour {color_bgr.shape[:2]} differ in size")
        z = self._mask_depth(depth_m, K, T_wc)
        n_valid = int(np.count_nonzero(z))
        if n_valid == 0:
            self.stats.frames_skipped_empty += 1
            return 0
        if self._vbg is None:
            if self.voxel_m is None:
                self.voxel_m = voxel_size_from_depth(z[z > 0], K[0, 0], self.config.voxel_footprint_px,
                                                     self.config.min_voxel_m, self.config.max_voxel_m)
            self._create(self.config.block_count or 1024)
        o3c = self._o3c
        dev = self._device
        depth_img = o3d.t.geometry.Image(o3c.Tensor(z, device=dev))
        rgb = np.ascontiguousarray(color_bgr[..., ::-1], dtype=np.float32) / 255.0
        color_img = o3d.t.geometry.Image(o3c.Tensor(rgb, device=dev))
        intr = o3c.Tensor(K, dtype=o3c.float64)
        # Open3D's integration kernel looks a voxel's depth up at pixel (int(u), int(v)), i.e. it
        # truncates the projection, so pixel k serves u in [k, k+1) and acts as if its centre were
        # at k + 0.5 (OpenCV: at k). Projecting with the principal point moved by +0.5 px makes that
        # lookup the nearest pixel. Without it every surface moves by half a pixel footprint along
        # the image's x and y (synthetic model-truck orbit fused from exact depth at 640 px wide:
        # roof and ground 3.0 mm low before, 0.0 mm after).
        intr_lookup = o3c.Tensor(pixel_centre_intrinsics(K), dtype=o3c.float64)
        extr = o3c.Tensor(np.linalg.inv(T_wc), dtype=o3c.float64)  # Open3D extrinsic = camera-from-world
        # Open3D wants a finite limit; the masked depth holds nothing beyond the configured one.
        depth_max = float(min(self.config.depth_max_m, 1.001 * float(z.max())))
        blocks = self._vbg.compute_unique_block_coordinates(depth_img, intr, extr, 1.0, depth_max,
                                                            float(self.config.trunc_voxels))
        n_blocks = int(blocks.shape[0])
        if self.stats.frames_integrated == 0 and self.config.block_count is None:
            self._ensure_capacity(4 * n_blocks)
        self._ensure_capacity(n_blocks)  # upper bound of the new blocks this frame adds
        self._vbg.integrate(blocks, depth_img, color_img, intr_lookup, intr_lookup, extr, 1.0, depth_max,
                            float(self.config.trunc_voxels))
        hm = self._vbg.hashmap()
        self.stats.frames_integrated += 1
        self.stats.pixels_integrated += n_valid
        self.stats.blocks_allocated = int(hm.size())
        self.stats.capacity_blocks = int(hm.capacity())
        self.stats.memory_gib = self.stats.capacity_blocks * self.bytes_per_block / 2**30
        return n_blocks

    # -- extraction ---------------------------------------------------------------------------
    def _require_grid(self) -> None:
        if self._vbg is None:
            raise StageError("fusion", "no frame with valid depth was integrated, so there is no surface to extract")

    def extract_cloud(self, min_weight: float | None = None, normals: bool = False):
        """Surface points (N, 3) float64 m (world) and their colours (N, 3) float64 RGB in [0, 1].

        normals: also return unit normals (N, 3), the TSDF's gradient, so pointing out of the surface
        toward the free space the cameras saw it from (a third element of the tuple).
        """
        self._require_grid()
        wt = self.config.min_weight if min_weight is None else min_weight
        pcd = self._vbg.extract_point_cloud(weight_threshold=float(wt))
        if "positions" not in pcd.point or pcd.point.positions.shape[0] == 0:
            return (np.zeros((0, 3)),) * (3 if normals else 2)
        pts = pcd.point.positions.cpu().numpy().astype(np.float64)
        cols = pcd.point.colors.cpu().numpy().astype(np.float64) if "colors" in pcd.point else np.zeros_like(pts)
        nrm = pcd.point.normals.cpu().numpy().astype(np.float64) if "normals" in pcd.point else np.zeros_like(pts)
        # The hash map's block order depends on thread scheduling, so the same volume comes out in a
        # different order each run; sorting makes cloud.ply (and all that reads it) reproducible. Two
        # neighbouring blocks can both emit a point at the same position (with its own normal and colour):
        # normals and colours break such ties, else their order was the threads' (a Ray worker's cloud
        # differed from a local worker's by two swapped points, 1 run in ~3).
        order = canonical_order(pts, nrm, cols)
        if not normals:
            return pts[order], np.clip(cols[order], 0.0, 1.0)
        nrm = nrm[order]
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        return pts[order], np.clip(cols[order], 0.0, 1.0), nrm

    def extract_mesh(self, min_weight: float | None = None):
        """Marching-cubes surface as a legacy ``open3d.geometry.TriangleMesh`` (vertex colours RGB [0, 1])."""
        self._require_grid()
        wt = self.config.min_weight if min_weight is None else min_weight
        return self._vbg.extract_triangle_mesh(weight_threshold=float(wt)).to_legacy()


def canonical_order(pts: np.ndarray, nrm: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Indices that sort points by x, y, z (m), then normal, then colour: the same set of points in any
    input order comes out in one order (points (N, 3), normals (N, 3), colours (N, 3))."""
    return np.lexsort((*cols.T[::-1], *nrm.T[::-1], pts[:, 2], pts[:, 1], pts[:, 0]))


def estimate_block_count(depth_m: np.ndarray, K: np.ndarray, voxel_m: float, block_resolution: int = 8,
                         trunc_voxels: float = 8.0, frames: int = 1) -> int:
    """Rough upper bound of blocks touched by ``frames`` views like this one (for planning memory).

    Surface area seen by the frame ≈ sum over valid pixels of (Z / f)², times the truncation shell
    thickness, divided by the block volume; views of an orbit overlap, so ``frames`` is scaled by
    a square root rather than linearly.
    """
    z = np.asarray(depth_m, np.float64)
    z = z[np.isfinite(z) & (z > 0)]
    block_m = voxel_m * block_resolution
    area = float(np.sum((z / K[0][0]) ** 2))
    shell = 2 * trunc_voxels * voxel_m + block_m
    return int(math.ceil(area * shell / block_m ** 3 * math.sqrt(max(frames, 1)))) + 1
