"""Ground plane identification (paper Algorithm 1, Eqs. 1–3) and ground removal.

The plane is written n·p + d = 0 with |n| = 1 and n pointing up (towards the truck), so
``height(p) = n·p + d`` is the signed height above the ground.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from measure.kde import binned_kde, local_maxima, refine_peak
from measure.normals import local_pca
from stereo_recon.core.geometry import plane_axes

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GroundPlane:
    """n·p + d = 0; ``normal`` (3,) unit, pointing up; ``offset`` d in metres."""

    normal: np.ndarray
    offset: float
    inlier_rate: float                 # τ of the accepted plane (Algorithm 1, line 8)
    n_inliers: int
    iterations: int
    rms_m: float                       # RMS distance of the inliers to the plane
    initial_normal: np.ndarray
    initial_normal_source: str         # "up_hint" (refined by local normals), "up_hint_as_given" or "local_normals"
    history: list = field(default_factory=list)   # per iteration: normal, tau

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed height of (N, 3) points above the plane, metres."""
        return np.asarray(points) @ self.normal + self.offset


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0:
        raise ValueError(f"not a direction: {v}")
    return v / n


def estimate_up(points: np.ndarray, rng=0, sample_size: int = 20_000, k: int = 12, cone_deg: float = 5.0,
                prior: np.ndarray | None = None, prior_cone_deg: float = 30.0) -> np.ndarray:
    """A robust initial ground normal from the cloud alone (no camera-axis assumption).

    Local PCA normals are computed on a random subsample; the direction shared by the most
    normals (within ``cone_deg``, sign ignored) is the dominant plane orientation — the ground
    and the truck's roof share it, the walls split between other directions. The sign is chosen
    so that most points lie above the lowest dense layer (a vehicle stands on the ground).
    Returns a unit (3,) vector.
    """
    rng = np.random.default_rng(rng)
    p = np.asarray(points, dtype=np.float64)
    m = min(sample_size, len(p))
    sub = p[rng.choice(len(p), m, replace=False)]
    w, v = local_pca(sub, min(k, m))
    normals = v[:, :, 0]
    planarity = (w[:, 1] - w[:, 0]) / np.maximum(w[:, 2], 1e-30)
    normals = normals[planarity > 0.3]
    if len(normals) < 10:
        normals = v[:, :, 0]
    if prior is not None:
        # Only orientations within prior_cone_deg of the caller's 'up' are candidates.
        pr = _unit(prior)
        near = normals[np.abs(normals @ pr) >= np.cos(np.deg2rad(prior_cone_deg))]
        if len(near) < 10:
            return pr
        normals = near
    cand = normals[rng.choice(len(normals), min(200, len(normals)), replace=False)]
    voters = normals[rng.choice(len(normals), min(8000, len(normals)), replace=False)]
    cosc = np.cos(np.deg2rad(cone_deg))
    votes = (np.abs(cand @ voters.T) > cosc).sum(axis=1)
    best = cand[int(np.argmax(votes))]
    if prior is None:
        best = _widest_layer_orientation(p, cand, votes, rng)
    # Refine: mean of the agreeing normals (signs aligned).
    agree = normals[np.abs(normals @ best) > cosc]
    agree = agree * np.sign(agree @ best)[:, None]
    up = _unit(agree.mean(axis=0))
    if prior is not None:
        return up if up @ _unit(prior) > 0 else -up
    # Orientation: the ground is the lowest big layer, so most of the cloud is on its + side.
    h = p[rng.choice(len(p), m, replace=False)] @ up
    lo, hi = np.quantile(h, [0.02, 0.98])
    dens = binned_kde(h, bandwidth_m=(hi - lo) / 200 + 1e-12)
    peak = dens.grid_m[int(np.argmax(dens.density))]
    if np.mean(h > peak) < np.mean(h < peak):
        up = -up
    return up


