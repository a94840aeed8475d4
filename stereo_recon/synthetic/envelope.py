"""Random scenes over the operating envelope: trucks, paint, flights, cameras and scenes a user may meet.

A draw is a :class:`RandomSceneSpec` sampled by the pure function :func:`sample_scene_spec` from a
``numpy.random.Generator``; draw ``i`` of seed ``S`` uses ``np.random.default_rng([S, i])``, so it is
the same whatever the number of draws. :func:`build_draw` turns a spec into the renderer's inputs
(scene, rig, poses, truth) and :func:`render_draw` writes the same folder layout as a preset
(``video.avi|mp4``, ``SN<serial>.conf``, ``rig.yaml``, ``poses_gt.txt``, ``truth.json`` with the
spec under ``random_spec``). Everything random in the rendering (distractor placement, flight
jitter, sensor noise) derives from the spec's ``render_seed``.

Envelope (each factor drawn independently, ranges in the constants below):

- truck: kind (box, semi-trailer, flatbed with a load, tanker), model scale (L 1-2.5 m) or full
  scale (L 6-18 m, W 2.3-2.8 m, H 2.5-4.5 m), half the draws each; cab length / height, paint
  (white, silver, black, saturated), yaw;
- panels: plain paint (contrast <= 2 %) with only seams, rails, dirt and decals, weakly textured,
  or strongly decorated; texel 0.5-1.5 pixel footprints at the working distance;
- flight: orbit radius 0.75-2.0 x L (at least 1 m model / 5 m full), camera elevation 15-50 deg
  seen from the truck's centre at half height, arc 240-360 deg, 60-200 frames, orbit centre up
  to 10 % of L off the truck, gimbal jitter and shake;
- camera: both ZED lens families (k1 ~ -0.17 and ~ -0.04), intrinsics and stereo extrinsics
  spread, pixel noise sigma 1-6 DN, blur 0.3-1 px, exposure drift and right-eye gain up to 5 %,
  MJPG AVI or mp4v MP4;
- scene: sun elevation 20-70 deg with shadows, ground from plain asphalt to busy, 0-10
  distractors, in a third of the draws a second vehicle (shorter, as tall or taller) 1-2 widths away.

Seeds: :data:`TUNING_SEEDS` (0-99 and the seeds of past reports) are for tuning; :data:`EVALUATION_SEED` is kept
for the next reported figures.
"""

from __future__ import annotations

import colorsys
import logging
import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from stereo_recon.core.errors import ConfigError
from stereo_recon.synthetic.camera import LENS_FAMILIES, resolution_size, stereo_rig
from stereo_recon.synthetic.flight import OrbitConfig, orbit_poses
from stereo_recon.synthetic.presets import Preset
from stereo_recon.synthetic.scene import PanelSpec, TruckSpec, truck_scene

log = logging.getLogger(__name__)

from stereo_recon.synthetic.seeds import EVALUATION_SEED, TUNING_SEEDS  # noqa: F401 - re-exported

SCALES = ("model", "full")
KINDS = ("box", "semi", "flatbed", "tanker")
PAINTS = ("white", "silver", "black", "saturated")
TEXTURE_CLASSES = ("plain", "weak", "decorated")
GROUND_CLASSES = ("plain", "marked", "busy")
CODECS = ("MJPG", "mp4v")
SECOND_RELATIONS = ("shorter", "as-tall", "taller")

