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

from stereo_recon.synthetic.mesh import Mesh, box, cylinder_y, cylinder_z, elliptic_cylinder_x, pose, rot_z
from stereo_recon.synthetic.texture import Material

log = logging.getLogger(__name__)

BODY_TYPES = ("box", "flatbed", "semi", "tanker")


@dataclass(frozen=True)
class PanelSpec:
    """Paint and markings of the cargo panels (box, trailer, tank), in the truck frame.

    texture_strength: relative std of the paint's noise (0.01 = plain paint, 0.25 = strongly decorated).
    stain_mix: weight of the coarse stains relative to the fine grain (0..1).
    seam_spacing_m / seam_width_m / seam_shade: vertical panel seams along the body every
        ``seam_spacing_m`` (0 = none), each ``seam_width_m`` wide, albedo times ``seam_shade``.
    rail_height_m / rail_shade: top and bottom rails (horizontal bands) of that height (0 = none).
    dirt: darkening at the bottom of the body (0..1, fades out at ``dirt_height_frac`` x H).
    decals: rectangles (x0, x1, z0, z1, r, g, b): x as fractions of the body's length from its rear
        end, z as fractions of H, paint colour 0..1 (lettering, logos, graphics).
    """

    texture_strength: float = 0.035
    stain_mix: float = 0.7
    seam_spacing_m: float = 0.0
    seam_width_m: float = 0.0
    seam_shade: float = 0.7
    rail_height_m: float = 0.0
    rail_shade: float = 0.85
    dirt: float = 0.0
    dirt_height_frac: float = 0.3
    decals: tuple[tuple[float, float, float, float, float, float, float], ...] = ()


@dataclass(frozen=True)
class TruckSpec:
    """A parametric truck.

    length_m / width_m / height_m: exact outer dimensions (see the module docstring).
    body: "box" (cargo box), "flatbed" (low deck with a load of crates), "semi" (tractor and
        a box semi-trailer) or "tanker" (an elliptic tank on the chassis).
    cab_rgb / body_rgb: paint colours (0..1 RGB); the cargo panels are weakly textured paint.
    stripe: paint a horizontal band (lettering-like) on the cargo box (ignored with ``panel``).
    cab_length_frac / cab_height_frac: cab length / L and cab height / H (None: the body style's default).
    load_heights_frac: flatbed crates' heights / H, rear to front (None: 0.78, 1, 0.9); the tallest must be 1.
    panel: cargo panel paint and markings (None: weakly textured paint, 3.5 % contrast, and the band).
    """

    length_m: float = 12.0
    width_m: float = 2.55
    height_m: float = 4.0
    body: str = "box"
    cab_rgb: tuple[float, float, float] = (0.75, 0.12, 0.10)
    body_rgb: tuple[float, float, float] = (0.82, 0.82, 0.80)
    stripe: bool = True
    cab_length_frac: float | None = None
    cab_height_frac: float | None = None
    load_heights_frac: tuple[float, ...] | None = None
    panel: PanelSpec | None = None

    def __post_init__(self) -> None:
        if self.body not in BODY_TYPES:
            raise ValueError(f"TruckSpec.body must be one of {BODY_TYPES}, got {self.body!r}")
        if min(self.length_m, self.width_m, self.height_m) <= 0:
            raise ValueError("TruckSpec: dimensions must be positive")
        if self.length_m < 1.5 * self.width_m:
            raise ValueError(f"TruckSpec: length {self.length_m} m too short for width {self.width_m} m")
        if self.cab_length_frac is not None and not 0.05 <= self.cab_length_frac <= 0.4:
            raise ValueError(f"TruckSpec: cab_length_frac {self.cab_length_frac} outside 0.05..0.4")
        if self.cab_height_frac is not None and not 0.4 <= self.cab_height_frac <= 1.0:
            raise ValueError(f"TruckSpec: cab_height_frac {self.cab_height_frac} outside 0.4..1")
        if self.load_heights_frac is not None and (not self.load_heights_frac or abs(max(self.load_heights_frac) - 1.0) > 1e-12
                                                   or min(self.load_heights_frac) <= 0.3):
            raise ValueError(f"TruckSpec: load_heights_frac {self.load_heights_frac} must be in (0.3, 1] with the tallest 1")


