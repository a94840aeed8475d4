"""Synthetic scenes: textured ground, a parametric truck with exact outer dimensions, distractors.

World frame: right-handed, metres, ``z`` up, the ground is the plane ``z = 0``.
Truck frame: origin on the ground at the centre of the truck's footprint, ``x`` toward the
front (rear -> front), ``y`` to the left, ``z`` up. By construction the truck occupies exactly
``x in [-L/2, L/2]``, ``y in [-W/2, W/2]``, ``z in [0, H]`` (length front to rear, width the
largest lateral extent, no mirrors; height the top above the ground) and every one of the six
bounds is reached by some component.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from stereo_recon.synthetic.mesh import Mesh, box, cylinder_y, cylinder_z, pose, rot_z
from stereo_recon.synthetic.texture import Material

log = logging.getLogger(__name__)

BODY_TYPES = ("box", "flatbed", "semi")


@dataclass(frozen=True)
class TruckSpec:
    """A parametric truck.

    length_m / width_m / height_m: exact outer dimensions (see the module docstring).
    body: "box" (cargo box), "flatbed" (low deck with a load of crates) or "semi" (tractor and
        a box semi-trailer).
    cab_rgb / body_rgb: paint colours (0..1 RGB); the cargo panels are weakly textured paint.
    stripe: paint a horizontal band (lettering-like) on the cargo box.
    """

    length_m: float = 12.0
    width_m: float = 2.55
    height_m: float = 4.0
    body: str = "box"
    cab_rgb: tuple[float, float, float] = (0.75, 0.12, 0.10)
    body_rgb: tuple[float, float, float] = (0.82, 0.82, 0.80)
    stripe: bool = True

    def __post_init__(self) -> None:
        if self.body not in BODY_TYPES:
            raise ValueError(f"TruckSpec.body must be one of {BODY_TYPES}, got {self.body!r}")
        if min(self.length_m, self.width_m, self.height_m) <= 0:
            raise ValueError("TruckSpec: dimensions must be positive")
        if self.length_m < 1.5 * self.width_m:
            raise ValueError(f"TruckSpec: length {self.length_m} m too short for width {self.width_m} m")


def truck_materials(spec: TruckSpec, texel_m: float, prefix: str = "truck") -> dict[str, Material]:
    """Materials of a truck (named ``<prefix>.<part>``); ``texel_m`` is the scene's noise texel."""
    H = spec.height_m
    return {
        f"{prefix}.cab": Material(f"{prefix}.cab", spec.cab_rgb, 0.05, texel_m, 0.6),
        f"{prefix}.glass": Material(f"{prefix}.glass", (0.10, 0.13, 0.16), 0.12, texel_m, 0.8),
        # Weakly textured painted cargo panels (the hard case for stereo matching), with a band.
        f"{prefix}.body": Material(
            f"{prefix}.body", spec.body_rgb, 0.035, texel_m, 0.7,
            pattern="band" if spec.stripe else "noise",
            params={"z_lo_m": 0.62 * H, "z_hi_m": 0.72 * H, "band_rgb": (0.10, 0.25, 0.55)} if spec.stripe else {},
        ),
        f"{prefix}.roof": Material(f"{prefix}.roof", tuple(0.9 * c for c in spec.body_rgb), 0.08, texel_m, 0.7),
        f"{prefix}.chassis": Material(f"{prefix}.chassis", (0.12, 0.12, 0.12), 0.15, texel_m, 0.3),
        f"{prefix}.tyre": Material(f"{prefix}.tyre", (0.06, 0.06, 0.06), 0.25, texel_m, 0.2),
        f"{prefix}.rim": Material(f"{prefix}.rim", (0.55, 0.55, 0.55), 0.1, texel_m, 0.3),
        f"{prefix}.deck": Material(f"{prefix}.deck", (0.45, 0.33, 0.20), 0.25, texel_m, 0.6),
        f"{prefix}.load": Material(f"{prefix}.load", (0.62, 0.50, 0.32), 0.2, texel_m, 0.5),
    }