# Ranges of the envelope (uniform draws unless said otherwise).
MODEL_LENGTH_M = (1.0, 2.5)
MODEL_WIDTH_OVER_LENGTH = (0.14, 0.22)  # the paper's Table 2 models: 0.15-0.18
MODEL_HEIGHT_OVER_WIDTH = (0.85, 1.75)  # Table 2: 0.87-1.71
FULL_LENGTH_M = (6.0, 18.0)
FULL_WIDTH_M = (2.3, 2.8)
FULL_HEIGHT_M = (2.5, 4.5)
CAB_LENGTH_FRAC = (0.12, 0.28)
CAB_HEIGHT_FRAC = (0.6, 0.95)
TEXTURE_STRENGTH = {"plain": (0.005, 0.02), "weak": (0.02, 0.08), "decorated": (0.12, 0.30)}
TEXEL_OVER_FOOTPRINT = (0.5, 1.5)
RADIUS_OVER_LENGTH = (0.75, 2.0)
MIN_RADIUS_M = {"model": 1.0, "full": 5.0}
ELEVATION_DEG = (15.0, 50.0)
ARC_DEG = (240.0, 360.0)
FRAMES = (60, 200)
CENTRE_OFFSET_OVER_LENGTH = 0.10
JITTER_DEG = (0.2, 1.0)
SHAKE_DEG = (0.0, 0.4)
NOISE_SIGMA_DN = (1.0, 6.0)
BLUR_SIGMA_PX = (0.3, 1.0)
EXPOSURE_JITTER = (0.0, 0.05)
RIGHT_GAIN = (0.95, 1.05)
SUN_ELEVATION_DEG = (20.0, 70.0)
GROUND_TEXTURE_STRENGTH = {"plain": (0.06, 0.12), "marked": (0.15, 0.25), "busy": (0.30, 0.45)}
DISTRACTORS = (0, 10)
SECOND_VEHICLE_SHARE = 1.0 / 3.0
SECOND_GAP_OVER_WIDTH = (1.0, 2.0)
SECOND_HEIGHT_RATIO = {"shorter": (0.6, 0.85), "as-tall": (0.98, 1.02), "taller": (1.1, 1.3)}


@dataclass(frozen=True)
class TruckDraw:
    """The truck of a draw: scale, body kind, exact outer dimensions (m), proportions, paint, yaw (deg)."""

    scale: str
    kind: str
    length_m: float
    width_m: float
    height_m: float
    cab_length_frac: float
    cab_height_frac: float
    load_heights_frac: tuple[float, ...] | None
    body_paint: str
    body_rgb: tuple[float, float, float]
    cab_paint: str
    cab_rgb: tuple[float, float, float]
    yaw_deg: float


@dataclass(frozen=True)
class PanelDraw:
    """Cargo panel paint: contrast class, the panel spec (seams, rails, dirt, decals) and the texel size in pixel footprints."""

    texture_class: str
    panel: PanelSpec
    texel_over_footprint: float
    seam_width_frac: float  # of H; widened to >= 1.5 pixel footprints at the working distance


@dataclass(frozen=True)
class FlightDraw:
    """The orbit: radius (m and / L), camera elevation seen from the truck's centre at half height, arc, frames, aim, wobble."""

    radius_over_length: float
    radius_m: float
    elevation_deg: float
    altitude_m: float
    look_height_m: float
    arc_deg: float
    start_deg: float
    frames_drawn: int
    frames: int  # frames_drawn capped by the spec's max_frames
    elevation_drawn_deg: float  # before the orbit was raised over a second vehicle in its way (else = elevation_deg)
    centre_offset_m: tuple[float, float]  # orbit centre - truck centre, world xy
    jitter_deg: float
    shake_deg: float
    position_jitter_m: float
    fps: float = 15.0


@dataclass(frozen=True)
class CameraDraw:
    """The ZED: lens family, HD720 factory values per eye (fx fy dcx dcy k1 k2 p1 p2 k3), stereo extrinsics, image formation, codec."""

    lens_family: str
    left_hd: tuple[float, ...]
    right_hd: tuple[float, ...]
    stereo: tuple[float, float, float, float, float, float]  # baseline_mm, ty_mm, tz_mm, rx_rad, cv_rad, rz_rad
    noise_sigma_dn: float
    blur_sigma_px: float
    exposure_jitter: float
    right_gain: float
    codec: str
    jpeg_quality: int


@dataclass(frozen=True)
class SecondVehicleDraw:
    """A second vehicle parked parallel beside the truck ``gap_m`` away (dimensions in m)."""

    relation: str
    kind: str
    length_m: float
    width_m: float
    height_m: float
    gap_m: float
    body_rgb: tuple[float, float, float]
    cab_rgb: tuple[float, float, float]