@dataclass(frozen=True)
class TruckLayout:
    """Where a truck's parts lie along its length and height (truck frame, metres; see :func:`truck_layout`)."""

    wheel_radius_m: float
    z_frame0_m: float  # chassis bottom
    z_floor_m: float  # cargo floor / chassis top
    cab_length_m: float
    cab_height_m: float
    x_cab0_m: float  # rear end of the cab
    x_body_front_m: float  # front end of the cargo body (box, deck, trailer or tank)
    x_rear_m: float


def truck_layout(spec: TruckSpec) -> TruckLayout:
    """The body style's proportions (cab length and height, floor, wheels) for ``spec``."""
    L, W, H = spec.length_m, spec.width_m, spec.height_m
    r = min(0.125 * H, 0.2 * W, 0.06 * L)  # wheel radius
    is_semi = spec.body == "semi"
    if spec.cab_length_frac is not None:
        cab_len = spec.cab_length_frac * L
    elif is_semi:
        cab_len = min(max(0.14 * L, 1.0 * W), 0.25 * L)
    else:
        cab_len = min(max(0.16 * L, 1.1 * W), 0.3 * L)
    if spec.cab_height_frac is not None:
        cab_h = spec.cab_height_frac * H
    else:
        cab_h = {"flatbed": 0.85, "semi": 0.9}.get(spec.body, 0.8) * H  # a flatbed's load is its tallest part
    x_cab0 = L / 2 - cab_len
    gap = max(0.015 * L, 0.08 * W)
    return TruckLayout(r, 0.85 * r, 2.15 * r, cab_len, cab_h, x_cab0, x_cab0 - gap, -L / 2)


def _panel_material(name: str, spec: TruckSpec, texel_m: float, T_world_truck: np.ndarray | None) -> Material:
    """The cargo panels' material: the presets' band paint, or ``spec.panel``'s seams, rails, dirt and decals."""
    H = spec.height_m
    if spec.panel is None:
        return Material(name, spec.body_rgb, 0.035, texel_m, 0.7, pattern="band" if spec.stripe else "noise",
                        params={"z_lo_m": 0.62 * H, "z_hi_m": 0.72 * H, "band_rgb": (0.10, 0.25, 0.55)} if spec.stripe else {})
    pn = spec.panel
    lay = truck_layout(spec)
    x0, x1 = lay.x_rear_m, lay.x_body_front_m
    T = np.eye(4) if T_world_truck is None else np.asarray(T_world_truck, float)
    seams = ()
    if pn.seam_spacing_m > 0:
        n = int((x1 - x0) / pn.seam_spacing_m)
        step = (x1 - x0) / max(n, 1)
        seams = tuple(x0 + k * step for k in range(1, n))  # interior seams only: the body's ends are no seam
    rails = ()
    if pn.rail_height_m > 0:
        rails = ((lay.z_floor_m, lay.z_floor_m + pn.rail_height_m), (H - pn.rail_height_m, H))
    decals = tuple((x0 + d[0] * (x1 - x0), x0 + d[1] * (x1 - x0), d[2] * H, d[3] * H, tuple(d[4:7])) for d in pn.decals)
    params = {"origin": tuple(T[:3, 3]), "x_axis": tuple(T[:3, 0]), "seams_x_m": seams, "seam_width_m": pn.seam_width_m,
              "seam_shade": pn.seam_shade, "rails_z_m": rails, "rail_shade": pn.rail_shade, "dirt": pn.dirt,
              "dirt_top_m": lay.z_floor_m + pn.dirt_height_frac * (H - lay.z_floor_m), "z_floor_m": lay.z_floor_m, "decals": decals}
    return Material(name, spec.body_rgb, pn.texture_strength, texel_m, pn.stain_mix, pattern="panel", params=params)