def _widest_layer_orientation(p: np.ndarray, cand: np.ndarray, votes: np.ndarray, rng, n_orient: int = 3,
                              min_sep_deg: float = 30.0) -> np.ndarray:
    """Among the most-voted, mutually distinct normal orientations, the one whose densest layer
    spreads widest in its plane.

    A noisy ground votes less sharply than a clean truck wall, so votes alone can pick a wall;
    but the ground is by far the widest planar layer of the scene.
    """
    order = np.argsort(votes)[::-1]
    picked: list[np.ndarray] = []
    cos_sep = np.cos(np.deg2rad(min_sep_deg))
    for i in order:
        if votes[i] < 0.25 * votes[order[0]]:
            break
        if all(abs(cand[i] @ q) < cos_sep for q in picked):
            picked.append(cand[i])
        if len(picked) == n_orient:
            break
    sub = p[rng.choice(len(p), min(50_000, len(p)), replace=False)]
    # Local normals of a noisy ground (noise ~ neighbourhood size) are not planar and cast no
    # votes; the least-variance axis of the whole cloud stands for a ground that dominates it.
    q = sub - sub.mean(axis=0)
    glob = np.linalg.eigh(q.T @ q)[1][:, 0]
    if all(abs(glob @ c) < cos_sep for c in picked):
        picked.append(glob)
    if len(picked) == 1:
        return picked[0]
    best, best_spread = picked[0], -1.0
    for n in picked:
        h = sub @ n
        lo, hi = np.quantile(h, [0.01, 0.99])
        band = max((hi - lo) / 50, 1e-9)
        counts, edges = np.histogram(h, bins=np.arange(lo, hi + band, band))
        spread = -1.0
        # The few densest layers of this orientation (a noisy ground may be less dense than a
        # clean roof), each judged by its extent in the plane.
        for k in np.argsort(counts)[::-1][:3]:
            layer = sub[(h >= edges[k] - band) & (h <= edges[k + 1] + band)]
            if len(layer) < 10:
                continue
            q = layer - layer.mean(axis=0)
            ev = np.linalg.eigvalsh(q.T @ q / len(layer))
            spread = max(spread, float(np.sqrt(max(ev[1], 0) * max(ev[2], 0))))
        log.debug('orientation %s: layer spread %.4g', n, spread)
        if spread > best_spread:
            best, best_spread = n, spread
    return best