@dataclass(frozen=True)
class SceneDraw:
    """Light, ground and clutter: sun elevation / azimuth (deg), ambient and sun intensities, ground, distractors, second vehicle."""

    sun_elevation_deg: float
    sun_azimuth_deg: float
    ambient: float
    sun: float
    ground_class: str
    ground_texture_strength: float
    ground_bays: bool
    n_distractors: int
    second: SecondVehicleDraw | None


@dataclass(frozen=True)
class RandomSceneSpec:
    """One random draw of the operating envelope (JSON-serialisable with :func:`spec_to_dict` / :func:`spec_from_dict`).

    seed / index: the draw's identity (``np.random.default_rng([seed, index])``; -1 when sampled from another
    generator); render_seed: seeds the rendering's own randomness; max_frames: the cap applied to the
    drawn frame count (None: none); resolution: ZED resolution rendered (HD720 unless a quick run asks less).
    """

    seed: int
    index: int
    render_seed: int
    max_frames: int | None
    resolution: str
    truck: TruckDraw
    panel: PanelDraw
    flight: FlightDraw
    camera: CameraDraw
    scene: SceneDraw

    @property
    def name(self) -> str:
        """``random-<seed>-<index>``."""
        return f"random-{self.seed}-{self.index}"


# ------------------------------------------------------------------------------------ sampling


def _u(rng: np.random.Generator, lo_hi) -> float:
    return float(rng.uniform(lo_hi[0], lo_hi[1]))


def _paint(rng: np.random.Generator) -> tuple[str, tuple[float, float, float]]:
    """A paint class and its RGB (0..1): white, silver, black or a saturated colour."""
    kind = PAINTS[int(rng.integers(len(PAINTS)))]
    if kind == "white":
        v = _u(rng, (0.82, 0.92))
        rgb = (v, v * _u(rng, (0.98, 1.0)), v * _u(rng, (0.95, 1.0)))
    elif kind == "silver":
        v = _u(rng, (0.55, 0.68))
        rgb = (v, v * _u(rng, (0.99, 1.01)), v * _u(rng, (1.0, 1.05)))
    elif kind == "black":
        v = _u(rng, (0.03, 0.08))
        rgb = (v, v, v)
    else:
        rgb = colorsys.hsv_to_rgb(_u(rng, (0.0, 1.0)), _u(rng, (0.75, 1.0)), _u(rng, (0.45, 0.85)))
    return kind, tuple(float(min(c, 1.0)) for c in rgb)


def _sample_truck(rng: np.random.Generator, scale: str | None) -> TruckDraw:
    drawn_scale = SCALES[int(rng.integers(2))]
    scale = scale or drawn_scale  # the coin is drawn either way: the rest of the draw does not depend on a forced scale
    kind = KINDS[int(rng.integers(len(KINDS)))]
    if scale == "model":
        L = _u(rng, MODEL_LENGTH_M)
        W = L * _u(rng, MODEL_WIDTH_OVER_LENGTH)
        H = W * _u(rng, MODEL_HEIGHT_OVER_WIDTH)
    else:
        L, W, H = _u(rng, FULL_LENGTH_M), _u(rng, FULL_WIDTH_M), _u(rng, FULL_HEIGHT_M)
    cab_l = _u(rng, CAB_LENGTH_FRAC)
    cab_h = _u(rng, CAB_HEIGHT_FRAC)
    # The load is drawn for every kind (kept for flatbeds only) so that the draws after it do not depend on the kind.
    load = None
    n_crates = int(rng.integers(2, 5))
    heights = [_u(rng, (0.5, 1.0)) for _ in range(n_crates)]
    heights[int(rng.integers(n_crates))] = 1.0
    if kind == "flatbed":
        load = tuple(heights)
    body_paint, body_rgb = _paint(rng)
    cab_paint, cab_rgb = _paint(rng)
    return TruckDraw(scale, kind, L, W, H, cab_l, cab_h, load, body_paint, body_rgb, cab_paint, cab_rgb, _u(rng, (0.0, 360.0)))