def truck_materials(spec: TruckSpec, texel_m: float, prefix: str = "truck", T_world_truck: np.ndarray | None = None) -> dict[str, Material]:
    """Materials of a truck (named ``<prefix>.<part>``); ``texel_m`` is the scene's noise texel.

    T_world_truck: the truck's 4x4 pose in the world (places ``spec.panel``'s markings; identity if None).
    """
    return {
        f"{prefix}.cab": Material(f"{prefix}.cab", spec.cab_rgb, 0.05, texel_m, 0.6),
        f"{prefix}.glass": Material(f"{prefix}.glass", (0.10, 0.13, 0.16), 0.12, texel_m, 0.8),
        # Painted cargo panels: weakly textured by default (the hard case for stereo matching).
        f"{prefix}.body": _panel_material(f"{prefix}.body", spec, texel_m, T_world_truck),
        f"{prefix}.roof": Material(f"{prefix}.roof", tuple(0.9 * c for c in spec.body_rgb), 0.08, texel_m, 0.7),
        f"{prefix}.chassis": Material(f"{prefix}.chassis", (0.12, 0.12, 0.12), 0.15, texel_m, 0.3),
        f"{prefix}.tyre": Material(f"{prefix}.tyre", (0.06, 0.06, 0.06), 0.25, texel_m, 0.2),
        f"{prefix}.rim": Material(f"{prefix}.rim", (0.55, 0.55, 0.55), 0.1, texel_m, 0.3),
        f"{prefix}.deck": Material(f"{prefix}.deck", (0.45, 0.33, 0.20), 0.25, texel_m, 0.6),
        f"{prefix}.load": Material(f"{prefix}.load", (0.62, 0.50, 0.32), 0.2, texel_m, 0.5),
    }


def _cargo_mesh(spec: TruckSpec, lay: TruckLayout, m) -> tuple[Mesh, list[float]]:
    """The cargo body of ``spec`` (box, flatbed deck and load, semi-trailer or tank) and its axles' x (m)."""
    L, W, H = spec.length_m, spec.width_m, spec.height_m
    r, z_floor, x_rear, x_front_body = lay.wheel_radius_m, lay.z_floor_m, lay.x_rear_m, lay.x_body_front_m
    mesh = Mesh()
    if spec.body == "box":
        mesh.extend(box((x_rear, -W / 2, z_floor), (x_front_body, W / 2, H), m("body"), top_material=m("roof")))
        return mesh, [x_rear + 0.22 * L, x_rear + 0.22 * L + 2.3 * r]
    if spec.body == "tanker":
        # Elliptic tank on the chassis: widest at mid-height, its crest is the truck's top.
        zc = 0.5 * (z_floor + H)
        mesh.extend(elliptic_cylinder_x((0.0, zc), W / 2, 0.5 * (H - z_floor), x_rear, x_front_body, m("body")))
        return mesh, [x_rear + 0.2 * L, x_rear + 0.2 * L + 2.3 * r]
    if spec.body == "flatbed":
        deck_t = 0.35 * r
        mesh.extend(box((x_rear, -W / 2, z_floor), (x_front_body, W / 2, z_floor + deck_t), m("deck")))
        # Load: crates along the deck; one of them reaches the full height.
        heights = spec.load_heights_frac or (0.78, 1.0, 0.9)
        cl = (x_front_body - x_rear) / len(heights)
        for i, hf in enumerate(heights):
            x0 = x_rear + i * cl + 0.04 * cl
            x1 = x_rear + (i + 1) * cl - 0.04 * cl
            mesh.extend(box((x0, -0.45 * W, z_floor + deck_t), (x1, 0.45 * W, hf * H), m("load")))
        return mesh, [x_rear + 0.2 * L, x_rear + 0.2 * L + 2.3 * r]
    # semi: box trailer over the tractor's fifth wheel, landing legs, tandem/tri-axle at the rear
    z_trailer = 2.6 * r
    mesh.extend(box((x_rear, -W / 2, z_trailer), (x_front_body, W / 2, H), m("body"), top_material=m("roof")))
    axles = [lay.x_cab0_m - 0.1 * lay.cab_length_m, lay.x_cab0_m - 0.1 * lay.cab_length_m - 2.3 * r]
    axles += [x_rear + 0.12 * L + k * 2.3 * r for k in range(3)]
    for s in (-1, 1):
        mesh.extend(box((x_front_body - 0.35 * L, s * 0.3 * W - 0.03 * W, 0.0), (x_front_body - 0.35 * L + 0.04 * W, s * 0.3 * W + 0.03 * W, z_trailer),
                        m("chassis")))
    return mesh, axles