def truck_mesh(spec: TruckSpec, prefix: str = "truck") -> Mesh:
    """Triangle mesh of the truck in the truck frame (see module docstring); materials ``<prefix>.*``."""
    L, W, H = spec.length_m, spec.width_m, spec.height_m
    m = lambda part: f"{prefix}.{part}"  # noqa: E731
    x_front, x_rear = L / 2, -L / 2
    r = min(0.125 * H, 0.2 * W, 0.06 * L)  # wheel radius
    z_frame0 = 0.85 * r  # chassis bottom
    z_floor = 2.15 * r  # cargo floor / chassis top
    wheel_w = 0.13 * W
    y_wheel_out = W / 2 - 0.03 * W  # wheels stay inside the body width
    mesh = Mesh()

    # Cab: lower cab box reaching the front, glazed upper part set back, roof on top.
    is_semi = spec.body == "semi"
    cab_len = min(max(0.16 * L, 1.1 * W), 0.3 * L) if not is_semi else min(max(0.14 * L, 1.0 * W), 0.25 * L)
    x_cab0 = x_front - cab_len
    if spec.body == "flatbed":
        cab_h = 0.85 * H  # the load is the tallest part
    elif is_semi:
        cab_h = 0.9 * H
    else:
        cab_h = 0.8 * H
    Wc = 0.97 * W
    z_sill = z_floor + 0.45 * (cab_h - z_floor)
    setback = 0.08 * cab_len
    roof_t = 0.06 * (cab_h - z_floor)
    mesh.extend(box((x_cab0, -Wc / 2, z_frame0), (x_front, Wc / 2, z_sill), m("cab")))
    mesh.extend(box((x_cab0, -0.98 * Wc / 2, z_sill), (x_front - setback, 0.98 * Wc / 2, cab_h - roof_t), m("glass")))
    mesh.extend(box((x_cab0, -Wc / 2, cab_h - roof_t), (x_front - setback, Wc / 2, cab_h), m("cab")))

    gap = max(0.015 * L, 0.08 * W)
    x_body_front = x_cab0 - gap
    # Chassis rails under everything.
    mesh.extend(box((x_rear + 0.04 * L, -0.36 * W, z_frame0), (x_cab0 + 0.5 * cab_len, 0.36 * W, z_floor), m("chassis")))

    axles = [x_front - 0.55 * cab_len]
    if spec.body == "box":
        mesh.extend(box((x_rear, -W / 2, z_floor), (x_body_front, W / 2, H), m("body"), top_material=m("roof")))
        axles += [x_rear + 0.22 * L, x_rear + 0.22 * L + 2.3 * r]
    elif spec.body == "flatbed":
        deck_t = 0.35 * r
        mesh.extend(box((x_rear, -W / 2, z_floor), (x_body_front, W / 2, z_floor + deck_t), m("deck")))
        # Load: crates along the deck; the middle one reaches the full height.
        n_crates = 3
        span = x_body_front - x_rear
        cl = span / n_crates
        heights = [0.78 * H, H, 0.9 * H]
        for i in range(n_crates):
            x0 = x_rear + i * cl + 0.04 * cl
            x1 = x_rear + (i + 1) * cl - 0.04 * cl
            mesh.extend(box((x0, -0.45 * W, z_floor + deck_t), (x1, 0.45 * W, heights[i]), m("load")))
        axles += [x_rear + 0.2 * L, x_rear + 0.2 * L + 2.3 * r]
    else:  # semi: box trailer over the tractor's fifth wheel, landing legs, tandem/tri-axle at the rear
        z_trailer = 2.6 * r
        mesh.extend(box((x_rear, -W / 2, z_trailer), (x_body_front, W / 2, H), m("body"), top_material=m("roof")))
        axles += [x_cab0 - 0.1 * cab_len, x_cab0 - 0.1 * cab_len - 2.3 * r]
        axles += [x_rear + 0.12 * L + k * 2.3 * r for k in range(3)]
        for s in (-1, 1):
            mesh.extend(box((x_body_front - 0.35 * L, s * 0.3 * W - 0.03 * W, 0.0), (x_body_front - 0.35 * L + 0.04 * W, s * 0.3 * W + 0.03 * W, z_trailer), m("chassis")))
    for xa in axles:
        for s in (-1, 1):
            y_out = s * y_wheel_out
            y_in = s * (y_wheel_out - wheel_w)
            y0, y1 = sorted((y_in, y_out))
            mesh.extend(cylinder_y((xa, r), r, y0, y1, m("tyre"), cap_material=m("rim")))
    lo, hi = mesh.bounds()
    expect_lo, expect_hi = np.array([-L / 2, -W / 2, 0.0]), np.array([L / 2, W / 2, H])
    if not (np.allclose(lo, expect_lo, atol=1e-9) and np.allclose(hi, expect_hi, atol=1e-9)):
        raise AssertionError(f"truck mesh bounds {lo}..{hi} differ from the spec {expect_lo}..{expect_hi}")
    return mesh