def _sample_decals(rng: np.random.Generator, texture_class: str) -> tuple:
    """Decals (x0, x1, z0, z1 as fractions of the body's length and of H; r, g, b)."""
    n = int(rng.integers(*{"plain": (0, 3), "weak": (1, 4), "decorated": (2, 7)}[texture_class]))
    big = texture_class == "decorated"
    out = []
    for _ in range(n):
        dx = _u(rng, (0.15, 0.6) if big else (0.05, 0.2))
        dz = _u(rng, (0.2, 0.6) if big else (0.05, 0.2))
        x0 = _u(rng, (0.02, 0.98 - dx))
        z0 = _u(rng, (0.1, max(0.9 - dz, 0.11)))
        _, rgb = _paint(rng)
        out.append((x0, x0 + dx, z0, min(z0 + dz, 0.9), *rgb))
    return tuple(out)


def _sample_panel(rng: np.random.Generator, H: float) -> PanelDraw:
    cls = TEXTURE_CLASSES[int(rng.integers(len(TEXTURE_CLASSES)))]
    strength = _u(rng, TEXTURE_STRENGTH[cls])
    seams = rng.uniform() < 0.8
    rails = rng.uniform() < 0.7
    spacing = _u(rng, (0.15, 0.45)) * H
    seam_w = _u(rng, (0.004, 0.012))
    panel = PanelSpec(texture_strength=strength, stain_mix=_u(rng, (0.3, 0.8)),
                      seam_spacing_m=spacing if seams else 0.0, seam_width_m=0.0, seam_shade=_u(rng, (0.45, 0.8)),
                      rail_height_m=_u(rng, (0.03, 0.08)) * H if rails else 0.0, rail_shade=_u(rng, (0.75, 1.25)),
                      dirt=_u(rng, (0.0, 0.35)), dirt_height_frac=_u(rng, (0.1, 0.4)), decals=_sample_decals(rng, cls))
    return PanelDraw(cls, panel, _u(rng, TEXEL_OVER_FOOTPRINT), seam_w)


def _sample_flight(rng: np.random.Generator, t: TruckDraw, max_frames: int | None) -> FlightDraw:
    ratio = _u(rng, RADIUS_OVER_LENGTH)
    radius = max(ratio * t.length_m, MIN_RADIUS_M[t.scale])
    elev = _u(rng, ELEVATION_DEG)
    altitude = 0.5 * t.height_m + radius * math.tan(math.radians(elev))
    frames = int(rng.integers(FRAMES[0], FRAMES[1] + 1))
    off_r = _u(rng, (0.0, CENTRE_OFFSET_OVER_LENGTH)) * t.length_m
    off_a = _u(rng, (0.0, 2 * math.pi))
    return FlightDraw(ratio, radius, elev, altitude, _u(rng, (0.2, 0.6)) * t.height_m, _u(rng, ARC_DEG), _u(rng, (0.0, 360.0)),
                      frames, frames if max_frames is None else min(frames, int(max_frames)), elev,
                      (off_r * math.cos(off_a), off_r * math.sin(off_a)), _u(rng, JITTER_DEG), _u(rng, SHAKE_DEG),
                      _u(rng, (0.002, 0.008)) * radius)


def second_vehicle_xy(t: TruckDraw, s: SecondVehicleDraw) -> tuple[float, float]:
    """The second vehicle's footprint centre in the truck frame (m): parked parallel on the truck's left, as truck_scene places it."""
    return 0.1 * t.length_m, t.width_m / 2 + s.gap_m + s.width_m / 2


def _clear_second_vehicle(f: FlightDraw, t: TruckDraw, s: SecondVehicleDraw | None) -> FlightDraw:
    """The flight raised over the second vehicle when the orbit passes over its footprint (a drone does not fly through a
    truck): at least 0.3 x H above its roof; the elevation follows (recorded; ``elevation_drawn_deg`` keeps the draw)."""
    if s is None:
        return f
    yaw = math.radians(t.yaw_deg)
    ox, oy = f.centre_offset_m
    # Orbit centre in the truck frame; the footprint's nearest and farthest points from it.
    cx, cy = math.cos(yaw) * ox + math.sin(yaw) * oy, -math.sin(yaw) * ox + math.cos(yaw) * oy
    sx, sy = second_vehicle_xy(t, s)
    hx, hy = s.length_m / 2, s.width_m / 2
    near = math.hypot(max(abs(cx - sx) - hx, 0.0), max(abs(cy - sy) - hy, 0.0))
    far = math.hypot(abs(cx - sx) + hx, abs(cy - sy) + hy)
    margin = 0.1 * t.length_m
    floor = s.height_m + 0.3 * t.height_m
    if not (near - margin <= f.radius_m <= far + margin) or f.altitude_m >= floor:
        return f
    elev = math.degrees(math.atan2(floor - 0.5 * t.height_m, f.radius_m))
    return replace(f, altitude_m=floor, elevation_deg=elev)


