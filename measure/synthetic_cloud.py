"""Synthetic truck scenes as point clouds, with the truth exact by construction.

Used by the tests and the benchmarks of the ``measure`` package. A truck is a cab, a gap and
a cargo box (or a flatbed) on wheels, standing on a ground plane; its surfaces are sampled
uniformly at a chosen point spacing. The scene can be tilted and rotated arbitrarily, and can
carry noise, outliers, distractor objects, a second vehicle nearby and faces that are only
partly seen.

Truck frame (before the scene pose): x along the length (rear at x = 0, front at x = length),
y across (centred), z up, ground at z = 0. The outer contour is the axis-aligned box
``[0, length] x [-width/2, width/2] x [0, height]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class TruckShape:
    """Outer dimensions and parts of a synthetic truck (metres).

    The box is the widest and tallest part unless ``cab_width_m``/``cab_height_m`` say otherwise;
    the truth is the bounding box of all parts.
    """

    length_m: float = 12.0          # rear of the box to the front of the cab
    width_m: float = 2.55           # overall width (the wider of box and cab)
    height_m: float = 4.0           # ground to the highest roof
    cab_length_m: float | None = None   # default: 0.18 x length
    gap_m: float | None = None          # between cab and box; default 0.02 x length
    cab_width_m: float | None = None    # default: width (a narrower cab is allowed)
    cab_height_m: float | None = None   # default: 0.8 x height
    clearance_m: float | None = None    # ground to the underside of the body; default 0.25 x height
    wheel_radius_m: float | None = None  # default: 0.8 x clearance
    flatbed: bool = False           # True: the cargo part is a low platform (height clearance + 0.05 x height), no box
    chassis_rails: bool = True      # False: nothing joins cab and box across the gap (two FoF clusters)

    def resolved(self) -> dict:
        """The shape with every default filled in (metres)."""
        L, W, H = self.length_m, self.width_m, self.height_m
        clearance = self.clearance_m if self.clearance_m is not None else 0.25 * H
        return {
            "length_m": L,
            "width_m": W,
            "height_m": H,
            "cab_length_m": self.cab_length_m if self.cab_length_m is not None else 0.18 * L,
            "gap_m": self.gap_m if self.gap_m is not None else 0.02 * L,
            "cab_width_m": self.cab_width_m if self.cab_width_m is not None else W,
            "cab_height_m": self.cab_height_m if self.cab_height_m is not None else 0.8 * H,
            "clearance_m": clearance,
            "wheel_radius_m": self.wheel_radius_m if self.wheel_radius_m is not None else 0.8 * clearance,
            "flatbed": self.flatbed,
            "chassis_rails": self.chassis_rails,
        }


MODEL_TRUCK = TruckShape(length_m=2.1, width_m=0.38, height_m=0.38)
FULL_TRUCK = TruckShape(length_m=12.0, width_m=2.55, height_m=4.0)


@dataclass(frozen=True)
class SceneSpec:
    """What goes into a synthetic scene besides the truck (spacings and distances in metres)."""

    spacing_m: float = 0.05               # mean point spacing on every surface
    noise_m: float = 0.0                  # Gaussian noise, standard deviation per axis
    outlier_fraction: float = 0.0         # uniform outliers in the scene box, fraction of all points
    ground_margin: float = 0.6            # ground extends this many truck lengths beyond the truck
    tilt_deg: float = 0.0                 # tilt of the ground normal from the frame's up axis
    yaw_deg: float = 30.0                 # truck heading in the ground plane
    camera_frame: bool = False            # True: express the scene in an OpenCV-like frame (up = -y)
    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    second_vehicle_gap_m: float | None = None   # a parked box-shaped vehicle beside the truck at this gap
    second_vehicle_scraps_m: tuple[float, float] | None = None  # ground scraps standing between these heights fill
                                          # that gap along the vehicle, twice the surfaces' density (label 0): they
                                          # link the two into one FoF cluster, as a narrow gap's do in a fused cloud
    distractors: int = 0                  # small objects (posts, cones, boxes) scattered on the ground
    partial_faces: dict[str, float] = field(default_factory=dict)  # face name -> fraction of points kept
    density_gradient: float = 0.0         # 0: uniform; g: density varies by factor (1+g) front-to-back


def _grid_2d(rng, nu, nv, jitter):
    """Stratified samples in the unit square: one per cell of an nu x nv grid, jittered within it."""
    s, t = np.meshgrid((np.arange(nu) + 0.5) / nu, (np.arange(nv) + 0.5) / nv, indexing="ij")
    st = np.stack([s.ravel(), t.ravel()], axis=1)
    st += (rng.random(st.shape) - 0.5) * jitter / np.array([nu, nv])
    return st


def _sample_rect(rng, origin, u, v, spacing_m, keep=1.0, jitter=0.8):
    """Points on the parallelogram origin + s*u + t*v, s,t in [0,1], one per spacing² of area.

    Stratified (a jittered grid), like the voxel-filtered or fused clouds a reconstruction
    produces; ``keep`` < 1 drops a random share (a partly seen face).
    """
    nu = max(int(round(np.linalg.norm(u) / spacing_m)), 1)
    nv = max(int(round(np.linalg.norm(v) / spacing_m)), 1)
    st = _grid_2d(rng, nu, nv, jitter)
    if keep < 1.0:
        st = st[rng.random(len(st)) < keep]
    return np.asarray(origin) + st[:, :1] * np.asarray(u) + st[:, 1:] * np.asarray(v)


def _sample_box(rng, lo, hi, spacing_m, faces=("top", "left", "right", "front", "rear"), keep=None, prefix=""):
    """Points on the faces of an axis-aligned box (no bottom unless asked); returns dict face -> (n,3)."""
    keep = keep or {}
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    dx, dy, dz = hi - lo
    ex, ey, ez = np.array([dx, 0, 0]), np.array([0, dy, 0]), np.array([0, 0, dz])
    spec = {
        "top": (lo + ez, ex, ey),
        "bottom": (lo, ex, ey),
        "left": (lo + ey, ex, ez),    # y = hi
        "right": (lo, ex, ez),        # y = lo
        "front": (lo + ex, ey, ez),   # x = hi
        "rear": (lo, ey, ez),         # x = lo
    }
    return {prefix + f: _sample_rect(rng, *spec[f], spacing_m, keep.get(prefix + f, 1.0)) for f in faces}


def _sample_disc(rng, centre, radius, normal_axis, spacing_m, jitter=0.8):
    """Stratified points on a disc of ``radius`` around ``centre``, normal along axis ``normal_axis``."""
    n = max(int(round(2 * radius / spacing_m)), 1)
    st = (_grid_2d(rng, n, n, jitter) - 0.5) * 2 * radius
    st = st[np.einsum("ij,ij->i", st, st) <= radius**2]
    p = np.zeros((len(st), 3))
    axes = [i for i in range(3) if i != normal_axis]
    p[:, axes[0]] = st[:, 0]
    p[:, axes[1]] = st[:, 1]
    return p + np.asarray(centre)


def truck_surface_points(shape: TruckShape, spacing_m: float, rng=None, partial_faces: dict | None = None) -> dict[str, np.ndarray]:
    """Sample the visible surfaces of a truck in the truck frame; returns part name -> (n, 3) points.

    The outer contour is ``[0, L] x [-W/2, W/2] x [0, H]``; wheels touch the ground at z = 0.
    """
    rng = np.random.default_rng(rng)
    s = shape.resolved()
    L, W, H = s["length_m"], s["width_m"], s["height_m"]
    cab_l, gap, cab_w, cab_h = s["cab_length_m"], s["gap_m"], s["cab_width_m"], s["cab_height_m"]
    clr, wr = s["clearance_m"], s["wheel_radius_m"]
    box_l = L - cab_l - gap
    box_w = W
    parts: dict[str, np.ndarray] = {}
    pf = partial_faces or {}
    if s["flatbed"]:
        box_top = clr + 0.05 * H
    else:
        box_top = H
    parts.update(_sample_box(rng, (0, -box_w / 2, clr), (box_l, box_w / 2, box_top), spacing_m, keep=pf, prefix="box_"))
    parts.update(_sample_box(rng, (L - cab_l, -cab_w / 2, clr), (L, cab_w / 2, cab_h if s["flatbed"] is False else H), spacing_m, keep=pf, prefix="cab_"))
    # Side rails of the chassis below the body, from the rear to the front axle: they join the
    # cab and the box as on a real truck (otherwise the gap would split them into two clusters).
    rail_y = min(box_w, cab_w) / 2 - 0.04 * W
    for side, y in (("l", rail_y), ("r", -rail_y)) if s["chassis_rails"] else ():
        parts[f"rail_{side}"] = _sample_rect(rng, (0.0, y, 0.6 * clr), (L - 0.3 * cab_l, 0, 0), (0, 0, 0.4 * clr), spacing_m)
    # Wheels: discs on both sides, just inside the body's outline.
    wheel_y = min(box_w, cab_w) / 2 - 0.02 * W
    for i, x in enumerate((0.15 * L, 0.15 * L + 2.2 * wr, L - 0.5 * cab_l)):
        for side, y in (("l", wheel_y), ("r", -wheel_y)):
            parts[f"wheel_{i}{side}"] = _sample_disc(rng, (x, y, wr), wr, 1, spacing_m)
    return parts


def truck_truth(shape: TruckShape) -> dict[str, float]:
    """The outer contour of ``shape`` (metres), exact by construction."""
    s = shape.resolved()
    H = s["height_m"] if not s["flatbed"] else s["height_m"]
    return {"length_m": s["length_m"], "width_m": max(s["width_m"], s["cab_width_m"]), "height_m": H}


def _rotation_from_to(a, b):
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else -np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * (1 / (1 + c))


def _distractors(rng: np.random.Generator, spec: SceneSpec, L: float, W: float, glo: np.ndarray,
                 ghi: np.ndarray) -> list[np.ndarray]:
    """Posts and small boxes on the ground (m), away from a truck of length L and width W."""
    d_parts = []
    for _ in range(spec.distractors):
        for _try in range(50):
            c = glo[:2] + rng.random(2) * (ghi[:2] - glo[:2])
            if not (-0.3 * L < c[0] < 1.3 * L and -W * 2.5 < c[1] < W * 2.5):
                break
        size = np.array([0.05, 0.05, 0.3]) * L * rng.uniform(0.3, 1.0, 3)
        d = np.concatenate(list(_sample_box(rng, (c[0], c[1], 0), (c[0] + size[0], c[1] + size[1], size[2]),
                                            spec.spacing_m).values()))
        d_parts.append(d)
    return d_parts


def _degrade(pts: np.ndarray, lab: np.ndarray, rng: np.random.Generator, spec: SceneSpec, glo: np.ndarray,
             ghi: np.ndarray, H: float) -> tuple[np.ndarray, np.ndarray]:
    """The cloud as a reconstruction delivers it: thinned towards the rear, noisy, with outliers (label 4)."""
    if spec.density_gradient > 0:
        # Thin points out towards the rear: keep probability from 1/(1+g) at the rear to 1 at the front.
        t = np.clip((pts[:, 0] - glo[0]) / (ghi[0] - glo[0]), 0, 1)
        keep_p = (1 + spec.density_gradient * t) / (1 + spec.density_gradient)
        keep = rng.random(len(pts)) < keep_p
        pts, lab = pts[keep], lab[keep]
    if spec.noise_m > 0:
        pts = pts + rng.normal(0, spec.noise_m, pts.shape)
    if spec.outlier_fraction > 0:
        n_out = int(spec.outlier_fraction * len(pts))
        lo = np.array([glo[0], glo[1], -0.2 * H])
        hi = np.array([ghi[0], ghi[1], 1.5 * H])
        out = lo + rng.random((n_out, 3)) * (hi - lo)
        pts = np.concatenate([pts, out])
        lab = np.concatenate([lab, np.full(n_out, 4)])
    return pts, lab


def _scene_rotation(spec: SceneSpec) -> np.ndarray:
    """Output-from-truck rotation: yaw about up, then tilt the up axis, then optional camera-like axes."""
    yaw = np.deg2rad(spec.yaw_deg)
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    tilt_axis = np.array([np.cos(0.7), np.sin(0.7), 0.0])
    t = np.deg2rad(spec.tilt_deg)
    up = np.cos(t) * np.array([0, 0, 1.0]) + np.sin(t) * np.cross(tilt_axis, [0, 0, 1.0])
    Rt = _rotation_from_to(np.array([0, 0, 1.0]), up)
    R = Rt @ Rz
    if spec.camera_frame:
        # Truck-frame z (up) becomes -y (OpenCV camera y points down); x stays, y -> z.
        C = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
        R = C @ R
    return R


def make_truck_scene(shape: TruckShape = FULL_TRUCK, spec: SceneSpec = SceneSpec(), rng=None) -> tuple[np.ndarray, dict]:
    """A truck on ground with optional clutter, as an (N, 3) float64 cloud plus its truth.

    Returns ``(points, truth)``; truth holds ``length_m``, ``width_m``, ``height_m``, ``up``
    (unit ground normal in the output frame), ``ground_offset`` (``up @ p`` on the ground),
    ``truck_centre`` (output frame), ``heading`` (unit length axis, output frame),
    ``labels`` (per point: 0 ground, 1 truck, 2 second vehicle, 3 distractor, 4 outlier).
    """
    rng = np.random.default_rng(rng)
    truth = truck_truth(shape)
    L, W, H = truth["length_m"], truth["width_m"], truth["height_m"]
    sp = spec.spacing_m
    truck = np.concatenate(list(truck_surface_points(shape, sp, rng, spec.partial_faces).values()))
    clouds = [truck]
    labels = [np.full(len(truck), 1)]
    # Second vehicle: a plain box parked alongside, slightly shorter and lower.
    if spec.second_vehicle_gap_m is not None:
        g = spec.second_vehicle_gap_m
        lo = (0.1 * L, W / 2 + g, 0.0)
        hi = (0.1 * L + 0.7 * L, W / 2 + g + 0.9 * W, 0.85 * H)
        other = np.concatenate(list(_sample_box(rng, lo, hi, sp).values()))
        clouds.append(other)
        labels.append(np.full(len(other), 2))
        if spec.second_vehicle_scraps_m is not None:
            n = int(2 * 0.7 * L * g / sp**2)
            scraps = np.c_[rng.uniform(0.1 * L, 0.8 * L, n), rng.uniform(W / 2, W / 2 + g, n),
                           rng.uniform(*spec.second_vehicle_scraps_m, n)]
            clouds.append(scraps)
            labels.append(np.full(n, 0))
    margin = spec.ground_margin * L
    glo = np.array([-margin, -W / 2 - margin, 0.0])
    ghi = np.array([L + margin, W / 2 + margin, 0.0])
    d_parts = _distractors(rng, spec, L, W, glo, ghi)
    if d_parts:
        d = np.concatenate(d_parts)
        clouds.append(d)
        labels.append(np.full(len(d), 3))
    ground = _sample_rect(rng, glo, np.array([ghi[0] - glo[0], 0, 0]), np.array([0, ghi[1] - glo[1], 0]), sp)
    # Nothing is seen under the truck's body.
    under = (ground[:, 0] > 0) & (ground[:, 0] < L) & (np.abs(ground[:, 1]) < W / 2)
    ground = ground[~under]
    clouds.append(ground)
    labels.append(np.full(len(ground), 0))
    pts, lab = _degrade(np.concatenate(clouds), np.concatenate(labels), rng, spec, glo, ghi, H)
    # Scene pose: the rotation, then shift.
    centre_local = np.array([L / 2, 0.0, H / 2])
    R = _scene_rotation(spec)
    tr = np.asarray(spec.translation_m, float)
    out_pts = pts @ R.T + tr
    perm = rng.permutation(len(out_pts))
    out_pts, lab = out_pts[perm], lab[perm]
    up_out = R @ np.array([0, 0, 1.0])
    truth.update(
        {
            "up": up_out,
            "ground_offset": float(up_out @ tr),
            "truck_centre": R @ centre_local + tr,
            "heading": R @ np.array([1.0, 0, 0]),
            "labels": lab,
            "rotation": R,
            "translation": tr,
        }
    )
    return out_pts, truth


def scene_with_n_points(n_points: int, shape: TruckShape = FULL_TRUCK, rng=0, **spec_kw) -> tuple[np.ndarray, dict]:
    """A scene of about ``n_points`` points: the spacing is chosen from the sampled area."""
    spec = SceneSpec(spacing_m=0.1, **spec_kw)
    pts, _ = make_truck_scene(shape, spec, rng=rng)
    spacing = 0.1 * np.sqrt(len(pts) / n_points)
    return make_truck_scene(shape, SceneSpec(spacing_m=float(spacing), **spec_kw), rng=rng)