# ------------------------------------------------------------------------------- distractors


def _car_mesh(length: float, prefix: str) -> Mesh:
    """A simple car: body, cabin, four wheels (car frame like the truck frame)."""
    L, W, H = length, 0.42 * length, 0.33 * length
    r = 0.075 * length
    m = Mesh()
    m.extend(box((-L / 2, -W / 2, 0.6 * r), (L / 2, W / 2, 0.55 * H), f"{prefix}.paint"))
    m.extend(box((-0.3 * L, -0.45 * W, 0.55 * H), (0.2 * L, 0.45 * W, H), f"{prefix}.glass"))
    for xa in (-0.32 * L, 0.32 * L):
        for s in (-1, 1):
            y0, y1 = sorted((s * 0.48 * W, s * 0.33 * W))
            m.extend(cylinder_y((xa, r), r, y0, y1, f"{prefix}.tyre", segments=12))
    return m


@dataclass(frozen=True)
class Placed:
    """A placed object: its kind, 2-D footprint circle (world x, y, radius m) and yaw."""

    kind: str
    x_m: float
    y_m: float
    radius_m: float
    yaw_rad: float
    size_m: float


@dataclass
class Scene:
    """Everything the renderer needs: a world-frame mesh, its materials, lighting and the truth.

    mesh: world-frame triangle mesh (materials by name); materials: name -> Material.
    sun_dir: unit vector toward the sun (world); ambient / sun intensities are relative.
    sky_rgb: colour of rays that hit nothing (horizon to zenith blend).
    """

    mesh: Mesh
    materials: dict[str, Material]
    sun_dir: np.ndarray = field(default_factory=lambda: np.array([0.4, -0.3, 0.87]) / np.linalg.norm([0.4, -0.3, 0.87]))
    ambient: float = 0.38
    sun: float = 0.75
    sky_rgb: tuple[tuple[float, float, float], tuple[float, float, float]] = ((0.80, 0.85, 0.92), (0.45, 0.62, 0.90))
    scale_m: float = 1.0  # characteristic size (truck width), sets ray offsets
    info: dict = field(default_factory=dict)

    def material_table(self) -> tuple[list[Material], np.ndarray]:
        """(list of materials, (M,) int32 material index per triangle)."""
        names = sorted(set(self.mesh.materials))
        missing = [n for n in names if n not in self.materials]
        if missing:
            raise KeyError(f"scene: no material for {missing}")
        index = {n: i for i, n in enumerate(names)}
        ids = np.fromiter((index[n] for n in self.mesh.materials), np.int32, len(self.mesh.materials))
        return [self.materials[n] for n in names], ids


def ground_mesh(half_size_m: float, material: str = "ground") -> Mesh:
    """A square ground quad at z = 0 centred on the origin."""
    s = half_size_m
    return Mesh(np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0]], float), np.array([(0, 1, 2), (0, 2, 3)], np.int32), [material] * 2)