def _fit_plane(pts: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Least-squares plane (Eqs. 1–2: unit normal minimising the squared residuals): (n, d, rms)."""
    c = pts.mean(axis=0)
    q = pts - c
    _, s, vt = np.linalg.svd(q.T @ q)
    n = vt[-1]
    d = -float(n @ c)
    rms = float(np.sqrt(max(s[-1], 0.0) / len(pts)))
    return n, d, rms


def _cell_keys(u: np.ndarray, v: np.ndarray, cell_m: float) -> np.ndarray:
    """One int64 key per point for its square cell of ``cell_m`` (m) in plane coordinates (u, v)."""
    ku = np.floor((u - u.min()) / cell_m).astype(np.int64)
    kv = np.floor((v - v.min()) / cell_m).astype(np.int64)
    return ku * (int(kv.max()) + 1) + kv


def _cell_median_refit(pts: np.ndarray, n: np.ndarray, d: float, cell_m: float, rms: float) -> tuple[np.ndarray, float, float]:
    """Refit the plane to per-cell median heights (cells of ``cell_m`` in the plane).

    The bottoms of walls and wheels standing on the ground fall inside the band on one side
    only; a per-cell median ignores such local minorities, which a plain least-squares fit
    would follow. Returns (normal, offset, rms of the points about the new plane).
    """
    e1, e2 = plane_axes(n)
    u, v, r = pts @ e1, pts @ e2, pts @ n + d
    key = _cell_keys(u, v, cell_m)
    order = np.lexsort((r, key))
    ks = key[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    counts = np.diff(np.r_[starts, len(ks)])
    ok = counts >= 5
    if ok.sum() < 3:
        return n, d, rms
    mid = starts + counts // 2
    med = np.where(counts % 2 == 1, r[order][mid], 0.5 * (r[order][mid] + r[order][np.maximum(mid - 1, starts)]))
    uc = np.add.reduceat(u[order], starts) / counts
    vc = np.add.reduceat(v[order], starts) / counts
    w = np.sqrt(counts[ok].astype(np.float64))
    A = np.stack([uc[ok], vc[ok], np.ones(ok.sum())], axis=1) * w[:, None]
    coef, *_ = np.linalg.lstsq(A, med[ok] * w, rcond=None)
    a, b, c = coef
    nn = n - a * e1 - b * e2
    norm = np.linalg.norm(nn)
    nn = nn / norm
    dd = (d - c) / norm
    res = pts @ nn + dd
    return nn, float(dd), float(np.sqrt(np.mean(res**2)))


def _final_refit(p: np.ndarray, nn: np.ndarray, d: float, xi_m: float, rms: float) -> tuple[np.ndarray, float, float]:
    """Refit the accepted plane on its own ±ξ band: least squares, a trim to 2.5 robust sigma, then the
    per-cell median fit. p: (N, 3) m; (nn, d): the plane; returns (normal, offset, rms)."""
    # Final least-squares refit on the band around the accepted plane itself.
    inl = np.abs(p @ nn + d) <= xi_m
    if inl.sum() >= 3:
        nn2, d2, rms = _fit_plane(p[inl])
        if nn2 @ nn < 0:
            nn2, d2 = -nn2, -d2
        nn, d = nn2, d2
        # Trim to ±2.5 robust sigma of the residuals: the fixed band also catches the lowest
        # parts of wheels and stray points, which tilt a plain least-squares fit.
        for _ in range(3):
            r = p[inl] @ nn + d
            sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
            core = inl.copy()
            core[inl] = np.abs(r) <= min(2.5 * sigma, xi_m) if sigma > 0 else np.abs(r) <= xi_m
            if core.sum() < 3:
                break
            nn3, d3, rms = _fit_plane(p[core])
            if nn3 @ nn < 0:
                nn3, d3 = -nn3, -d3
            nn, d = nn3, d3
            inl = np.abs(p @ nn + d) <= xi_m
        nn, d, rms = _cell_median_refit(p[inl], nn, d, 6 * xi_m, rms)
    return nn, d, rms


def ground_plane(points: np.ndarray, xi_m: float, up_hint: np.ndarray | None = None, max_iter: int = 30, rng=0,
                 min_peak_rel: float = 0.25, max_points: int = 300_000, refine_hint: bool = True) -> GroundPlane:
    """Algorithm 1: iteratively refit the ground plane while the inlier rate τ rises.

    points: (N, 3) metres. xi_m: half-thickness ξ of the band around the density peak (metres).
    up_hint: approximate up direction (e.g. from the camera trajectory): it selects the dominant
    local-normal orientation within 30° of it as the start (refine_hint False: the hint itself is the
    start, the measure pipeline's second try where the local normals' start finds no ground);
    None => :func:`estimate_up` alone.
    Each iteration projects all points on the current normal (W = P·n), takes the peak of their
    Gaussian KDE, keeps the points within ±ξ of it (P_m, τ = |P_m|/N) and fits a least-squares
    plane to them (Eqs. 1–3); the new normal is kept while τ does not fall.
    Among density peaks of at least ``min_peak_rel`` × the highest, the ground is the one whose
    band spreads widest in the plane (a roof is a peak too, but a small one in extent).
    The iterations use a seeded subsample of at most ``max_points`` points.
    Raises ValueError when no plane is found.
    """
    p = np.asarray(points, dtype=np.float64)
    N = len(p)
    if up_hint is not None and not refine_hint:
        n, source = _unit(up_hint), "up_hint_as_given"
    elif up_hint is not None:
        # The hint picks the orientation; the local normals near it give the precise start
        # (a trajectory's 'up' can be several degrees off, too far for the ±ξ band).
        n = estimate_up(p, rng=rng, prior=_unit(up_hint))
        source = "up_hint"
    else:
        n = estimate_up(p, rng=rng)
        source = "local_normals"
    n0 = n.copy()
    history = []
    best = None
    # Algorithm 1 runs on a seeded subsample: τ and the least-squares plane of 3·10⁵ points are
    # as good as those of 10⁶ (the normal's error is already far below 0.01°) at a third of the cost.
    rng_ = np.random.default_rng(rng)
    full = p
    p = p if N <= max_points else p[rng_.choice(N, max_points, replace=False)]
    for it in range(max_iter):
        w = p @ n
        dens = binned_kde(w, bandwidth_m=max(xi_m / 2, 1e-9), step_m=max(xi_m / 8, 1e-9), max_bins=1 << 18)
        peaks = local_maxima(dens.density, min_peak_rel)
        if len(peaks) == 0:
            break
        # Choose the widest-spread layer among the significant peaks.
        best_peak, best_spread = None, -1.0
        stride = max(1, len(p) // 50_000)
        ps, ws = p[::stride], w[::stride]
        for i in peaks:
            wy = refine_peak(dens.grid_m, dens.density, int(i))
            band = np.abs(ws - wy) <= xi_m
            if band.sum() < 3:
                continue
            q = ps[band] - ps[band].mean(axis=0)
            ev = np.linalg.eigvalsh(q.T @ q / band.sum())
            spread = float(np.sqrt(max(ev[1], 0) * max(ev[2], 0)))
            if spread > best_spread:
                best_peak, best_spread = wy, spread
        if best_peak is None:
            break
        inl = np.abs(w - best_peak) <= xi_m
        tau = float(inl.mean())
        history.append({"normal": n.copy(), "tau": tau})
        if best is not None and tau < best[2]:
            break   # τ fell: keep the previous plane (Algorithm 1, lines 10-13)
        nn, d, rms = _fit_plane(p[inl])
        if nn @ n < 0:
            nn, d = -nn, -d
        best = (nn, d, tau, int(inl.sum()), rms, it + 1)
        if np.degrees(np.arccos(np.clip(nn @ n, -1, 1))) < 1e-4:
            break
        n = nn
    if best is None or best[3] < 3:
        raise ValueError("no ground plane: no dense planar layer in the cloud")
    nn, d, tau, n_in, rms, iters = best
    nn, d, rms = _final_refit(p, nn, d, xi_m, rms)
    p = full
    h = p @ nn + d
    inl = np.abs(h) <= xi_m
    n_in, tau = int(inl.sum()), float(inl.mean())
    # Up is the side holding most of the off-ground points.
    off = np.abs(h) > 3 * xi_m
    if up_hint is not None:
        if nn @ _unit(up_hint) < 0:
            nn, d = -nn, -d
    elif off.any() and np.mean(h[off] < 0) > 0.5:
        nn, d = -nn, -d
    return GroundPlane(nn, float(d), tau, n_in, iters, rms, n0, source, history)


def local_layer_sigma(points: np.ndarray, plane: GroundPlane, cell_m: float, window_m: float,
                      min_points: int = 30) -> np.ndarray:
    """Per point, the ground layer's robust noise sigma (m) in its cell of the ground plane.

    points: (N, 3) metres. cell_m: cell size in the plane (m). window_m: first search depth below the plane (m).
    Depth noise grows with range (Z^2 for stereo), so the ground seen far out is a thicker layer
    than the ground beside the truck; one global thickness either cuts into the truck or leaves
    far noise standing as clutter. Only points BELOW the plane are used: nothing stands under the
    ground, so walls, wheels and clutter in a cell do not inflate its sigma (half-normal: sigma =
    1.4826 x the median depth below the plane). The window follows each cell's sigma (5 sigma, a
    few passes: a window that truncates the layer reads it thinner).
    Cells with fewer than ``min_points`` points below the plane get the median sigma of the cells.
    """
    p = np.asarray(points, dtype=np.float64)
    h = p @ plane.normal + plane.offset
    e1, e2 = plane_axes(plane.normal)
    _, inv = np.unique(_cell_keys(p @ e1, p @ e2, cell_m), return_inverse=True)
    n_cells = int(inv.max()) + 1
    # Depths below the plane, sorted once by (cell, depth): each pass then only counts, per cell,
    # the depths inside its window and takes the middle one.
    neg = np.flatnonzero(h < 0)
    cell, depth = inv[neg], -h[neg]
    order = np.lexsort((depth, cell))
    cell, depth = cell[order], depth[order]
    starts = np.searchsorted(cell, np.arange(n_cells))
    span = float(depth.max()) + 1.0 if len(depth) else 1.0
    combined = cell * span + depth          # sorted: cell first, then depth
    win = np.full(n_cells, float(window_m))
    for _ in range(4):
        cnt = np.searchsorted(combined, np.arange(n_cells) * span + win, side="right") - starts
        ok = cnt >= min_points
        med = np.full(n_cells, np.nan)
        med[ok] = depth[starts[ok] + cnt[ok] // 2]
        sigma = 1.4826 * med
        fill = float(np.nanmedian(sigma)) if np.isfinite(sigma).any() else float(window_m) / 4
        sigma = np.where(np.isfinite(sigma), sigma, fill)
        win = np.maximum(5.0 * sigma, float(window_m))
    return sigma[inv]


def remove_ground(points: np.ndarray, plane: GroundPlane, thickness_m: float) -> np.ndarray:
    """Mask of points kept above the ground layer: height > ``thickness_m`` (d_h); points below
    the ground (beyond −d_h, reconstruction noise) are dropped too. Returns (N,) bool."""
    h = plane.height(points)
    return h > thickness_m