def _sample_camera(rng: np.random.Generator) -> CameraDraw:
    family = ("zed", "zed2")[int(rng.integers(2))]
    f_scale = _u(rng, (0.97, 1.03))
    eyes = []
    for base in LENS_FAMILIES[family]:
        fx, fy, dcx, dcy, k1, k2, p1, p2, k3 = base
        fe = f_scale * _u(rng, (0.997, 1.003))
        eyes.append((fx * fe, fy * fe * _u(rng, (0.999, 1.001)), dcx + _u(rng, (-10.0, 10.0)), dcy + _u(rng, (-10.0, 10.0)),
                     k1 * _u(rng, (0.9, 1.1)), k2 * _u(rng, (0.85, 1.15)), _u(rng, (-5e-4, 5e-4)), _u(rng, (-5e-4, 5e-4)), k3))
    stereo = (_u(rng, (119.0, 121.0)), _u(rng, (-0.3, 0.3)), _u(rng, (-0.8, 0.8)),
              _u(rng, (-3e-3, 3e-3)), _u(rng, (-3e-3, 3e-3)), _u(rng, (-3e-3, 3e-3)))
    return CameraDraw(family, eyes[0], eyes[1], stereo, _u(rng, NOISE_SIGMA_DN), _u(rng, BLUR_SIGMA_PX), _u(rng, EXPOSURE_JITTER),
                      _u(rng, RIGHT_GAIN), CODECS[int(rng.integers(2))], int(rng.integers(80, 96)))


def _sample_scene(rng: np.random.Generator, t: TruckDraw) -> SceneDraw:
    ground = GROUND_CLASSES[int(rng.integers(len(GROUND_CLASSES)))]
    # The second vehicle is drawn in every draw (kept in a third) for the same reason as the flatbed's load.
    second = None
    has_second = rng.uniform() < SECOND_VEHICLE_SHARE
    relation = SECOND_RELATIONS[int(rng.integers(len(SECOND_RELATIONS)))]
    kind = KINDS[int(rng.integers(len(KINDS)))]
    W2 = t.width_m * _u(rng, (0.9, 1.02))
    L2 = max(t.length_m * _u(rng, (0.6, 1.1)), 1.6 * W2)
    H2 = t.height_m * _u(rng, SECOND_HEIGHT_RATIO[relation])
    gap = t.width_m * _u(rng, SECOND_GAP_OVER_WIDTH)
    _, body = _paint(rng)
    _, cab = _paint(rng)
    if has_second:
        second = SecondVehicleDraw(relation, kind, L2, W2, H2, gap, body, cab)
    return SceneDraw(_u(rng, SUN_ELEVATION_DEG), _u(rng, (0.0, 360.0)), _u(rng, (0.3, 0.45)), _u(rng, (0.6, 0.85)), ground,
                     _u(rng, GROUND_TEXTURE_STRENGTH[ground]), ground != "plain", int(rng.integers(DISTRACTORS[0], DISTRACTORS[1] + 1)),
                     second)