def ground_material(texel_m: float, scale_m: float, truck_length_m: float) -> Material:
    """Asphalt-like ground with painted parking-bay lines around the truck (all sizes follow ``scale_m``)."""
    return Material(
        "ground", (0.42, 0.41, 0.39), 0.28, texel_m, 0.45, pattern="bays",
        params={
            "line_width_m": 0.12 * scale_m,
            "spacing_m": 1.4 * scale_m,
            "y_lo_m": -2.3 * scale_m,
            "y_hi_m": 2.3 * scale_m,
            "x_extent_m": 0.75 * truck_length_m + 3 * scale_m,
            "x0_m": 0.0,
            "paint_rgb": (0.85, 0.83, 0.75),
        },
    )


DISTRACTOR_KINDS = ("car", "cone", "pole", "crate")


def place_distractors(n: int, scale_m: float, keep_out: list[tuple[float, float, float]], ring_m: tuple[float, float], max_height_m: float, rng) -> list[Placed]:
    """Rejection-sample ``n`` distractors on the ground, no footprint overlapping another or ``keep_out``.

    scale_m: truck width (sizes follow it); keep_out: circles (x, y, r) to avoid (the truck);
    ring_m: (r_min, r_max) distance from the origin; max_height_m: nothing taller (stays under the drone).
    """
    rng = np.random.default_rng(rng)
    placed: list[Placed] = []
    circles = list(keep_out)
    tries = 0
    while len(placed) < n and tries < 200 * max(n, 1):
        tries += 1
        kind = DISTRACTOR_KINDS[int(rng.integers(len(DISTRACTOR_KINDS)))]
        size = {"car": 1.7, "cone": 0.3, "pole": 0.12, "crate": 0.5}[kind] * scale_m * rng.uniform(0.85, 1.15)
        rad = {"car": 0.55 * size, "cone": 0.5 * size, "pole": 2.0 * size, "crate": 0.75 * size}[kind]
        ang = rng.uniform(0, 2 * np.pi)
        dist = rng.uniform(*ring_m)
        x, y = dist * np.cos(ang), dist * np.sin(ang)
        if any(np.hypot(x - cx, y - cy) < rad + cr for cx, cy, cr in circles):
            continue
        placed.append(Placed(kind, float(x), float(y), float(rad), float(rng.uniform(0, 2 * np.pi)), float(size)))
        circles.append((x, y, rad))
    if len(placed) < n:
        log.warning("placed only %d of %d distractors without overlap", len(placed), n)
    return placed


def distractor_mesh(p: Placed, index: int, max_height_m: float) -> Mesh:
    """World-frame mesh of one placed distractor."""
    pre = f"dis{index}"
    T = pose(rot_z(p.yaw_rad), (p.x_m, p.y_m, 0.0))
    if p.kind == "car":
        return _car_mesh(p.size_m, pre).transformed(T)
    if p.kind == "cone":
        return cylinder_z((p.x_m, p.y_m), 0.5 * p.size_m, 0.0, min(1.5 * p.size_m, max_height_m), f"{pre}.paint", top_radius=0.08 * p.size_m)
    if p.kind == "pole":
        return cylinder_z((p.x_m, p.y_m), p.size_m / 2, 0.0, min(18 * p.size_m, max_height_m), f"{pre}.paint")
    s = p.size_m
    return box((-s / 2, -s / 2, 0.0), (s / 2, s / 2, min(0.8 * s, max_height_m)), f"{pre}.paint").transformed(T)


def distractor_materials(p: Placed, index: int, texel_m: float, rng) -> dict[str, Material]:
    """Materials of one distractor (random paint for cars/crates, orange cones, grey poles)."""
    rng = np.random.default_rng(rng)
    pre = f"dis{index}"
    col = {"cone": (0.95, 0.40, 0.05), "pole": (0.55, 0.56, 0.58), "crate": (0.55, 0.42, 0.25)}.get(p.kind)
    if col is None:
        col = tuple(float(c) for c in rng.uniform(0.15, 0.85, 3))
    out = {f"{pre}.paint": Material(f"{pre}.paint", col, 0.2 if p.kind == "crate" else 0.06, texel_m, 0.5)}
    if p.kind == "car":
        out[f"{pre}.glass"] = Material(f"{pre}.glass", (0.08, 0.10, 0.12), 0.1, texel_m, 0.5)
        out[f"{pre}.tyre"] = Material(f"{pre}.tyre", (0.05, 0.05, 0.05), 0.2, texel_m, 0.3)
    return out


