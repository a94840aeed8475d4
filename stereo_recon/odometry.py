"""Stereo visual odometry: left-image feature tracks, 3-D from stereo depth, PnP, loop closure.

Per frame: corners (Shi-Tomasi) tracked from the current keyframe's image by pyramidal Lucas-Kanade
(seeded with the previous frame's positions, forward-backward checked), so per-frame tracking errors
do not accumulate along a track; each track carries a world point lifted from the depth of the
keyframe that created it (a dense depth map, or sparse row matching in the right image at the
keyframe's corners only); the current pose comes from PnP-RANSAC on those 2-D/3-D pairs, refined by
Levenberg-Marquardt on the inliers (motion-only bundle adjustment). Corners need no descriptor
match, which keeps tracks alive on texture-poor panels where descriptors are ambiguous.

Keyframes are made when too few tracks survive or the camera moved far enough; they get new
corners plus ORB descriptors with camera-frame 3-D points, kept for relocalisation after tracking
loss and for loop detection: a new keyframe near an older one (index gap large, centres close,
views alike) is matched by descriptors and verified by PnP, which adds a loop edge. ``finish``
optimises the keyframe pose graph (odometry + loop edges, SE(3) least squares) and carries the
correction to every frame through its keyframe.

Metric by construction: 3-D points come from metric stereo depth. Poses are world-from-left-camera
with the world at the first tracked frame. Memory: a pose per frame, and per keyframe its ORB
descriptors and 3-D points (about 60 kB at 1000 features).
"""

from __future__ import annotations

import math

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from stereo_recon.trajectory import Trajectory, rotation_angle_deg

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class VOConfig:
    """Settings of the stereo visual odometry."""

    # Corners kept per frame (Shi-Tomasi); more = more robust, slower.
    max_features: int = 800
    # Corner quality relative to the best corner, and minimum spacing (px, at HD720).
    feature_quality: float = 0.005
    feature_min_distance_px: float = 12.0
    # Lucas-Kanade window (px), pyramid levels, and forward-backward agreement (px).
    # Smaller windows track more accurately under the perspective change of an orbit (a 21 px window
    # shortened every step by 1 % on the synthetic orbit, 11 px by 0.3 %).
    lk_window_px: int = 15
    lk_levels: int = 3
    lk_fb_max_px: float = 1.0
    # Depth range trusted for lifting corners to 3-D (metres).
    min_depth_m: float = 0.3
    max_depth_m: float = math.inf   # no fixed cap: the sparse matcher stops at 1 px of disparity
    # A corner is lifted only where its inverse depth differs from the 5x5 mean by less than this
    # fraction (corners on depth edges get foreground/background mixes; planes pass).
    depth_edge_rel: float = 0.02
    # PnP-RANSAC reprojection threshold (px), iterations, confidence; minimum inliers for a pose.
    pnp_reproj_px: float = 2.0
    pnp_iterations: int = 200
    pnp_confidence: float = 0.999
    min_inliers: int = 25
    # New keyframe when fewer than this fraction of the keyframe's tracks survive ...
    keyframe_min_track_ratio: float = 0.6
    # ... or when fewer tracks than this are left ...
    keyframe_min_tracks: int = 150
    # ... or after this rotation (deg) or translation relative to the median scene depth.
    keyframe_rotation_deg: float = 8.0
    keyframe_translation_rel: float = 0.10
    # ORB features per keyframe for relocalisation and loops (descriptor matching ratio test).
    orb_features: int = 1000
    orb_ratio: float = 0.8
    # Loop closure on/off; a candidate keyframe must be at least this many keyframes older,
    loop_closure: bool = True
    loop_min_keyframe_gap: int = 10
    # its centre within this fraction of the path length so far (at least loop_min_radius_rel
    # times the median depth) and its optical axis within loop_max_angle_deg of the current one.
    loop_radius_rel: float = 0.1
    loop_min_radius_rel: float = 0.5
    loop_max_angle_deg: float = 45.0
    # Candidates tried per keyframe (nearest first), and PnP inliers needed to accept a loop.
    loop_max_candidates: int = 3
    loop_min_inliers: int = 40
    loop_min_inlier_ratio: float = 0.3
    # Pose graph: weight of a loop edge relative to an odometry edge; rotation-to-translation
    # weight (metres per radian) in the residual.
    loop_edge_weight: float = 1.0
    graph_rot_weight_m: float = 1.0

    def __post_init__(self) -> None:
        from stereo_recon.core.errors import ConfigError

        positive = ("max_features", "feature_min_distance_px", "lk_window_px", "pnp_reproj_px", "pnp_iterations",
                    "min_inliers", "orb_features", "max_depth_m", "keyframe_rotation_deg", "keyframe_translation_rel")
        bad = [n for n in positive if not getattr(self, n) > 0]
        if bad:
            raise ConfigError(f"VOConfig: {', '.join(bad)} must be > 0")
        if not 0 <= self.min_depth_m < self.max_depth_m:
            raise ConfigError(f"VOConfig: need 0 <= min_depth_m < max_depth_m, got {self.min_depth_m}, {self.max_depth_m}")
        if self.min_inliers < 6:
            raise ConfigError("VOConfig.min_inliers: PnP needs at least 6 points")