def sample_scene_spec(rng, *, max_frames: int | None = None, scale: str | None = None, resolution: str = "HD720") -> RandomSceneSpec:
    """Draw one scene of the operating envelope (module docstring) from ``rng`` (a Generator or a seed).

    max_frames: cap on the drawn frame count (recorded in the spec); scale: force "model" or "full"
    (the scale coin is still drawn, so every other factor is the one the unforced draw gets);
    resolution: ZED resolution to render. Each group of factors draws from its own child generator,
    so changing how one group is sampled leaves the others' values alone.
    """
    if scale is not None and scale not in SCALES:
        raise ConfigError(f"--scale: must be one of {', '.join(SCALES)}, got {scale!r}")
    if max_frames is not None and int(max_frames) < 2:
        raise ConfigError(f"--max-frames: must be >= 2, got {max_frames}")
    resolution_size(resolution)  # a one-line error for an unknown resolution
    rng = np.random.default_rng(rng)
    r_truck, r_panel, r_flight, r_camera, r_scene, r_render = rng.spawn(6)
    truck = _sample_truck(r_truck, scale)
    scene = _sample_scene(r_scene, truck)
    flight = _clear_second_vehicle(_sample_flight(r_flight, truck, max_frames), truck, scene.second)
    return RandomSceneSpec(seed=-1, index=-1, render_seed=int(r_render.integers(2**31 - 1)),
                           max_frames=None if max_frames is None else int(max_frames), resolution=resolution,
                           truck=truck, panel=_sample_panel(r_panel, truck.height_m), flight=flight,
                           camera=_sample_camera(r_camera), scene=scene)


def draw_spec(seed: int, index: int, *, max_frames: int | None = None, scale: str | None = None, resolution: str = "HD720") -> RandomSceneSpec:
    """Draw ``index`` of seed ``seed``: :func:`sample_scene_spec` on ``np.random.default_rng([seed, index])``."""
    if int(seed) < 0 or int(index) < 0:
        raise ConfigError(f"--seed: seed and draw index must be >= 0, got {seed}, {index}")
    spec = sample_scene_spec(np.random.default_rng([int(seed), int(index)]), max_frames=max_frames, scale=scale, resolution=resolution)
    return replace(spec, seed=int(seed), index=int(index))


# ------------------------------------------------------------------------------ (de)serialising


def spec_to_dict(spec: RandomSceneSpec) -> dict:
    """The spec as plain JSON types (tuples become lists)."""
    return asdict(spec)


def _tuples(x):
    if isinstance(x, list):
        return tuple(_tuples(v) for v in x)
    return x


def _build(cls, d: dict):
    """Rebuild dataclass ``cls`` from ``d`` (nested dataclasses by their field types; lists back to tuples)."""
    nested = {"truck": TruckDraw, "panel": PanelDraw, "flight": FlightDraw, "camera": CameraDraw, "scene": SceneDraw}
    out = {}
    known = {f.name for f in fields(cls)}
    unknown = set(d) - known
    if unknown:
        raise ConfigError(f"random scene spec: unknown keys {sorted(unknown)} in {cls.__name__}")
    for k, v in d.items():
        if cls is PanelDraw and k == "panel":
            out[k] = PanelSpec(**{kk: _tuples(vv) for kk, vv in v.items()})
        elif cls is SceneDraw and k == "second":
            out[k] = None if v is None else _build(SecondVehicleDraw, v)
        elif cls is RandomSceneSpec and k in nested:
            out[k] = _build(nested[k], v)
        else:
            out[k] = _tuples(v)
    return cls(**out)


def spec_from_dict(d: dict) -> RandomSceneSpec:
    """Inverse of :func:`spec_to_dict` (ConfigError on unknown keys)."""
    try:
        return _build(RandomSceneSpec, d)
    except TypeError as err:
        raise ConfigError(f"random scene spec: {err}") from err


# ------------------------------------------------------------------------------------- building


@dataclass
class DrawInputs:
    """What the renderer needs for one draw, and its truth (see :func:`build_draw`)."""

    preset: Preset
    scene: object  # synthetic.scene.Scene
    rig: object  # calib.rig.StereoRig
    poses: np.ndarray  # (N, 4, 4) world-from-left-camera
    orbit: OrbitConfig
    render_config: object  # synthetic.render.RenderConfig
    truth: dict
    exposure: np.ndarray  # (N,) per-frame gain
    noise_seed: int
    noise_rng: np.random.Generator


def _truck_spec(t: TruckDraw, p: PanelDraw | None, seam_width_m: float) -> TruckSpec:
    panel = None if p is None else replace(p.panel, seam_width_m=seam_width_m)
    return TruckSpec(t.length_m, t.width_m, t.height_m, t.kind, t.cab_rgb, t.body_rgb, stripe=False, cab_length_frac=t.cab_length_frac,
                     cab_height_frac=t.cab_height_frac, load_heights_frac=t.load_heights_frac, panel=panel)