def truck_scene(spec: TruckSpec, *, truck_xy_m=(0.0, 0.0), truck_yaw_rad: float = 0.0, texel_m: float | None = None, n_distractors: int = 6,
                second_truck: TruckSpec | None = None, second_offset_m: float | None = None, max_distractor_height_m: float | None = None, rng=None) -> Scene:
    """Build a scene: ground, one truck posed at ``truck_xy_m``/``truck_yaw_rad``, distractors, optional second truck.

    texel_m: noise texel size (default: 1/200 of the truck width ~ one HD720 pixel at the usual range).
    second_truck: parked parallel beside the first, ``second_offset_m`` (default 0.6 x width) gap.
    Returns a :class:`Scene` whose ``info`` holds the truth (truck pose, dims, distractors).
    """
    rng = np.random.default_rng(rng)
    s = spec.width_m
    texel = texel_m if texel_m is not None else s / 200.0
    T_wt = pose(rot_z(truck_yaw_rad), (truck_xy_m[0], truck_xy_m[1], 0.0))
    mesh = Mesh()
    mats: dict[str, Material] = {}
    mesh.extend(ground_mesh(max(200 * s, 20 * spec.length_m)).transformed(pose(np.eye(3), (truck_xy_m[0], truck_xy_m[1], 0.0))))
    gmat = ground_material(texel * 1.5, s, spec.length_m)
    # Lines are laid out in the truck's frame axes only when the truck is axis-aligned; keep world axes.
    gmat = Material(gmat.name, gmat.albedo_rgb, gmat.texture_strength, gmat.texel_m, gmat.stain_mix, gmat.pattern,
                    dict(gmat.params, x0_m=float(truck_xy_m[0]), y_lo_m=float(truck_xy_m[1]) - 2.3 * s, y_hi_m=float(truck_xy_m[1]) + 2.3 * s))
    mats["ground"] = gmat
    mesh.extend(truck_mesh(spec, "truck").transformed(T_wt))
    mats.update(truck_materials(spec, texel, "truck"))
    half_diag = 0.5 * np.hypot(spec.length_m, spec.width_m)
    keep_out = [(0.0, 0.0, half_diag + 0.6 * s)]  # relative to the truck centre
    info: dict = {"truck_T_world": T_wt, "second_truck": None}
    if second_truck is not None:
        gap = second_offset_m if second_offset_m is not None else 0.6 * s
        dy = spec.width_m / 2 + gap + second_truck.width_m / 2
        off = T_wt[:3, :3] @ np.array([0.1 * spec.length_m, dy, 0.0])
        T_w2 = pose(T_wt[:3, :3], T_wt[:3, 3] + off)
        mesh.extend(truck_mesh(second_truck, "truck2").transformed(T_w2))
        mats.update(truck_materials(second_truck, texel, "truck2"))
        keep_out.append((off[0], off[1], 0.5 * np.hypot(second_truck.length_m, second_truck.width_m) + 0.6 * s))
        info["second_truck"] = {"T_world": T_w2, "length_m": second_truck.length_m, "width_m": second_truck.width_m,
                                "height_m": second_truck.height_m, "body": second_truck.body, "gap_m": gap}
    max_h = max_distractor_height_m if max_distractor_height_m is not None else 0.8 * spec.height_m
    r0 = half_diag + 1.0 * s
    placed = place_distractors(n_distractors, s, keep_out, (r0, r0 + 5 * s), max_h, rng) if n_distractors > 0 else []
    placed = [Placed(p.kind, p.x_m + truck_xy_m[0], p.y_m + truck_xy_m[1], p.radius_m, p.yaw_rad, p.size_m) for p in placed]
    for i, p in enumerate(placed):
        mesh.extend(distractor_mesh(p, i, max_h))
        mats.update(distractor_materials(p, i, texel, rng))
    info["distractors"] = [vars(p) for p in placed]
    info["texel_m"] = texel
    return Scene(mesh=mesh, materials=mats, scale_m=s, info=info)
