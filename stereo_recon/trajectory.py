"""Camera trajectories: the TUM ``poses.txt`` format, Umeyama alignment, trajectory errors and 'up'.

Poses are world-from-left-camera (``X_world = R_wc @ X_cam + t_wc``), metres, OpenCV camera axes
(x right, y down, z forward); see :mod:`stereo_recon.core.conventions`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereo_recon.core.atomic import write_text_atomic
from stereo_recon.core.errors import InputError
from stereo_recon.core.geometry import plane_axes

log = logging.getLogger(__name__)


@dataclass
class Trajectory:
    """A sequence of camera poses.

    indices: (N,) int frame indices in the source video.
    timestamps_s: (N,) float seconds (TUM timestamp; frame index / fps for videos).
    T_wc: (N, 4, 4) float world-from-left-camera poses, metres.
    stats: free-form counts and diagnostics (tracking gaps, loop closures, scale spread ...).
    """

    indices: np.ndarray
    timestamps_s: np.ndarray
    T_wc: np.ndarray
    stats: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.indices = np.asarray(self.indices, dtype=np.int64).reshape(-1)
        self.timestamps_s = np.asarray(self.timestamps_s, dtype=np.float64).reshape(-1)
        self.T_wc = np.asarray(self.T_wc, dtype=np.float64).reshape(-1, 4, 4)
        n = len(self.T_wc)
        if len(self.indices) != n or len(self.timestamps_s) != n:
            raise ValueError(
                f"Trajectory: {len(self.indices)} indices, {len(self.timestamps_s)} timestamps, {n} poses"
            )

    def __len__(self) -> int:
        return len(self.T_wc)

    @property
    def centres_m(self) -> np.ndarray:
        """(N, 3) camera centres in the world frame, metres."""
        return self.T_wc[:, :3, 3].copy()

    def path_length_m(self) -> float:
        """Sum of the distances between consecutive camera centres, metres."""
        c = self.centres_m
        return float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) if len(c) > 1 else 0.0

    def subset(self, mask_or_idx) -> "Trajectory":
        """The poses selected by a boolean mask or an index array (stats kept)."""
        sel = np.asarray(mask_or_idx)
        return Trajectory(self.indices[sel], self.timestamps_s[sel], self.T_wc[sel], dict(self.stats))

    def transformed(self, s: float, R: np.ndarray, t: np.ndarray) -> "Trajectory":
        """Poses mapped by the similarity ``X -> s R X + t`` (camera rotations stay orthonormal)."""
        T = self.T_wc.copy()
        T[:, :3, :3] = R @ self.T_wc[:, :3, :3]
        T[:, :3, 3] = s * (self.T_wc[:, :3, 3] @ R.T) + t
        return Trajectory(self.indices.copy(), self.timestamps_s.copy(), T, dict(self.stats))


# ----------------------------------------------------------------------------------------- TUM I/O


def _quat_xyzw_from_R(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()  # scipy order is (x, y, z, w), as TUM


def write_tum(path, traj: Trajectory) -> Path:
    """Write ``timestamp tx ty tz qx qy qz qw`` lines (TUM RGB-D format, evo-readable); atomic.

    path: output file. traj: world-from-left-camera poses, metres.
    """
    path = Path(path)
    q = _quat_xyzw_from_R(traj.T_wc[:, :3, :3]) if len(traj) else np.zeros((0, 4))
    lines = ["# timestamp tx ty tz qx qy qz qw  (world-from-left-camera, metres)"]
    for ts, T, qi in zip(traj.timestamps_s, traj.T_wc, q):
        t = T[:3, 3]
        lines.append(
            f"{ts:.6f} {t[0]:.9f} {t[1]:.9f} {t[2]:.9f} {qi[0]:.9f} {qi[1]:.9f} {qi[2]:.9f} {qi[3]:.9f}"
        )
    return write_text_atomic(path, "\n".join(lines) + "\n", encoding=None)


def read_tum(path, fps: float | None = None) -> Trajectory:
    """Read a TUM trajectory file (``#`` comments and blank lines skipped).

    fps: if given, frame indices are ``round(timestamp * fps)``; else 0..N-1.
    Raises InputError naming the file and line for malformed content.
    """
    from scipy.spatial.transform import Rotation

    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise InputError(f"{path}: cannot read trajectory ({err.strerror or err})") from err
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            raise InputError(f"{path}:{lineno}: expected 8 numbers 'timestamp tx ty tz qx qy qz qw', got {len(parts)}")
        try:
            vals = [float(p) for p in parts]
        except ValueError as err:
            raise InputError(f"{path}:{lineno}: not a number ({err})") from err
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path}:{lineno}: non-finite value")
        if np.linalg.norm(vals[4:]) < 1e-9:
            raise InputError(f"{path}:{lineno}: zero quaternion")
        rows.append(vals)
    if not rows:
        raise InputError(f"{path}: no poses in file")
    a = np.asarray(rows, dtype=np.float64)
    T = np.tile(np.eye(4), (len(a), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(a[:, 4:8]).as_matrix()
    T[:, :3, 3] = a[:, 1:4]
    idx = np.rint(a[:, 0] * fps).astype(np.int64) if fps else np.arange(len(a))
    return Trajectory(idx, a[:, 0], T)


# ------------------------------------------------------------------------------------- alignment


def align_umeyama(src_xyz: np.ndarray, dst_xyz: np.ndarray, with_scale: bool = True):
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama 1991, eqs. 40-42).

    src_xyz, dst_xyz: (N, 3) corresponding points, N >= 3 (not all collinear for a unique R).
    Returns (s, R (3,3), t (3,)); s = 1 when with_scale is False.
    """
    src = np.asarray(src_xyz, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst_xyz, dtype=np.float64).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise ValueError(f"align_umeyama: need >= 3 corresponding points, got {len(src)} and {len(dst)}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)  # eq. 38
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:  # eq. 39: keep a proper rotation
        S[2, 2] = -1.0
    R = U @ S @ Vt  # eq. 40
    if with_scale:
        var_s = (xs**2).sum() / len(src)  # eq. 36
        s = float(np.trace(np.diag(D) @ S) / var_s) if var_s > 0 else 1.0  # eq. 42
    else:
        s = 1.0
    t = mu_d - s * R @ mu_s  # eq. 41
    return s, R, t


def _associate(est: Trajectory, gt: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (into est, into gt) of poses sharing a frame index."""
    common, ie, ig = np.intersect1d(est.indices, gt.indices, return_indices=True)
    if len(common) < 3:
        raise ValueError(f"trajectories share only {len(common)} frame indices (need >= 3)")
    return ie, ig


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle (deg) of one (3, 3) rotation matrix, from its trace (as the pose selectors compare it)."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _rot_angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angles (deg) of (N,3,3) matrices; via quaternions, exact near 0 unlike arccos of the trace."""
    from scipy.spatial.transform import Rotation

    return np.degrees(Rotation.from_matrix(R).magnitude())


def absolute_trajectory_error(est: Trajectory, gt: Trajectory, with_scale: bool = True) -> dict:
    """ATE of the camera centres after Umeyama alignment of est onto gt (frames matched by index).

    Returns rmse_m, mean_m, median_m, max_m, the same relative to gt's path length
    (rmse_rel_path ...), path_length_m, scale (s of the alignment; 1 without scale),
    rotation errors after alignment (rot_rmse_deg, rot_max_deg) and n (poses compared).
    """
    ie, ig = _associate(est, gt)
    e, g = est.subset(ie), gt.subset(ig)
    s, R, t = align_umeyama(e.centres_m, g.centres_m, with_scale=with_scale)
    al = e.transformed(s, R, t)
    err = np.linalg.norm(al.centres_m - g.centres_m, axis=1)
    rot = _rot_angle_deg(np.swapaxes(g.T_wc[:, :3, :3], 1, 2) @ al.T_wc[:, :3, :3])
    L = g.path_length_m()
    rel = (lambda v: float(v / L)) if L > 0 else (lambda v: float("nan"))
    out = {
        "n": int(len(err)),
        "rmse_m": float(np.sqrt(np.mean(err**2))),
        "mean_m": float(err.mean()),
        "median_m": float(np.median(err)),
        "max_m": float(err.max()),
        "path_length_m": float(L),
        "scale": float(s),
        "rot_rmse_deg": float(np.sqrt(np.mean(rot**2))),
        "rot_max_deg": float(rot.max()),
    }
    out.update(
        rmse_rel_path=rel(out["rmse_m"]), median_rel_path=rel(out["median_m"]), max_rel_path=rel(out["max_m"])
    )
    return out


def relative_pose_error(est: Trajectory, gt: Trajectory, delta: int = 1) -> dict:
    """RPE over pose pairs ``delta`` apart (in the common frames): translation (m) and rotation (deg).

    Scale-sensitive: est must be metric (no alignment is needed, RPE is frame-independent).
    Returns trans_rmse_m, trans_median_m, trans_max_m, rot_rmse_deg, rot_max_deg, n.
    """
    ie, ig = _associate(est, gt)
    E, G = est.T_wc[ie], gt.T_wc[ig]
    if len(E) <= delta:
        raise ValueError(f"relative_pose_error: {len(E)} poses, delta {delta}")
    inv = np.linalg.inv
    dE = inv(E[:-delta]) @ E[delta:]
    dG = inv(G[:-delta]) @ G[delta:]
    D = inv(dG) @ dE
    tr = np.linalg.norm(D[:, :3, 3], axis=1)
    rot = _rot_angle_deg(D[:, :3, :3])
    return {
        "n": int(len(D)),
        "delta": int(delta),
        "trans_rmse_m": float(np.sqrt(np.mean(tr**2))),
        "trans_median_m": float(np.median(tr)),
        "trans_max_m": float(tr.max()),
        "rot_rmse_deg": float(np.sqrt(np.mean(rot**2))),
        "rot_max_deg": float(rot.max()),
    }


def align_trajectories(est: Trajectory, gt: Trajectory, with_scale: bool = True):
    """Similarity (s, R, t) with gt centre ~ s R est centre + t, frames matched by index (Umeyama).

    Maps est's world frame onto gt's: apply it to anything est's run produced (its cloud) to
    compare with gt's world.
    """
    ie, ig = _associate(est, gt)
    return align_umeyama(est.centres_m[ie], gt.centres_m[ig], with_scale=with_scale)


def graft_poses(base: Trajectory, refined: Trajectory, keep_refined_scale: bool = False) -> tuple[Trajectory, dict]:
    """base's trajectory with the poses of the frames ``refined`` has replaced by refined's, in base's world.

    refined (e.g. bundle-adjusted poses of a subset of frames) is mapped onto base's world frame and
    scale by the similarity of their common camera centres; the frames only base has get the
    correction (refined-from-base) of the nearest refined frame by index, so the whole trajectory
    stays smooth. keep_refined_scale: then scale the whole result by 1 / the similarity's scale about base's
    world origin, so the trajectory has refined's scale (a metric bundle adjustment's) in base's world frame.
    Returns (trajectory, stats with the similarity's scale and the corrections' size, both against base at its
    own scale: median moved (m, and as a fraction of the rms distance of base's common centres from their mean)
    and turned (deg)).
    """
    ib, ir = _associate(base, refined)  # ValueError below 3 common frames
    s, R, t = align_umeyama(refined.centres_m[ir], base.centres_m[ib], with_scale=True)
    new = refined.transformed(s, R, t).T_wc[ir]
    corr = new @ np.linalg.inv(base.T_wc[ib])  # world-from-world corrections of the refined frames
    nearest = np.abs(base.indices[:, None] - base.indices[ib][None, :]).argmin(axis=1)
    T = corr[nearest] @ base.T_wc
    T[ib] = new
    moved = np.linalg.norm(new[:, :3, 3] - base.T_wc[ib, :3, 3], axis=1)
    turned = _rot_angle_deg(np.einsum("nji,njk->nik", base.T_wc[ib, :3, :3], new[:, :3, :3]))
    c = base.T_wc[ib, :3, 3]
    radius = float(np.sqrt(((c - c.mean(axis=0)) ** 2).sum(axis=1).mean()))  # the path's rms radius (m)
    moved_m = float(np.median(moved))
    stats = {"grafted_frames": int(len(ib)), "similarity_scale": float(s),
             "moved_m_median": moved_m, "turned_deg_median": float(np.median(turned)),
             "moved_rel_median": moved_m / radius if radius > 0 else float("inf")}
    if keep_refined_scale:
        T[:, :3, 3] /= s
    return Trajectory(base.indices.copy(), base.timestamps_s.copy(), T, dict(base.stats)), stats


def scale_error(est: Trajectory, gt: Trajectory) -> float:
    """Relative scale error ``s - 1`` of the similarity aligning est onto gt (0 for a perfectly metric est)."""
    s, _, _ = align_trajectories(est, gt)
    return float(1.0 / s - 1.0)


# ------------------------------------------------------------------------------------------- up


def up_from_trajectory(traj: Trajectory, collinear_ratio: float = 0.05) -> np.ndarray:
    """Ground normal (unit, world frame) from the camera centres of an orbit.

    The normal of the least-squares plane of the centres (smallest singular vector), oriented so
    that it points against the mean camera +y axis (a camera's y axis points down). When the
    centres are nearly collinear or too few (second singular value < collinear_ratio of the first),
    falls back to ``-mean(camera y axis)``.
    """
    if len(traj) == 0:
        raise ValueError("up_from_trajectory: empty trajectory")
    y_mean = traj.T_wc[:, :3, 1].mean(axis=0)  # camera +y (down) in the world, averaged
    down = y_mean / max(np.linalg.norm(y_mean), 1e-12)
    c = traj.centres_m
    if len(c) >= 3:
        X = c - c.mean(0)
        _, sv, Vt = np.linalg.svd(X, full_matrices=False)
        if sv[0] > 0 and sv[1] > collinear_ratio * sv[0]:
            n = Vt[2]
            n = n / np.linalg.norm(n)
            return -n if n @ down > 0 else n
    log.debug("up_from_trajectory: centres nearly collinear, using -mean camera y")
    return -down


def orbit_centre(centres: np.ndarray, up: np.ndarray | None = None, max_radius_rel: float = 10.0,
                 max_residual_rel: float = 0.2) -> np.ndarray:
    """Centre (3,) of the circle the camera centres fly around, m (world frame); their mean when they do not orbit.

    centres: (N, 3) camera centres, m; up: world up (None: +z). The circle is fitted in the plane normal to
    up (algebraic least squares, Kasa's fit) and placed at the cameras' mean height. Why not the mean: on a
    partial orbit the mean lies inside the arc, towards its middle (0.41 x the radius for 240 deg, 0.37 m
    off a model tanker's centre on a 294 deg arc of seed 2033, which put the hint nearer a second vehicle).
    Falls back to the mean with fewer than 5 centres, a radius over ``max_radius_rel`` x the centres' spread
    (a straight pass) or an rms residual over ``max_residual_rel`` x the radius (not an orbit).
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    mean = c.mean(axis=0)
    if len(c) < 5:
        return mean
    u = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    a, b = plane_axes(u)
    d = c - mean
    x, y = d @ a, d @ b
    A = np.column_stack([x, y, np.ones_like(x)])
    sol, *_ = np.linalg.lstsq(A, x * x + y * y, rcond=None)
    cx, cy = sol[0] / 2, sol[1] / 2
    r2 = sol[2] + cx * cx + cy * cy
    spread = float(np.sqrt(np.mean(x * x + y * y)))
    if not r2 > 0 or spread <= 0:
        return mean
    r = float(np.sqrt(r2))
    resid = float(np.sqrt(np.mean((np.hypot(x - cx, y - cy) - r) ** 2)))
    if r > max_radius_rel * spread or resid > max_residual_rel * r:
        return mean
    return mean + cx * a + cy * b