@dataclass
class _Keyframe:
    kf_id: int
    frame_index: int
    T_wc: np.ndarray
    # ORB descriptors (M,32) uint8 and their camera-frame 3-D points (M,3) metres, pixel coords (M,2).
    desc: np.ndarray
    pts3_cam: np.ndarray
    median_depth_m: float


@dataclass
class _Edge:
    i: int
    j: int
    Z_ij: np.ndarray  # measured T_i^-1 T_j (keyframe i from keyframe j)
    weight: float
    kind: str


def _inv(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def _T_from_rt(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, np.float64).reshape(3)
    return T


def sparse_stereo_depth(left_gray: np.ndarray, right_gray: np.ndarray, uv: np.ndarray, focal_px: float,
                        baseline_m: float, min_depth_m: float = 0.3, max_depth_m: float = math.inf,
                        window_px: int = 9, min_ncc: float = 0.8, uniqueness: float = 0.05) -> np.ndarray:
    """Depth (M,) metres at left-image pixels uv (M,2) by row search in the rectified right image.

    Normalised cross-correlation of a window_px square along the same row over the disparities of
    [min_depth_m, max_depth_m], parabola sub-pixel peak; NaN where the best score is below min_ncc,
    not `uniqueness` above the best score more than 2 px away, or the window leaves the image.
    Z = focal_px * baseline_m / disparity (rectified pair, right eye to the right).
    All points are matched at once (vectorised NCC, the same scores as cv2.matchTemplate's
    TM_CCOEFF_NORMED per point, about 2x faster at 1000 points on HD720).
    """
    h, w = left_gray.shape[:2]
    r = window_px // 2
    n_px = float(window_px * window_px)
    fb = focal_px * baseline_m
    d_lo = max(1, int(np.floor(fb / max_depth_m)))
    d_hi = int(np.ceil(fb / min_depth_m))
    z = np.full(len(uv), np.nan)
    if len(uv) == 0:
        return z
    cols = np.rint(uv[:, 0]).astype(int)
    rows = np.rint(uv[:, 1]).astype(int)
    # Candidate right-window centres x = u - d_hi + j, j = 0..n-1 (d from d_hi down to d_lo); usable where x >= r.
    x_first = np.maximum(r, cols - d_hi)
    ok = (rows - r >= 0) & (rows + r < h) & (cols - r >= 0) & (cols + r < w) & (cols - d_lo - x_first >= 2)
    k_ok = np.flatnonzero(ok)
    if k_ok.size == 0:
        return z
    u, v = cols[k_ok], rows[k_ok]
    n_cand = d_hi - d_lo + 1
    # Vectorised zero-mean NCC (OpenCV's TM_CCOEFF_NORMED) of every point's left window against its
    # right-image row strip; the right image is padded on the left so every strip has the same width.
    pad = d_hi + r
    right_p = np.pad(np.asarray(right_gray, np.float32), ((0, 0), (pad, 0)))
    left_f = np.asarray(left_gray, np.float32)
    dr = np.arange(-r, r + 1)
    rr = (v[:, None] + dr)[:, :, None]                                   # (M, win, 1)
    strip_c = (u - d_hi - r + pad)[:, None] + np.arange(n_cand + 2 * r)  # (M, Ws) padded columns
    strips = right_p[rr, strip_c[:, None, :]]                            # (M, win, Ws)
    tmpl = left_f[rr, (u[:, None] + dr)[:, None, :]]                     # (M, win, win)
    tmpl = tmpl - tmpl.mean(axis=(1, 2), keepdims=True)
    # num[m, j] = sum_a,k strips[m, a, j + k] * tmpl[m, a, k]: one batched mat-vec per window column k.
    num = np.zeros((len(u), n_cand), np.float32)
    for k in range(window_px):
        num += np.matmul(tmpl[:, None, :, k], strips[:, :, k:k + n_cand])[:, 0]
    cs = np.concatenate([np.zeros((len(u), 1), np.float64), np.cumsum(strips.sum(axis=1), axis=1, dtype=np.float64)], 1)
    cs2 = np.concatenate([np.zeros((len(u), 1), np.float64),
                          np.cumsum((strips.astype(np.float64) ** 2).sum(axis=1), axis=1)], 1)
    s1 = cs[:, window_px:] - cs[:, :-window_px]
    s2 = cs2[:, window_px:] - cs2[:, :-window_px]
    var_i = np.maximum(s2 - s1 * s1 / n_px, 0.0)
    var_t = np.sum(tmpl.astype(np.float64) ** 2, axis=(1, 2))[:, None]
    den = np.sqrt(var_i * var_t)
    score = np.where(den > 1e-6 * n_px, num / np.maximum(den, 1e-12), 0.0)
    j = np.arange(n_cand)[None, :]
    j_first = (x_first[k_ok] - (u - d_hi))[:, None]
    score = np.where(j >= j_first, score, -np.inf)
    i = np.argmax(score, axis=1)
    m = np.arange(len(u))
    best = score[m, i]
    good = (best >= min_ncc) & (i != j_first[:, 0]) & (i != n_cand - 1)
    far = np.where(np.abs(j - i[:, None]) > 2, score, -np.inf).max(axis=1)
    good &= ~(far > best - uniqueness)
    i_c = np.clip(i, 1, n_cand - 2)
    s_m, s_p = score[m, i_c - 1], score[m, i_c + 1]
    curv = s_m - 2 * best + s_p
    with np.errstate(invalid="ignore", divide="ignore"):
        delta = np.where(curv < 0, 0.5 * (s_m - s_p) / np.where(curv < 0, curv, -1.0), 0.0)
    disp = u - (u - d_hi + i + delta)
    good &= disp > 0
    z[k_ok[good]] = fb / disp[good]
    return z


class _DenseDepth:
    """Depth source of one frame from a dense depth map (edge-filtered lazily)."""

    def __init__(self, vo: "StereoVO", depth_m: np.ndarray):
        self.vo, self.depth_m, self._ok = vo, depth_m, None

    @property
    def ok(self) -> np.ndarray:
        if self._ok is None:
            self._ok = self.vo._depth_ok(self.depth_m)
        return self._ok

    def lift(self, uv: np.ndarray):
        h, w = self.depth_m.shape[:2]
        c = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
        r = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
        z = self.depth_m[r, c].astype(np.float64)
        ok = self.ok[r, c] & np.isfinite(z)
        return self.vo._backproject(uv, z), ok

    def median_m(self) -> float:
        zs = self.depth_m[self.ok]
        return float(np.median(zs)) if zs.size else 1.0


class _SparseStereoDepth:
    """Depth source of one frame by sparse stereo matching at the requested pixels only."""

    def __init__(self, vo: "StereoVO", left: np.ndarray, right: np.ndarray):
        self.vo, self.left, self.right = vo, left, right
        self._z: list[np.ndarray] = []

    def lift(self, uv: np.ndarray):
        c = self.vo.cfg
        z = sparse_stereo_depth(self.left, self.right, uv, self.vo.K[0, 0], self.vo.baseline_m,
                                c.min_depth_m, c.max_depth_m)
        ok = np.isfinite(z)
        self._z.append(z[ok])
        return self.vo._backproject(uv, z), ok

    def median_m(self) -> float:
        zs = np.concatenate(self._z) if self._z else np.zeros(0)
        return float(np.median(zs)) if zs.size else 1.0


class StereoVO:
    """Streaming stereo visual odometry over rectified left images with metric depth.

    K_rect: (3,3) rectified left pinhole intrinsics, px. baseline_m: stereo baseline (recorded).
    Call ``track`` once per frame in order, then ``finish`` for the loop-closed trajectory.
    Memory per frame is one 4x4 pose; per keyframe about ``orb_features`` descriptors + 3-D points.
    """

    def __init__(self, K_rect: np.ndarray, baseline_m: float, config: VOConfig = VOConfig(),
                 fps: float | None = None):
        self.K = np.asarray(K_rect, dtype=np.float64).reshape(3, 3)
        self.baseline_m = float(baseline_m)
        self.cfg = config
        self.fps = fps
        self._orb = cv2.ORB_create(nfeatures=config.orb_features)
        self._bf = cv2.BFMatcher(cv2.NORM_HAMMING)
        # Per-frame records (flat memory: a pose and two ints per frame).
        self._indices: list[int] = []
        self._timestamps: list[float] = []
        self._T_list: list[np.ndarray] = []
        self._kf_of_frame: list[int] = []
        # Tracking state.
        self._pts2: np.ndarray = np.zeros((0, 2), np.float32)   # current track positions, px
        self._pts3w: np.ndarray = np.zeros((0, 3), np.float64)  # their world points, m
        self._kf_gray: np.ndarray | None = None                 # image of the current keyframe
        self._kf_pts2: np.ndarray = np.zeros((0, 2), np.float32)  # track positions in it, px
        self._kf_tracks0 = 0
        self._T_prev: np.ndarray | None = None
        self._keyframes: list[_Keyframe] = []
        self._edges: list[_Edge] = []
        self._gaps: list[tuple[int, int]] = []
        self._path_m = 0.0
        self._n_reloc = 0
        self._segment = 0

    # ------------------------------------------------------------------------------- helpers
    def _backproject(self, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Camera-frame 3-D points (M,3) of pixels uv (M,2) at depths z (M,)."""
        X = np.empty((len(uv), 3))
        X[:, 0] = (uv[:, 0] - self.K[0, 2]) / self.K[0, 0] * z
        X[:, 1] = (uv[:, 1] - self.K[1, 2]) / self.K[1, 1] * z
        X[:, 2] = z
        return X

    def _depth_ok(self, depth_m: np.ndarray) -> np.ndarray:
        """Pixels whose depth is in range and not on a depth edge.

        Inverse depth is affine in the pixel coordinates on any plane, so its 5x5 box mean equals the
        centre value on smooth surfaces (oblique ground included) and differs at depth edges.
        """
        d = np.where(np.isfinite(depth_m), depth_m, 0).astype(np.float32)
        ok = (d >= self.cfg.min_depth_m) & (d <= self.cfg.max_depth_m)
        inv = np.where(ok, 1.0 / np.maximum(d, 1e-6), 0).astype(np.float32)
        ok &= cv2.erode(ok.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        return ok & (np.abs(cv2.blur(inv, (5, 5)) - inv) <= self.cfg.depth_edge_rel * inv)

    def _pnp(self, X: np.ndarray, uv: np.ndarray):
        """PnP-RANSAC + LM refinement; returns (T_cw of the points' frame, inlier idx) or (None, None)."""
        if len(X) < max(6, self.cfg.min_inliers):
            return None, None
        X = np.ascontiguousarray(X, np.float64)
        uv = np.ascontiguousarray(uv, np.float64)
        kw = dict(iterationsCount=self.cfg.pnp_iterations, reprojectionError=self.cfg.pnp_reproj_px,
                  confidence=self.cfg.pnp_confidence, flags=cv2.SOLVEPNP_SQPNP)
        try:
            ok, rvec, tvec, inl = cv2.solvePnPRansac(X, uv, self.K, None, **kw)
        except cv2.error:
            return None, None
        if not ok or inl is None or len(inl) < self.cfg.min_inliers:
            return None, None
        inl = inl.reshape(-1)
        rvec, tvec = cv2.solvePnPRefineLM(X[inl], uv[inl], self.K, None, rvec, tvec)
        # Re-collect inliers under the refined pose and refine once more on them.
        proj, _ = cv2.projectPoints(X, rvec, tvec, self.K, None)
        err = np.linalg.norm(proj.reshape(-1, 2) - uv, axis=1)
        inl2 = np.flatnonzero(err < self.cfg.pnp_reproj_px)
        if len(inl2) >= self.cfg.min_inliers:
            rvec, tvec = cv2.solvePnPRefineLM(X[inl2], uv[inl2], self.K, None, rvec, tvec)
            inl = inl2
        return _T_from_rt(rvec, tvec), inl

    def _detect(self, gray: np.ndarray, mask_pts: np.ndarray, n: int) -> np.ndarray:
        mask = np.full(gray.shape[:2], 255, np.uint8)
        rad = int(round(self.cfg.feature_min_distance_px))
        for u, v in mask_pts:
            cv2.circle(mask, (int(u), int(v)), rad, 0, -1)
        pts = cv2.goodFeaturesToTrack(gray, maxCorners=n, qualityLevel=self.cfg.feature_quality,
                                      minDistance=self.cfg.feature_min_distance_px, mask=mask, blockSize=5)
        return np.zeros((0, 2), np.float32) if pts is None else pts.reshape(-1, 2).astype(np.float32)

    def _make_keyframe(self, index: int, gray: np.ndarray, ds, T_wc: np.ndarray, link_prev: bool,
                       orb=None) -> _Keyframe:
        """New keyframe at this frame: replenish tracks, store ORB + 3-D, add graph edges, look for loops."""
        cfg = self.cfg
        need = cfg.max_features - len(self._pts2)
        if need > 0:
            new = self._detect(gray, self._pts2, need)
            X, ok = ds.lift(new.astype(np.float64))
            Xw = X[ok] @ T_wc[:3, :3].T + T_wc[:3, 3]
            self._pts2 = np.vstack([self._pts2, new[ok]]).astype(np.float32)
            self._pts3w = np.vstack([self._pts3w, Xw])
        self._kf_tracks0 = len(self._pts2)
        self._kf_gray = gray
        self._kf_pts2 = self._pts2.copy()
        desc, X, ok, uv = orb if orb is not None else self._orb_frame(gray, ds)
        med = ds.median_m()
        kf = _Keyframe(len(self._keyframes), index, T_wc.copy(), desc[ok], X[ok], med)
        self._keyframes.append(kf)
        if len(self._keyframes) > 1:
            prev = self._keyframes[-2]
            # Across a tracking gap the relative pose is unknown: a weak edge keeps the graph connected.
            w, kind = (1.0, "odometry") if link_prev else (1e-4, "gap")
            self._edges.append(_Edge(prev.kf_id, kf.kf_id, _inv(prev.T_wc) @ T_wc, w, kind))
        if cfg.loop_closure:
            self._try_loop(kf, desc, uv)
        return kf

    def _orb_frame(self, gray: np.ndarray, ds):
        """ORB descriptors (M,32), camera-frame 3-D (M,3), depth validity (M,), pixels (M,2)."""
        kps, desc = self._orb.detectAndCompute(gray, None)
        if desc is None or not kps:
            return np.zeros((0, 32), np.uint8), np.zeros((0, 3)), np.zeros(0, bool), np.zeros((0, 2))
        uv = np.array([k.pt for k in kps], np.float64)
        X, ok = ds.lift(uv)
        return desc, X, ok, uv

    def _match_pnp(self, kf: _Keyframe, desc: np.ndarray, uv: np.ndarray, min_inliers: int):
        """(T_cur_from_kf, inliers) by ORB matching + PnP against kf's 3-D points, or (None, n)."""
        if len(kf.desc) < min_inliers or len(desc) < min_inliers:
            return None, 0
        knn = self._bf.knnMatch(desc, kf.desc, k=2)
        pairs = [(m[0].queryIdx, m[0].trainIdx) for m in knn
                 if len(m) == 2 and m[0].distance < self.cfg.orb_ratio * m[1].distance]
        if len(pairs) < min_inliers:
            return None, len(pairs)
        q, t = np.array(pairs).T
        T, inl = self._pnp(kf.pts3_cam[t], uv[q])
        if T is None or len(inl) < min_inliers or len(inl) < self.cfg.loop_min_inlier_ratio * len(pairs):
            return None, 0 if inl is None else len(inl)
        return T, len(inl)

    def _try_loop(self, kf: _Keyframe, desc: np.ndarray, uv: np.ndarray) -> None:
        cfg = self.cfg
        older = self._keyframes[: max(0, kf.kf_id - cfg.loop_min_keyframe_gap + 1)]
        if not older:
            return
        radius = max(cfg.loop_radius_rel * self._path_m, cfg.loop_min_radius_rel * kf.median_depth_m)
        c = kf.T_wc[:3, 3]
        z = kf.T_wc[:3, 2]
        cands = []
        for o in older:
            d = float(np.linalg.norm(o.T_wc[:3, 3] - c))
            ang = float(np.degrees(np.arccos(np.clip(o.T_wc[:3, 2] @ z, -1, 1))))
            if d <= radius and ang <= cfg.loop_max_angle_deg:
                cands.append((d, o))
        cands.sort(key=lambda x: x[0])
        for _, o in cands[: cfg.loop_max_candidates]:
            T_cur_from_o, n = self._match_pnp(o, desc, uv, cfg.loop_min_inliers)
            if T_cur_from_o is not None:
                self._edges.append(_Edge(o.kf_id, kf.kf_id, _inv(T_cur_from_o), cfg.loop_edge_weight, "loop"))
                log.info("loop closure: keyframe %d (frame %d) -> keyframe %d (frame %d), %d inliers",
                         kf.kf_id, kf.frame_index, o.kf_id, o.frame_index, n)
                return

    def _relocalise(self, gray, ds):
        """Pose of this frame from ORB matches against the last few keyframes, or None."""
        orb = self._orb_frame(gray, ds)
        desc, _, _, uv = orb
        for kf in reversed(self._keyframes[-3:]):
            T_cur_from_kf, _ = self._match_pnp(kf, desc, uv, self.cfg.min_inliers)
            if T_cur_from_kf is not None:
                return kf.T_wc @ _inv(T_cur_from_kf), orb
        return None, orb

    def _keep(self, sel, new_pts2: np.ndarray | None = None) -> None:
        """Keep the selected tracks (mask or indices), optionally moving them to new_pts2 first."""
        if new_pts2 is not None:
            self._pts2 = new_pts2.astype(np.float32)
        self._pts2, self._pts3w, self._kf_pts2 = self._pts2[sel], self._pts3w[sel], self._kf_pts2[sel]

    def _record(self, index: int, timestamp_s: float | None, T_wc: np.ndarray) -> None:
        if self._T_list:
            self._path_m += float(np.linalg.norm(T_wc[:3, 3] - self._T_list[-1][:3, 3]))
        self._indices.append(int(index))
        self._timestamps.append(
            float(timestamp_s) if timestamp_s is not None else (index / self.fps if self.fps else float(index))
        )
        self._T_list.append(T_wc.copy())
        self._kf_of_frame.append(self._keyframes[-1].kf_id)
        self._T_prev = T_wc

    # ---------------------------------------------------------------------------------- API
    def track(self, index: int, left_rect_gray: np.ndarray, depth_m: np.ndarray | None,
              timestamp_s: float | None = None, right_rect_gray: np.ndarray | None = None) -> np.ndarray | None:
        """Pose of this frame (4x4 world-from-camera, metres) or None when tracking is lost.

        index: frame index in the video. left_rect_gray: (H,W) uint8 rectified left image.
        depth_m: (H,W) float depth of the left image in metres, NaN/0 where invalid; or None with
            right_rect_gray given: depth is then matched sparsely, only at the corners a keyframe
            lifts (no dense depth needed for tracking, so a caller can run SGBM on fusion frames only).
        timestamp_s: TUM timestamp (default index / fps, or the index without fps).
        After a loss the frame is relocalised against recent keyframes; if that fails, tracking is
        re-initialised at this frame (pose unknown: None is returned, the gap is recorded and the
        new segment starts at the last known pose).
        """
        gray = left_rect_gray
        if gray.ndim == 3:
            gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
        ds = self._depth_source(gray, depth_m, right_rect_gray)
        if not self._keyframes:
            T = np.eye(4)
            self._make_keyframe(index, gray, ds, T, link_prev=False)
            self._record(index, timestamp_s, T)
            return T.copy()
        T_wc = self._track_from_keyframe(gray) if len(self._pts2) >= self.cfg.min_inliers else None
        if T_wc is None:
            return self._recover(index, gray, ds, timestamp_s)
        if self._needs_keyframe(T_wc):
            self._make_keyframe(index, gray, ds, T_wc, link_prev=True)
        self._record(index, timestamp_s, T_wc)
        return T_wc.copy()

    def _depth_source(self, gray: np.ndarray, depth_m: np.ndarray | None, right_rect_gray: np.ndarray | None):
        """Where keyframe corners get their depth: the dense map (m), or sparse matching in the right image."""
        if depth_m is not None:
            depth_m = np.asarray(depth_m)
            if depth_m.shape[:2] != gray.shape[:2]:
                raise ValueError(f"track: depth {depth_m.shape[:2]} and image {gray.shape[:2]} sizes differ")
            return _DenseDepth(self, depth_m)
        if right_rect_gray is not None:
            right = right_rect_gray if right_rect_gray.ndim == 2 else cv2.cvtColor(right_rect_gray, cv2.COLOR_BGR2GRAY)
            if right.shape[:2] != gray.shape[:2]:
                raise ValueError(f"track: right {right.shape[:2]} and left {gray.shape[:2]} sizes differ")
            return _SparseStereoDepth(self, gray, right)
        raise ValueError("track: give depth_m or right_rect_gray")

    def _track_from_keyframe(self, gray: np.ndarray) -> np.ndarray | None:
        """Pose (world-from-camera, m) of this image by LK tracking of the keyframe's corners and PnP; None = lost."""
        cfg = self.cfg
        # Track from the keyframe image (not the previous frame) so that the tracking errors of
        # consecutive frames do not add up along a track; the previous position seeds the search.
        win = (cfg.lk_window_px, cfg.lk_window_px)
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        p0 = self._kf_pts2.reshape(-1, 1, 2)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(self._kf_gray, gray, p0, self._pts2.reshape(-1, 1, 2).copy(),
                                             winSize=win, maxLevel=cfg.lk_levels, flags=flags)
        p0r, st2, _ = cv2.calcOpticalFlowPyrLK(gray, self._kf_gray, p1, p0.copy(), winSize=win,
                                               maxLevel=cfg.lk_levels, flags=flags)
        fb = np.linalg.norm((p0r - p0).reshape(-1, 2), axis=1)
        p1 = p1.reshape(-1, 2)
        h, w = gray.shape[:2]
        good = (st.reshape(-1) == 1) & (st2.reshape(-1) == 1) & (fb < cfg.lk_fb_max_px)
        good &= (p1[:, 0] >= 0) & (p1[:, 0] < w) & (p1[:, 1] >= 0) & (p1[:, 1] < h)
        self._keep(good, p1)
        T_cw, inl = self._pnp(self._pts3w, self._pts2)
        if T_cw is None:
            return None
        self._keep(inl)
        return _inv(T_cw)

    def _recover(self, index: int, gray: np.ndarray, ds, timestamp_s: float | None) -> np.ndarray | None:
        """After a loss: relocalise against recent keyframes, else re-initialise a new segment (pose None)."""
        self._keep(np.zeros(len(self._pts2), bool))
        T_wc, orb = self._relocalise(gray, ds)
        if T_wc is not None:
            self._n_reloc += 1
            log.info("frame %d: tracking lost, relocalised against a recent keyframe", index)
            self._make_keyframe(index, gray, ds, T_wc, link_prev=True, orb=orb)
            self._record(index, timestamp_s, T_wc)
            return T_wc.copy()
        # Re-initialise: a new segment at the last known pose; this frame's pose is unknown.
        last = self._indices[-1] if self._indices else index
        self._gaps.append((int(last), int(index)))
        self._segment += 1
        log.warning("frame %d: tracking lost since frame %d, re-initialised", index, last)
        self._make_keyframe(index, gray, ds, self._T_prev.copy(), link_prev=False, orb=orb)
        return None

    def _needs_keyframe(self, T_wc: np.ndarray) -> bool:
        """Too few tracks left, or the camera turned or moved too far from the last keyframe."""
        cfg = self.cfg
        kf = self._keyframes[-1]
        rel = _inv(kf.T_wc) @ T_wc
        n = len(self._pts2)
        return bool(n < cfg.keyframe_min_track_ratio * self._kf_tracks0 or n < cfg.keyframe_min_tracks
                    or rotation_angle_deg(rel[:3, :3]) > cfg.keyframe_rotation_deg
                    or np.linalg.norm(rel[:3, 3]) > cfg.keyframe_translation_rel * kf.median_depth_m)

    def finish(self) -> Trajectory:
        """All tracked frames' poses after loop-closing pose-graph optimisation (when loops were found)."""
        if not self._T_list:
            return Trajectory(np.zeros(0, int), np.zeros(0), np.zeros((0, 4, 4)), self._stats({}))
        T = np.stack(self._T_list)
        n_loops = sum(e.kind == "loop" for e in self._edges)
        graph = {}
        if n_loops:
            K_old = np.stack([k.T_wc for k in self._keyframes])
            K_new, graph = optimise_pose_graph(K_old, [(e.i, e.j, e.Z_ij, e.weight) for e in self._edges],
                                               rot_weight_m=self.cfg.graph_rot_weight_m)
            ref = np.asarray(self._kf_of_frame)
            T = K_new[ref] @ np.linalg.inv(K_old[ref]) @ T
            for k, Tk in zip(self._keyframes, K_new):
                k.T_wc = Tk
        return Trajectory(np.asarray(self._indices), np.asarray(self._timestamps), T, self._stats(graph))

    def _stats(self, graph: dict) -> dict:
        return {
            "backend": "vo",
            "frames_tracked": len(self._T_list),
            "keyframes": len(self._keyframes),
            "tracking_gaps": [list(g) for g in self._gaps],
            "relocalisations": self._n_reloc,
            # Segments after re-initialisation share a world frame only through loop edges.
            "segments": self._segment + 1,
            "loop_closures": sum(e.kind == "loop" for e in self._edges),
            "loop_pairs_frames": [
                [self._keyframes[e.i].frame_index, self._keyframes[e.j].frame_index]
                for e in self._edges if e.kind == "loop"
            ],
            "pose_graph": graph,
            "baseline_m": self.baseline_m,
        }


def optimise_pose_graph(T_wc: np.ndarray, edges: list, rot_weight_m: float = 1.0,
                        fixed: int = 0) -> tuple[np.ndarray, dict]:
    """SE(3) pose-graph optimisation by sparse least squares (scipy), node `fixed` held.

    T_wc: (N,4,4) initial world-from-node poses. edges: (i, j, Z_ij, weight) with Z_ij the measured
    T_i^-1 T_j. Each node is updated on the right, T_i = T_i0 exp(d_i), d_i = (rotvec, translation).
    Residual of an edge: sqrt(weight) * [rot_weight_m * log(E)_rot, E_t] with E = Z_ij^-1 T_i^-1 T_j.
    Returns the optimised poses and a dict of costs before/after.
    """
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix
    from scipy.spatial.transform import Rotation

    T0 = np.asarray(T_wc, np.float64)
    N = len(T0)
    I = np.array([e[0] for e in edges])
    J = np.array([e[1] for e in edges])
    Zinv = np.linalg.inv(np.stack([e[2] for e in edges]))
    sw = np.sqrt(np.array([e[3] for e in edges], np.float64))[:, None]
    free = np.array([k for k in range(N) if k != fixed])
    col = np.full(N, -1)
    col[free] = np.arange(len(free))

    def poses(x):
        d = np.zeros((N, 6))
        d[free] = x.reshape(-1, 6)
        D = np.tile(np.eye(4), (N, 1, 1))
        D[:, :3, :3] = Rotation.from_rotvec(d[:, :3]).as_matrix()
        D[:, :3, 3] = d[:, 3:]
        return T0 @ D

    def residual(x):
        P = poses(x)
        Pi = P[I]
        Ri_T = np.swapaxes(Pi[:, :3, :3], 1, 2)
        inv_i = np.tile(np.eye(4), (len(I), 1, 1))
        inv_i[:, :3, :3] = Ri_T
        inv_i[:, :3, 3] = -np.einsum("nij,nj->ni", Ri_T, Pi[:, :3, 3])
        E = Zinv @ inv_i @ P[J]
        r = np.hstack([rot_weight_m * Rotation.from_matrix(E[:, :3, :3]).as_rotvec(), E[:, :3, 3]])
        return (sw * r).ravel()

    S = lil_matrix((6 * len(edges), 6 * len(free)), dtype=int)
    for k, (i, j) in enumerate(zip(I, J)):
        for n in (i, j):
            if col[n] >= 0:
                S[6 * k: 6 * k + 6, 6 * col[n]: 6 * col[n] + 6] = 1
    x0 = np.zeros(6 * len(free))
    c0 = 0.5 * float(np.sum(residual(x0) ** 2))
    res = least_squares(residual, x0, jac_sparsity=S, method="trf", x_scale="jac", max_nfev=100)
    return poses(res.x), {"cost_before": c0, "cost_after": float(res.cost), "nodes": N, "edges": len(edges),
                          "converged": bool(res.success)}