def _second_spec(s: SecondVehicleDraw, panel: PanelSpec) -> TruckSpec:
    return TruckSpec(s.length_m, s.width_m, s.height_m, s.kind, s.cab_rgb, s.body_rgb, stripe=False,
                     load_heights_frac=(0.8, 1.0, 0.9) if s.kind == "flatbed" else None, panel=replace(panel, decals=()))


def build_draw(spec: RandomSceneSpec) -> DrawInputs:
    """The scene, rig, poses and truth of a draw (nothing written); all randomness from ``spec.render_seed``."""
    from stereo_recon.synthetic.render import RenderConfig
    from stereo_recon.synthetic.sequence import _exposure_drift, setting_truth, truck_truth

    t, f, c, s = spec.truck, spec.flight, spec.camera, spec.scene
    rig = stereo_rig(spec.resolution, False, c.left_hd, c.right_hd, dict(zip(("baseline_mm", "ty_mm", "tz_mm", "rx_rad", "cv_rad", "rz_rad"), c.stereo)))
    fx = float(rig.K1[0, 0])
    # Pixel footprint at the working distance (camera to the aimed point) sets the texel and the thinnest marking.
    footprint = math.hypot(f.radius_m, f.altitude_m - f.look_height_m) / fx
    texel = spec.panel.texel_over_footprint * footprint
    truck = _truck_spec(t, spec.panel, max(spec.panel.seam_width_frac * t.height_m, 1.5 * footprint))
    second = None if s.second is None else _second_spec(s.second, truck.panel)
    ss = np.random.SeedSequence(spec.render_seed)
    scene_rng, flight_rng, noise_rng, expo_rng = (np.random.default_rng(q) for q in ss.spawn(4))
    orbit = OrbitConfig(radius_m=f.radius_m, altitude_m=f.altitude_m, arc_deg=f.arc_deg, start_deg=f.start_deg, look_height_m=f.look_height_m,
                        jitter_deg=f.jitter_deg, position_jitter_m=f.position_jitter_m, fps=f.fps, shake_deg=f.shake_deg)
    preset = Preset(name=spec.name, scale=t.scale, truck=truck, second_truck=second, second_gap_m=None if s.second is None else s.second.gap_m,
                    orbit=orbit, frames=f.frames, n_distractors=s.n_distractors, texel_m=texel, truck_yaw_deg=t.yaw_deg)
    yaw = math.radians(t.yaw_deg)
    # Distractors stay well under the drone (poles would otherwise reach its altitude on low orbits).
    scene = truck_scene(truck, truck_yaw_rad=yaw, texel_m=texel, n_distractors=s.n_distractors, second_truck=second,
                        second_offset_m=preset.second_gap_m, max_distractor_height_m=min(0.8 * t.height_m, 0.7 * f.altitude_m), rng=scene_rng)
    _light_and_ground(scene, s)
    poses = orbit_poses(f.frames, f.centre_offset_m, orbit, rng=flight_rng)
    cfg = RenderConfig(noise_sigma_dn=c.noise_sigma_dn, shadows=True, blur_sigma_px=c.blur_sigma_px, right_gain=c.right_gain)
    video_format = "avi" if c.codec == "MJPG" else "mp4"
    truth = {"preset": spec.name, "seed": spec.seed, "frames": f.frames, "fps": f.fps, "scale": t.scale}
    truth.update(truck_truth(preset, scene, yaw))
    truth.update(setting_truth(rig, scene, orbit, "orbit", texel, cfg, c.exposure_jitter, c.jpeg_quality, video_format))
    truth["flight"]["centre_offset_m"] = list(f.centre_offset_m)
    truth["random_spec"] = spec_to_dict(spec)
    return DrawInputs(preset, scene, rig, poses, orbit, cfg, truth, _exposure_drift(expo_rng, f.frames, c.exposure_jitter),
                      int(ss.generate_state(1)[0]), noise_rng)