def truck_mesh(spec: TruckSpec, prefix: str = "truck") -> Mesh:
    """Triangle mesh of the truck in the truck frame (see module docstring); materials ``<prefix>.*``."""
    L, W, H = spec.length_m, spec.width_m, spec.height_m
    m = lambda part: f"{prefix}.{part}"  # noqa: E731
    lay = truck_layout(spec)
    r, z_frame0, z_floor = lay.wheel_radius_m, lay.z_frame0_m, lay.z_floor_m
    x_front = L / 2
    cab_len, cab_h, x_cab0 = lay.cab_length_m, lay.cab_height_m, lay.x_cab0_m
    wheel_w = 0.13 * W
    y_wheel_out = W / 2 - 0.03 * W  # wheels stay inside the body width
    mesh = Mesh()

    # Cab: lower cab box reaching the front, glazed upper part set back, roof on top.
    Wc = 0.97 * W
    z_sill = z_floor + 0.45 * (cab_h - z_floor)
    setback = 0.08 * cab_len
    roof_t = 0.06 * (cab_h - z_floor)
    mesh.extend(box((x_cab0, -Wc / 2, z_frame0), (x_front, Wc / 2, z_sill), m("cab")))
    mesh.extend(box((x_cab0, -0.98 * Wc / 2, z_sill), (x_front - setback, 0.98 * Wc / 2, cab_h - roof_t), m("glass")))
    mesh.extend(box((x_cab0, -Wc / 2, cab_h - roof_t), (x_front - setback, Wc / 2, cab_h), m("cab")))
    # Chassis rails under everything.
    mesh.extend(box((lay.x_rear_m + 0.04 * L, -0.36 * W, z_frame0), (x_cab0 + 0.5 * cab_len, 0.36 * W, z_floor), m("chassis")))
    cargo, axles = _cargo_mesh(spec, lay, m)
    mesh.extend(cargo)
    for xa in [x_front - 0.55 * cab_len, *axles]:
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
    mats.update(truck_materials(spec, texel, "truck", T_wt))
    half_diag = 0.5 * np.hypot(spec.length_m, spec.width_m)
    keep_out = [(0.0, 0.0, half_diag + 0.6 * s)]  # relative to the truck centre
    info: dict = {"truck_T_world": T_wt, "second_truck": None}
    if second_truck is not None:
        gap = second_offset_m if second_offset_m is not None else 0.6 * s
        dy = spec.width_m / 2 + gap + second_truck.width_m / 2
        off = T_wt[:3, :3] @ np.array([0.1 * spec.length_m, dy, 0.0])
        T_w2 = pose(T_wt[:3, :3], T_wt[:3, 3] + off)
        mesh.extend(truck_mesh(second_truck, "truck2").transformed(T_w2))
        mats.update(truck_materials(second_truck, texel, "truck2", T_w2))
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