def _light_and_ground(scene, s: SceneDraw) -> None:
    """Set the draw's sun, ambient light and ground texture on ``scene`` (in place)."""
    el, az = math.radians(s.sun_elevation_deg), math.radians(s.sun_azimuth_deg)
    scene.sun_dir = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    scene.ambient, scene.sun = s.ambient, s.sun
    g = scene.materials["ground"]
    scene.materials["ground"] = replace(g, texture_strength=s.ground_texture_strength, pattern="bays" if s.ground_bays else "noise",
                                        stain_mix=0.45 if s.ground_class != "busy" else 0.7)


def render_draw(spec: RandomSceneSpec, out_dir, depth: bool = False) -> dict:
    """Render one draw into ``out_dir`` (the preset layout; truth.json carries ``random_spec``); returns the truth.

    depth: also write the left eye's rendered z-depth maps (``depth/NNNNNN.npy``); the video is the same either way.
    """
    from stereo_recon.core.manifest import Stopwatch, to_jsonable
    from stereo_recon.synthetic.sequence import write_sequence

    sw = Stopwatch()
    with sw.stage("scene"):
        d = build_draw(spec)
    c = spec.camera
    params = {"random_spec": spec.name, "seed": spec.seed, "index": spec.index, "render_seed": spec.render_seed, "frames": spec.flight.frames,
              "max_frames": spec.max_frames, "resolution": spec.resolution, "video_format": "avi" if c.codec == "MJPG" else "mp4"}
    write_sequence(out_dir, d.scene, d.rig, d.poses, d.truth, d.render_config, fps=spec.flight.fps, noise_seed=d.noise_seed,
                   noise_rng=d.noise_rng, exposure=d.exposure, video_format=params["video_format"], jpeg_quality=c.jpeg_quality,
                   depth=depth, run_params=params, seed=spec.seed, stopwatch=sw)
    log.info("random draw %s: %d frames in %.1f s -> %s", spec.name, spec.flight.frames, sum(sw.timings_s.values()), out_dir)
    return to_jsonable(d.truth)


def draw_dir(out_dir, index: int) -> Path:
    """``out_dir/draw_NNN``."""
    return Path(out_dir) / f"draw_{index:03d}"


def render_random(count: int, seed: int, out_dir, *, max_frames: int | None = None, scale: str | None = None,
                  resolution: str = "HD720", depth: bool = False) -> list[dict]:
    """Render draws 0..count-1 of ``seed`` into ``out_dir/draw_NNN`` (a folder whose truth.json holds the same spec is
    reused); depth: with the rendered depth maps (``render_draw``)."""
    if int(count) < 1:
        raise ConfigError(f"--random: the number of draws must be >= 1, got {count}")
    return [ensure_rendered(draw_spec(seed, i, max_frames=max_frames, scale=scale, resolution=resolution), draw_dir(out_dir, i),
                            depth=depth) for i in range(int(count))]


def ensure_rendered(spec: RandomSceneSpec, d, depth: bool = False) -> dict:
    """The truth of draw ``spec`` in folder ``d``: reused when ``d`` holds this very draw, rendered when ``d`` has none;
    ConfigError when ``d`` holds another draw, or this draw without the depth maps asked for (never overwritten)."""
    existing = load_draw_spec(d)
    if existing is None:
        return render_draw(spec, d, depth=depth)
    if existing != spec:
        raise ConfigError(f"{d}: holds another draw (its truth.json's random_spec differs); choose another --out")
    if depth and not (Path(d) / "depth").is_dir():
        raise ConfigError(f"{d}: holds this draw without its depth maps; choose another --out for --depth")
    log.info("random draw %s: reusing %s", spec.name, d)
    return _read_truth(d)


def _read_truth(d: Path) -> dict:
    import json

    return json.loads((Path(d) / "truth.json").read_text())


def load_draw_spec(d) -> RandomSceneSpec | None:
    """The spec a rendered draw folder holds (None when the folder has no truth.json)."""
    p = Path(d) / "truth.json"
    if not p.is_file():
        return None
    try:
        return spec_from_dict(_read_truth(d)["random_spec"])
    except (KeyError, ValueError) as err:
        raise ConfigError(f"{p}: not a random draw's truth ({err})") from err
