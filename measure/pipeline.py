"""The measure stage: cloud -> ground -> FoF clusters -> truck -> length, width, height -> report.

Every scale-dependent parameter defaults to a multiple of the cloud's resolution (its median
nearest-neighbour spacing), so a 2 m model truck and an 18 m road train both work without flags;
each can be pinned in metres instead (the ``*_m`` fields), from the CLI or a config file.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from stereo_recon.core.errors import ConfigError, InputError, StageError
from stereo_recon.core.manifest import library_versions, sha256_file, to_jsonable
from stereo_recon.core.paths import RunPaths

log = logging.getLogger(__name__)

# Version of measurement.json's layout (measure/schemas/measurement.schema.json).
SCHEMA_VERSION = "1.0"


@dataclass(frozen=True)
class MeasureConfig:
    """Every parameter of the measure stage. ``*_res`` are multiples of the resolution; a ``*_m``
    value, when set, overrides the matching multiple (metres)."""

    resolution_m: float | None = None        # point spacing; None => measured (median NN distance)
    resolution_sample: int = 20_000          # query points for the resolution estimate
    # Ground (Algorithm 1): band half-thickness ξ around the density peak.
    ground_band_res: float = 2.0
    ground_band_m: float | None = None
    ground_max_iter: int = 30
    min_ground_fraction: float = 0.05        # a ground layer holds at least this share of all points
    min_ground_contrast: float = 2.0         # ... and this many times the points of the layers beside it
    ground_hint_retry: bool = True           # where no ground passes these from the up hint refined by the local
                                             # normals, Algorithm 1 runs again from the hint as given (an orbit's
                                             # up): on a plain, noisy ground the normals are the truck's and lead
                                             # the start degrees off (tuning seed 2074/6: 2.8 deg, tau 0.008)
    ground_noise_band: float = 2.5           # ξ >= this x the ground layer's measured robust sigma (0 = off)
    ground_noise_thickness: float = 3.0      # d_h >= this x the ground layer's measured robust sigma
    ground_noise_max_res: float | None = None  # ... up to this x resolution (None: no such cap)
    ground_noise_max_spread: float = 0.2     # ... and up to this x the layer's extent in its plane (RMS): a layer
                                             # that thick is a blob or a volume, not a ground
    ground_noise_max_rel: float | None = 0.4   # the ground's removal thickness d_h stays <= this x the height of
                                             # what stands on it (99.9 % quantile of the heights), else refused
    ground_local_thickness: float = 3.0      # also remove ground up to this x its local (per-cell) sigma (0 = off)
    ground_cell_res: float = 40.0            # cell size of that local sigma, x resolution
    # Ground removal thickness d_h (paper: 3–4 x resolution, 0.07 m at theirs).
    ground_thickness_res: float = 3.5
    ground_thickness_m: float | None = None
    # FoF friendship distance ε (paper: 0.05 m at ~2 cm spacing).
    eps_res: float = 3.0
    eps_m: float | None = None
    eps_retry_max: float = 4.0               # with an orbit's centre as the hint and no truck-like cluster at it, FoF
                                             # again at 2, 4, ... x ε up to this factor (1: off; see _truck_points).
                                             # Tuning seeds 2045-2051 (280 clouds): of 8 refused so, 3 now read
                                             # within 1.9 %, 3 are refused by a face gate instead, 2 stay refused
    # Truck-like cluster filters (counts and circumscribed-cuboid size).
    min_cluster_points: int = 300
    max_cluster_points: int | None = None
    min_length_res: float = 50.0
    min_length_m: float | None = None
    max_length_m: float | None = None
    min_width_res: float = 10.0
    min_height_res: float = 10.0
    min_length_to_width: float = 1.3
    max_length_to_width: float = 12.0
    min_height_to_width: float = 0.25
    max_height_to_width: float = 4.0
    ambiguity_ratio: float = 0.8             # runner-up volume >= this x the best => refuse to guess
    min_volume_rel: float = 0.1              # with a centre hint, clusters below this x the largest volume do not compete
    contained_part_share: float | None = 0.5  # two clusters covering the hint are one truck cut apart when the smaller
    contained_part_max_volume_rel: float = 0.5  # lies this share inside the larger's footprint with under this x its
                                             # volume (None: always ambiguous; see measure.truck.TruckFilter)
    part_union_width_rel: float | None = 1.1  # ... or when together they are at most this x as wide as the wider
                                             # alone, at their narrowest (None: off; see measure.truck.TruckFilter)
    max_hint_distance_rel: float | None = 0.15  # with an orbit's centre as the hint, the chosen cluster's footprint lies
                                             # within this x its length of it, else no truck is at the hint (refused;
                                             # None: off). A user's --centre is judged by quality.check_centre instead
    merge_gap_res: float = 15.0              # clusters in line with the truck within this gap join it (a cab across
                                             # the gap to its box); 0 disables (the paper's single cluster)
    merge_min_width_overlap: float = 0.6     # ... when their width ranges overlap by this share of the narrower one
    merge_alongside_max_angle_deg: float = 20.0  # a long part lying along the truck (axes within this angle, both at
    merge_alongside_min_length_to_width: float = 2.0  # least this x as long as wide) is read in the two's joined axes
    merge_apart_beside: bool = True          # a long part standing apart from the truck (together wider than the two
                                             # widths added, at their narrowest) never joins: a vehicle beside it
                                             # (see measure.truck.merge_truck_parts)
    end_scraps_min_height_rel: float | None = 0.1  # beyond either end, scraps within the truck's width join it while
                                             # points reaching this x its height follow each other within the merge
                                             # gap (a cab seen obliquely, in scraps; None: off; see
                                             # measure.truck.join_end_scraps)
    side_by_side_split: bool = True          # a truck's points holding two vehicles side by side, nothing standing
                                             # between them (ground scraps in a narrow gap linked them), are split
                                             # and the one at the centre hint kept (see
                                             # measure.truck.side_by_side_vehicles; False: off)
    side_by_side_max_height_to_width: float = 2.0  # ... when each is at most this x as tall as wide (a whole vehicle)
    side_by_side_min_along_overlap: float = 0.5    # ... and they overlap along by this share of the shorter
    opposite_side_max_offset_rel: float | None = 0.1  # with an orbit's centre as the hint lying beside the truck's parts,
                                             # the cluster across it that is the truck's other side joins them when
                                             # the two centre on the hint within this x their length (None: off;
                                             # see measure.truck.join_opposite_side)
    # Dimension rules (see measure.dimensions).
    peak_min_rel: float = 0.15
    end_window: float = 0.04
    extreme_fraction: float = 0.001
    roof_min_fraction: float = 0.01
    top_above_roof_sigmas: float | None = None  # height from the top 0.5 % of the points when they lie this many
                                                # noise sigmas over the roof level (None: the roof level, as the
                                                # paper; see measure.dimensions.DimensionConfig)
    roof_cells_quantile: float | None = 0.9     # a height read at the roof level spans its upper stretch: this quantile
                                                # of its cells' median levels (None: off; see DimensionConfig)
    wall_min_share: float = 0.85
    peak_min_prominence_sigmas: float | None = None  # place a wall at the outermost peak standing this many of the
                                             # density's standard errors out, not at a noise ripple on its flank
                                             # (None, the default: off; see measure.dimensions.DimensionConfig)
    shoulder_doubt_excess: float | None = 1.0  # a side's points outside its wall, more than the wall's scatter puts there
                                             # but too few for a shoulder: the width with them is a reading the
                                             # uncertainty spans (None: off; see measure.dimensions.DimensionConfig)
    shoulder_pair: bool = True               # ... taken as a shoulder when the other side's passed (a truck is symmetric)
    shoulder_reach_own_flank: bool = True    # a shoulder looked for beyond the wall's own scatter where that is sharper
                                             # than the ground's noise (False: the noise's reach; see DimensionConfig)
    flank_length_segments: int = 3           # a rounded flank's widest line also read stretch by stretch along the
                                             # length, so that a narrower cab does not pull it in (1: the whole
                                             # length only; see DimensionConfig)
    shoulder_fringe_height: float | None = 0.75  # a side's outside points mostly at or above this share of the top
                                             # are a fringe under the roof's edge: no shoulder, a reading the
                                             # uncertainty spans (None: off; see DimensionConfig)
    shoulder_skirt_height: float | None = 0.15  # ... and mostly below this share of the top the ground's skirt fused to
                                             # the walls' foot: no shoulder either, a reading the uncertainty spans
                                             # (None: off; see DimensionConfig)
    end_facing_cos: float | None = 0.7       # each end of the length moved in to its own face's points when the
                                             # peak of all points lies beyond it (None: the paper's peaks; see
                                             # measure.dimensions.DimensionConfig)
    end_step_blurs: float | None = 2.0       # each end of the length moved out to a face a stretch of low heights
                                             # holds beyond it by more than this many blurs: a cab's nose ahead of
                                             # its windscreen (None: off; see measure.dimensions.DimensionConfig)
    end_profile_slices: int = 20             # ... height slices of that profile
    end_step_slices: int = 3                 # ... consecutive slices a stretch spans
    end_step_max_height: float = 0.5         # ... a stretch starting below this share of the top
    ledge_blurs: float | None = 2.5          # each side of the width moved out to a wider part low on the truck, the
                                             # outer edge of its own thin height slice along the length, beyond the
                                             # side by more than this many blurs: a flatbed's deck beside its load
                                             # (None: off; see measure.dimensions.DimensionConfig)
    ledge_slice_share: float = 0.025         # ... those slices' thickness, a share of the top
    ledge_max_height: float = 0.5            # ... slices up to this share of the top
    ledge_min_cover: float = 0.5             # ... a slice's outer part spanning this share of the length
    ledge_walls_quantile: float = 0.75       # ... and standing beyond this quantile of the upper slices' edges
    ledge_below_blurs: float | None = 0.0    # ... and beyond a lower slice's edge by more than this many blurs (a deck
                                             # on its chassis, not a wall's foot flaring into the ground; 0: by any
                                             # amount; None: any slice)
    ledge_less_walls_offset: bool = False    # ... the ledge's edge taken in by the walls' peak-to-edge offset, as for
                                             # a wall (False: where the deck's points end)
    wall_facing_cos: float | None = 0.7      # walls and roof placed by their own facing points (None: the
    roof_facing_cos: float | None = 0.7      # paper's peaks of all points; see measure.dimensions.DimensionConfig)
    curved_flank_min_drop: float | None = 0.02  # a rounded body's width at its widest height (None: off; see
                                                # measure.dimensions.DimensionConfig)
    wall_plateau_slices: int | None = 13        # vertical walls' width from the profile's widest stretch of this many
                                                # height slices of 20 (None: off; see measure.dimensions.DimensionConfig)
    wall_plateau_low_slices: int = 9            # ... none where a stretch of this many from the ground is wider
    wall_plateau_max_top_drop: float = 0.07     # ... under a top seen flat (rounded_top_drop below this)
    wall_plateau_min_outside_height: float = 0.5  # ... and, where the peaks read wider, with the points outside it at
                                                # a median height of at least this share of the top
    crest_flank_min_drop: float | None = 0.005  # under a rounded top, its flanks' widest height with only this fall
                                                # on both sides (None: off; see measure.dimensions.DimensionConfig)
    rounded_top_min_drop: float | None = 0.07   # a rounded top's height from its top 0.5 % of points (None: off; see
                                                # measure.dimensions.DimensionConfig)
    dark_body_max_brightness: float | None = 0.2   # a body this much darker than the ground (median luma ratio): its
                                                # height from its top 0.5 % of points (None: off; see
                                                # measure.dimensions.DimensionConfig)
    roof_stretch_min_share: float | None = 0.25  # the roof level of the stretches of the length whose upper surface lies
    roof_stretch_sigmas: float = 3.0            # this many height bandwidths above the level of all the points, when
                                                # they make this share of the length (None: off; see DimensionConfig)
    heading_wall_max_nz: float | None = 0.3     # the length axis turned to the walls' sharpest projection, its direction
                                                # picked on the points of near-vertical surfaces (|normal z| below
                                                # this; None: all points; see measure.dimensions.DimensionConfig)
    width_min_height: float | None = 0.15       # the width's extent judged from the points at or above this share of the
                                                # top (the ground's skirt at the truck's foot left out; None: all points,
                                                # as the paper; see measure.dimensions.DimensionConfig)
    length_min_height: float | None = 0.15      # an end peak of the length beyond the extent of the points at or above
                                                # this share of the top is the ground's skirt, no end (None: every
                                                # peak, as the paper; see measure.dimensions.DimensionConfig)
    length_extreme_above_skirt: bool = True     # ... nor are all points' extremes past theirs (see measure.dimensions.
                                                # DimensionConfig)
    lattice_dither: bool = True                 # a fused cloud's lattice coordinates dithered one voxel along its
                                                # surfaces and the width read on the dithers (measure.resolution.
                                                # lattice_dither): the voxel planes comb the width's density, read at
                                                # 0.2 voxel, into false walls and shoulders. False: read as fused.
                                                # Tuning seeds 2062-2066 and Table 2 (214 clouds): width mean / p90 /
                                                # rms |error| 2.49 / 5.34 / 4.83 -> 2.27 / 5.47 / 3.44 %; seed 2069
                                                # mean 1.96 -> 2.12 % (docs/ROUNDS.md, 38th-39th rounds)
    lattice_dither_all: bool = False            # true: the length and height are read on the dithers too (the 38th
                                                # round's option). Off: the dither flips the length's end rule both
                                                # ways (its p90 2.13 -> 2.20 % on those clouds, 1.45 -> 1.69 % on seed
                                                # 2068; the CI slice draw random-21-0 +1.04 -> +3.73 %), and the
                                                # heights barely move (mean 0.84 -> 0.82 %)
    lattice_dither_draws: int = 2               # ... that many times; the readings are their mean, their spread a part
                                                # of the uncertainty. Tuning seeds 2062-2066 (193 clouds): width mean /
                                                # p90 / max |error| 2.38 / 5.64 / 19.14 % as fused, one draw 2.24 / 4.97
                                                # / 10.57 % or 2.44 / 6.07 / 13.93 % (two seeds), two 2.27 / 5.13 / 12.25
    bootstrap: int = 30
    seed: int = 0

    def with_overrides(self, **kw: Any) -> "MeasureConfig":
        """A copy with the given fields replaced (None values are ignored)."""
        return dataclasses.replace(self, **{k: v for k, v in kw.items() if v is not None})


def config_from_dict(data: dict, where: str = "config") -> MeasureConfig:
    """A MeasureConfig from a mapping; unknown keys or wrongly typed values -> ConfigError."""
    from stereo_recon.core.config import known_keys

    data = known_keys(data, MeasureConfig, where, "measure parameters", section="measure")
    known = {f.name: f for f in fields(MeasureConfig)}
    defaults = MeasureConfig()
    kw = {}
    for k, v in data.items():
        d = getattr(defaults, k)
        typ = known[k].type
        if v is None:
            if "None" not in str(typ):
                raise ConfigError(f"{where}: {k} cannot be empty")
            kw[k] = None
            continue
        if isinstance(d, bool):    # a switch: true or false, never a number
            if not isinstance(v, bool):
                raise ConfigError(f"{where}: {k} must be true or false, got {v!r}")
            kw[k] = v
            continue
        want_int = "int" in str(typ) and "float" not in str(typ)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{where}: {k} must be a number, got {v!r}")
        if want_int and not float(v).is_integer():
            raise ConfigError(f"{where}: {k} must be an integer, got {v!r}")
        v = int(v) if want_int else float(v)
        if not np.isfinite(v) or (v < 0) or (v == 0 and k not in ("seed", "bootstrap", "ledge_below_blurs") and not isinstance(d, int)):
            raise ConfigError(f"{where}: {k} must be a positive number, got {v!r}")
        if k in ("wall_plateau_slices", "wall_plateau_low_slices") and v < 1:   # a stretch of no slices reads nothing
            raise ConfigError(f"{where}: {k} must be at least 1 (slices), got {v!r}")
        if k in ("roof_cells_quantile", "ledge_walls_quantile") and v > 1:
            raise ConfigError(f"{where}: {k} is a quantile, at most 1, got {v!r}")
        if k == "side_by_side_min_along_overlap" and v > 1:
            raise ConfigError(f"{where}: {k} is a share of the shorter vehicle's length, at most 1, got {v!r}")
        if k in ("wall_facing_cos", "roof_facing_cos", "end_facing_cos") and v > 1:  # above 1 no point faces: the paper's reading unasked
            raise ConfigError(f"{where}: {k} is a cosine, at most 1 (null for the paper's peaks of all points), got {v!r}")
        kw[k] = v
    return MeasureConfig(**kw)


def load_config(path: str | os.PathLike) -> MeasureConfig:
    """Read a TOML or YAML file of MeasureConfig fields (optionally under a ``[measure]`` table)."""
    from stereo_recon.core.config import read_config_file

    return config_from_dict(read_config_file(path), where=str(Path(path)))


@dataclass
class Measurement:
    """Result of :func:`measure_points` (metres; frames as documented per field)."""

    length_m: float
    width_m: float
    height_m: float
    uncertainty_m: dict
    rules: dict
    bandwidths_m: dict
    ground: dict                 # normal (input frame, up), offset, inlier rate, rms, iterations...
    clusters: dict               # counts, rejections per filter, candidates, chosen label
    parameters: dict             # every parameter actually used (resolved to metres)
    timings_s: dict
    n_points: int
    truck_xyz_ground: np.ndarray = field(repr=False)   # truck points in the ground frame (z = height)
    frame_rotation: np.ndarray = field(repr=False)     # R: ground frame = R @ p + t  (Eqs. 5-6)
    frame_translation: np.ndarray = field(repr=False)
    details: dict = field(repr=False, default_factory=dict)   # densities, edges, rectangle, axes

    def summary(self) -> dict:
        """The JSON-ready part (no per-point arrays)."""
        return to_jsonable({
            "length_m": self.length_m,
            "width_m": self.width_m,
            "height_m": self.height_m,
            "uncertainty_m": self.uncertainty_m,
            "rules": self.rules,
            "bandwidths_m": self.bandwidths_m,
            "ground_plane": self.ground,
            "clusters": self.clusters,
            "parameters": self.parameters,
            "timings_s": self.timings_s,
            "n_points": self.n_points,
            "n_truck_points": int(len(self.truck_xyz_ground)),
            "frame": {"rotation": self.frame_rotation, "translation_m": self.frame_translation,
                      "note": "ground frame = rotation @ input + translation; z is height above the fitted ground (Eqs. 5-6)"},
            "axes": {k: self.details[k] for k in ("axes_xy", "origin_xy_m", "heading_refinement_deg", "edges_m", "rear_end", "rectangle_xy_m") if k in self.details},
            "bandwidth_rules": self.details.get("bandwidth_rules"),
            "warnings": self.details.get("warnings", []),
            "roof_support": self.details.get("roof_support"),
            # The second readings the uncertainty spans (measure.dimensions): the side walls' own width when
            # the width came from a shoulder or a rounded flank's widest height, else null; the roof level's
            # and the top 0.5 % of the truck's points' heights (the height is one of them, see rules.height).
            "width_walls_m": self.details.get("width_walls_m"),
            # The width with a side's doubtful shoulder (more points outside a wall than its scatter puts there,
            # too few to pass for a wider part), when the width is the walls' own, else null.
            "width_shoulder_m": self.details.get("width_shoulder_m"),
            "length_peaks_m": self.details.get("length_peaks_m"),
            "height_top_m": self.details.get("height_top_m"),
            "height_roof_m": self.details.get("height_roof_m"),
            "height_roof_cells_m": self.details.get("height_roof_cells_m"),
            "rounded_top_drop": self.details.get("rounded_top_drop"),
            "body_brightness": self.details.get("body_brightness"),
            "bootstrap_std_m": self.details.get("bootstrap_std_m"),
            # The width (every dimension with lattice_dither_all) read on each dither of a fused cloud's lattice (the
            # reading is their mean); null when not dithered (lattice_dither off, or a cloud on no lattice).
            "lattice_draws_m": self.details.get("lattice_draws_m"),
        })


def _parse_vec(v, name: str) -> np.ndarray | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise InputError(f"{name} must be three finite numbers, got {v!r}")
    return a


def _layer_spread(p: np.ndarray, plane, xi_m: float, n: int = 50_000) -> float:
    """RMS extent (m) in its plane of the layer within +-xi_m of the plane (every k-th point, about n)."""
    band = p[np.abs(plane.height(p)) <= xi_m]
    if len(band) < 3:
        return 0.0
    band = band[::max(1, len(band) // n)]
    q = band - band.mean(axis=0)
    ev = np.linalg.eigvalsh(q.T @ q / len(band))
    return float(np.sqrt(max(ev[1], 0.0) + max(ev[2], 0.0)))


def _layer_sigma(heights: np.ndarray, xi_m: float) -> float:
    """Robust sigma (1.4826 MAD) of the heights of points near the ground plane, metres."""
    near = heights[np.abs(heights) <= 8 * xi_m]
    if len(near) < 10:
        return 0.0
    return float(1.4826 * np.median(np.abs(near - np.median(near))))


def body_brightness(truck_rgb: np.ndarray, ground_rgb: np.ndarray) -> float | None:
    """The truck's median luma over the ground's (Rec. 601 weights): a black body reads well under 1.

    truck_rgb, ground_rgb: (N, 3) RGB in [0, 1] of the truck's and the ground layer's points. None when either
    is empty or the ground is black.
    """
    w = np.array([0.299, 0.587, 0.114])
    if len(truck_rgb) == 0 or len(ground_rgb) == 0:
        return None
    ground = float(np.median(ground_rgb @ w))
    return float(np.median(truck_rgb @ w)) / ground if ground > 1e-6 else None


def measure_points(points_xyz: np.ndarray, config: MeasureConfig = MeasureConfig(), up_hint: np.ndarray | None = None,
                   centre_hint: np.ndarray | None = None, rng=0, source: str = "cloud",
                   colors_rgb: np.ndarray | None = None) -> Measurement:
    """Measure the truck in a point cloud.

    points_xyz: (N, 3) metres, any frame. colors_rgb: (N, 3) RGB in [0, 1] or None (the truck's brightness
    against the ground's then stays unknown, see ``body_brightness``). up_hint: approximate ground normal pointing up
    (input frame), e.g. from the camera trajectory; None => estimated from the cloud.
    centre_hint: a point near the truck (input frame), e.g. the orbit centre; used to pick
    the truck among several candidates. rng: seed for subsampling and bootstrap.
    Raises InputError (bad points), StageError (no ground / no truck / ambiguous trucks).
    """
    from measure.dimensions import DimensionConfig, measure_dimensions
    from measure.resolution import point_lattice
    from measure.truck import ground_frame

    cfg = config
    timings: dict[str, float] = {}
    t_all = time.perf_counter()
    p = _checked_points(points_xyz, cfg, source)
    up = _parse_vec(up_hint, "up hint")
    centre = _parse_vec(centre_hint, "centre hint")

    t = time.perf_counter()
    res = _resolution(p, cfg, rng, source)
    # The width's density is read at half the point spacing, 0.2 of a fused cloud's voxel, where the voxel grid's
    # planes ripple it (docs/ROUNDS.md, issue 12's thirty-seventh round): the truck's points are dithered below for the width
    # (lattice_dither, the 38th-39th rounds).
    lattice = point_lattice(p)
    timings["resolution"] = time.perf_counter() - t

    t = time.perf_counter()
    g = _ground(p, cfg, res, up, rng, source)
    timings["ground"] = time.perf_counter() - t
    above = p[g.keep]
    if len(above) < cfg.min_cluster_points:
        raise StageError("measure", f"{source}: no truck-like cluster (only {len(above)} points above the ground layer of {g.d_h:.3g} m)")
    # A ground is thin beside what stands on it. A layer so noisy that removing it (d_h) takes a large share of
    # what stands there cannot be told from the truck's lower part, and its level is pulled up by the wheels and
    # the chassis inside its band (a model truck 0.38 m tall on a ground of sigma 30 / 60 / 90 mm, d_h 26 / 53 /
    # 78 % of it: heights -1.9 / -2.8 / -6.1 %; tests/measure/test_measure_ground_noise.py).
    if cfg.ground_noise_max_rel is not None and g.d_h > cfg.ground_noise_max_rel * g.top_m:
        raise StageError("measure", f"{source}: no ground plane (the layer is {1000 * g.layer_sigma:.3g} mm thick (robust sigma): removing "
                                    f"it ({g.d_h:.3g} m) would take {100 * g.d_h / max(g.top_m, 1e-12):.0f}% of the {g.top_m:.3g} m that stands on "
                                    f"it, > {100 * cfg.ground_noise_max_rel:.0f}%; the depth is too noisy there (plain, untextured ground or a "
                                    "far range) to place the ground)")

    R = ground_frame(g.plane.normal)
    tvec = np.array([0.0, 0.0, g.plane.offset])
    xyz_g = above @ R.T + tvec     # Eqs. 5-6
    centre_xy = None if centre is None else (R @ centre + tvec)[:2]
    truck, in_truck, filt, eps, cstats = _truck_points(above, xyz_g, centre_xy, cfg, res, timings, source, ground_m=g.d_h)
    # The noise that blurs the truck's own surfaces is the ground layer's where the truck stands: the
    # whole ground's RMS is dominated by far, noisier ground and would smooth the roof into the walls.
    noise_m = g.plane.rms_m
    if g.local_sigma is not None:
        noise_m = float(min(noise_m, np.median(g.local_sigma[g.keep][in_truck])))

    t = time.perf_counter()
    # The dimension rules' parameters are the MeasureConfig fields of the same names.
    dcfg = DimensionConfig(**{f.name: getattr(cfg, f.name) for f in fields(DimensionConfig) if hasattr(cfg, f.name)})
    brightness = None
    if colors_rgb is not None and len(colors_rgb) == len(p):
        brightness = body_brightness(colors_rgb[g.keep][in_truck], colors_rgb[~g.keep])
    dithered = lattice is not None and cfg.lattice_dither and cfg.lattice_dither_draws > 0
    if dithered:
        from measure.normals import point_normals

        # The surfaces' normals, once: the dither moves the points along them, and every reading uses them
        # (three readings of the cloud: ~1 s each on a model truck's 10^5 points).
        normals = point_normals(truck, dcfg.normal_neighbours)
        # As fused first: the length and height are then read exactly as without the dither (same bootstrap stream).
        dims = None if cfg.lattice_dither_all else \
            measure_dimensions(truck, res, noise_m=noise_m, config=dcfg, rng=rng, body_brightness=brightness, normals=normals)
        draws = _surface_dither(above[in_truck], R, lattice, normals, cfg.lattice_dither_draws, cfg.seed if rng is None else rng)
        on_draws = _mean_of_draws([measure_dimensions(truck + d, res, noise_m=noise_m, config=dcfg, rng=rng,
                                                      body_brightness=brightness, normals=normals) for d in draws],
                                  ("length", "width", "height") if cfg.lattice_dither_all else ("width",))
        if cfg.lattice_dither_all:
            dims = on_draws
            truck = truck + draws[0]     # the points the details (densities, plots) were read from
        else:
            dims = _with_dimension(dims, on_draws, "width")
    else:
        dims = measure_dimensions(truck, res, noise_m=noise_m, config=dcfg, rng=rng, body_brightness=brightness)
    timings["dimensions"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_all
    if "side_by_side" in cstats:
        o = cstats["side_by_side"]["other_vehicle_m"]
        dims["warnings"] = [*dims.get("warnings", []),
                            f"a second vehicle ({o[0]:.3g} x {o[1]:.3g} x {o[2]:.3g} m) stood beside the truck and was clustered "
                            f"with it; the two were split at the gap between them and "
                            f"{'the one at the orbit centre' if cstats['side_by_side']['rule'] == 'nearest_to_centre_hint' else 'the larger'} measured"]

    params = dataclasses.asdict(cfg)
    params["resolved"] = {"resolution_m": res, "ground_band_m": g.xi, "ground_thickness_m": g.d_h, "eps_m": eps,
                          "min_length_m": filt.min_length_m, "min_width_m": filt.min_width_m, "min_height_m": filt.min_height_m,
                          "resolution_measured": cfg.resolution_m is None, "lattice_m": lattice,
                          "lattice_dithered": bool(dithered)}
    params["up_hint"] = up
    params["centre_hint"] = centre
    cstats["n_truck_points"] = int(len(truck))
    return Measurement(
        length_m=float(dims["length_m"]), width_m=float(dims["width_m"]), height_m=float(dims["height_m"]),
        uncertainty_m=dims["uncertainty_m"], rules=dims["rules"], bandwidths_m=dims["bandwidths_m"],
        ground=g.record(noise_m), clusters=cstats, parameters=params, timings_s=timings, n_points=len(p),
        truck_xyz_ground=truck, frame_rotation=R, frame_translation=tvec, details=dims,
    )


def _surface_dither(points_in: np.ndarray, R: np.ndarray, lattice_m: float, normals: np.ndarray, draws: int,
                    rng) -> list[np.ndarray]:
    """Displacements (N, 3), ground frame, that dither a fused truck's lattice coordinates along its surfaces: draws of them.

    points_in: the truck's points in the input (fusion) frame, where the lattice lies; R: the rotation from the
    input frame to the ground frame; lattice_m: the lattice (m); normals: the points' unit normals (ground frame);
    rng: seed. Each displacement is ``measure.resolution.lattice_dither``'s less its part along the point's
    surface normal: the comb a surface makes along the lattice is filled in, while a wall or roof stays as thin
    as it was fused (the whole dither thickened them: on tuning seeds 2062-2066 the p90 of |error| over length,
    width and height went 3.44 -> 3.64 %; along the surfaces 3.47 %).
    """
    from measure.resolution import lattice_dither

    # Its own stream: the bootstrap draws from the seed itself.
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng([int(rng), 38])
    out = []
    for _ in range(draws):
        d = lattice_dither(points_in, lattice_m, rng=gen) @ R.T
        out.append(d - np.sum(d * normals, axis=1, keepdims=True) * normals)
    return out


def _mean_of_draws(runs: list[dict], dims=("length", "width", "height")) -> dict:
    """One reading from the dimensions of several dithers of a cloud: the first's details, the mean of the readings
    of ``dims`` (the others: the first's).

    Where one dither of the lattice moves a reading from the next (16 of 193 tuning clouds' widths by more than
    2 %), the reading rests on where the voxel planes fell, not on the truck: their spread (sample standard
    deviation) is added to each dimension's uncertainty, and the draws are kept under ``lattice_draws_m``.
    """
    out = dict(runs[0])
    if len(runs) == 1:
        return out
    out["uncertainty_m"] = dict(out["uncertainty_m"])
    out["lattice_draws_m"] = {}
    for d in dims:
        vals = np.array([float(r[f"{d}_m"]) for r in runs])
        out[f"{d}_m"] = float(vals.mean())
        out["lattice_draws_m"][d] = vals.tolist()
        u = np.sqrt(np.mean([float(r["uncertainty_m"][d]) ** 2 for r in runs]) + np.var(vals, ddof=1))
        out["uncertainty_m"][d] = float(u)
    return out


def _with_dimension(base: dict, other: dict, dim: str) -> dict:
    """``measure_dimensions``' output ``base`` with one dimension's reading (value, rule, bandwidth, edges, density,
    uncertainty, warnings, its own details) taken from ``other``; the fitted rectangle follows its edges.

    base, other: outputs for the same truck (other: on its dithered points, ``_mean_of_draws``); dim: "length",
    "width" or "height".
    """
    from measure.dimensions import fitted_rectangle

    out = dict(base)
    for k, v in other.items():
        if k.startswith(dim + "_"):
            out[k] = v
    for k in ("uncertainty_m", "bootstrap_std_m", "rules", "bandwidths_m", "bandwidth_rules", "edges_m", "densities"):
        if dim in other.get(k, {}):
            out[k] = {**base[k], dim: other[k][dim]}
    out["warnings"] = ([w for w in base["warnings"] if not w.startswith(dim + " ")]
                       + [w for w in other["warnings"] if w.startswith(dim + " ")])
    if "lattice_draws_m" in other:
        out["lattice_draws_m"] = {dim: other["lattice_draws_m"][dim]}
    # Same truck, same axes up to the dither's sub-voxel shift of the centroid: the base's axes carry the edges.
    out["rectangle_xy_m"] = fitted_rectangle(out["origin_xy_m"], out["axes_xy"]["length"], out["axes_xy"]["width"], out["edges_m"])
    return out


def _checked_points(points_xyz: np.ndarray, cfg: MeasureConfig, source: str) -> np.ndarray:
    """The points as (N, 3) float64; InputError for a wrong shape, NaN/inf, or too few points."""
    p = np.asarray(points_xyz, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{source}: points must be an (N, 3) array, got shape {p.shape}")
    if not np.isfinite(p).all():
        raise InputError(f"{source}: points contain NaN or infinite coordinates")
    if len(p) < max(100, cfg.min_cluster_points):
        raise InputError(f"{source}: only {len(p)} points, at least {max(100, cfg.min_cluster_points)} are needed")
    return p


def _resolution(p: np.ndarray, cfg: MeasureConfig, rng, source: str) -> float:
    """The cloud's point spacing, metres: ``cfg.resolution_m`` or the measured median nearest-neighbour distance."""
    from scipy.spatial import cKDTree

    from measure.resolution import point_resolution

    if cfg.resolution_m is not None:
        res = float(cfg.resolution_m)
    else:
        res = point_resolution(p, cfg.resolution_sample, rng=cfg.seed if rng is None else rng,
                               tree=cKDTree(p, balanced_tree=False, compact_nodes=False))
    if not res > 0:
        raise InputError(f"{source}: most points are exact duplicates; cannot measure the point spacing")
    return res


@dataclass
class _Ground:
    """The ground step's result: the plane, band ξ and removal thickness d_h (metres), and what it measured."""

    plane: Any
    xi: float
    d_h: float
    layer_sigma: float
    contrast: float
    top_m: float          # the 99.9 % quantile of all points' heights above the plane: what stands on the ground
    keep: np.ndarray      # (N,) bool: points above the ground layer
    local_sigma: np.ndarray | None = None   # (N,) the ground layer's sigma in each point's cell (m)

    def record(self, noise_at_truck_m: float) -> dict:
        """measurement.json's ``ground_plane``; noise_at_truck_m: the noise used for the truck's surfaces (m)."""
        plane = self.plane
        return {"normal": plane.normal, "offset_m": plane.offset, "equation": "normal . p + offset_m = 0 (normal points up)",
                "inlier_rate": plane.inlier_rate, "n_inliers": plane.n_inliers, "rms_m": plane.rms_m, "iterations": plane.iterations,
                "initial_normal": plane.initial_normal, "initial_normal_source": plane.initial_normal_source,
                "n_above_ground": int(self.keep.sum()), "layer_contrast": self.contrast, "layer_sigma_m": self.layer_sigma,
                "band_xi_m": self.xi, "n_removed": int((~self.keep).sum()), "noise_at_truck_m": noise_at_truck_m}


def _ground(p: np.ndarray, cfg: MeasureConfig, res: float, up, rng, source: str) -> _Ground:
    """Algorithm 1 with the band widened to a noisy layer's own thickness; StageError when there is no ground.

    Started from the up hint refined by the local normals; where that finds no ground and
    ``cfg.ground_hint_retry`` is set, again from the hint as given (the first error stands if that fails too).
    """
    try:
        return _ground_from(p, cfg, res, up, rng, source, refine_hint=True)
    except StageError as err:
        if up is None or not cfg.ground_hint_retry:
            raise
        first = err
    try:
        return _ground_from(p, cfg, res, up, rng, source, refine_hint=False)
    except StageError:
        raise first from None


def _ground_from(p: np.ndarray, cfg: MeasureConfig, res: float, up, rng, source: str, refine_hint: bool) -> _Ground:
    """``_ground`` from one start: the up hint refined by the local normals, or (refine_hint False) as given."""
    from measure.ground import ground_plane, local_layer_sigma

    xi = cfg.ground_band_m or cfg.ground_band_res * res
    d_h = cfg.ground_thickness_m or cfg.ground_thickness_res * res
    try:
        plane = ground_plane(p, xi, up_hint=up, max_iter=cfg.ground_max_iter, rng=rng, refine_hint=refine_hint)
        # A fused stereo cloud's ground is thicker than its point spacing (depth noise grows
        # with range), so a band of a few spacings would cut the layer in half. Measure the
        # layer's own thickness (robust sigma of the heights near the plane) and widen ξ and
        # d_h to it when the caller has not fixed them.
        layer_sigma = _layer_sigma(plane.height(p), xi)
        noisy_xi = cfg.ground_noise_band * layer_sigma
        # A layer as thick as it is wide is no ground at all (a blob, a volume): do not widen, and let the
        # layer-contrast check below reject it. The cap is the layer's own extent, not the point spacing: the
        # spacing is the fusion's voxel, not the depth's precision, and plain asphalt matched from 2-4 m is
        # 5-10 spacings thick yet a plane that places the height well (11 tuning draws were refused by a cap
        # of 12 spacings; the 7 the face gates pass have their heights within 2.5 %). Whether a ground is too
        # noisy for the truck on it is judged against what stands on it (measure_points).
        spread = None   # the layer's extent, measured only when the band is to widen
        if cfg.ground_band_m is None and cfg.ground_noise_band > 0 and xi < noisy_xi:
            spread = _layer_spread(p, plane, xi)
            cap = cfg.ground_noise_max_spread * spread
            if cfg.ground_noise_max_res is not None:
                cap = min(cap, cfg.ground_noise_max_res * res)
            if noisy_xi <= cap:
                xi = noisy_xi
                plane = ground_plane(p, xi, up_hint=plane.normal, max_iter=cfg.ground_max_iter, rng=rng, refine_hint=refine_hint)
                layer_sigma = _layer_sigma(plane.height(p), xi)
        if cfg.ground_thickness_m is None and xi == noisy_xi:
            d_h = max(d_h, cfg.ground_noise_thickness * layer_sigma)
    except ValueError as err:
        raise StageError("measure", f"{source}: no ground plane ({err})") from None
    if plane.inlier_rate < cfg.min_ground_fraction:
        raise StageError("measure", f"{source}: no ground plane (the densest planar layer holds only {100 * plane.inlier_rate:.1f}% of the points, "
                                    f"< {100 * cfg.min_ground_fraction:.0f}%)")
    # A ground is a dense layer: it must hold clearly more points than the layers of the same
    # thickness just above and below it (a blob or a volume has no such layer).
    hgt = plane.height(p)
    n_band = int((np.abs(hgt) <= xi).sum())
    n_next = max(int(((hgt > xi) & (hgt <= 3 * xi)).sum()), int(((hgt < -xi) & (hgt >= -3 * xi)).sum()), 1)
    contrast = n_band / n_next
    if contrast < cfg.min_ground_contrast:
        thick = ""
        if spread is not None and xi < noisy_xi:
            # Say why: the band was not widened to the layer's thickness.
            thick = (f"; the layer is {1000 * layer_sigma:.3g} mm thick (robust sigma), {100 * layer_sigma / max(spread, 1e-12):.1f} % of "
                     f"its extent and {layer_sigma / res:.1f} x the point spacing: no thin planar layer to place the ground on")
        raise StageError("measure", f"{source}: no ground plane (the densest layer holds {n_band} points, only {contrast:.2f} x its neighbouring layers; "
                                    f"a ground needs >= {cfg.min_ground_contrast:g} x{thick})")
    keep = hgt > d_h   # remove_ground(p, plane, d_h), reusing the heights
    local = None
    if cfg.ground_local_thickness > 0:
        # Far ground is a thicker layer (stereo depth noise grows with Z^2): remove it by its own
        # thickness, cell by cell, so that it does not stand as clutter around the truck.
        local = local_layer_sigma(p, plane, cfg.ground_cell_res * res, 8 * xi)
        keep &= hgt > cfg.ground_local_thickness * local
    return _Ground(plane, xi, d_h, layer_sigma, contrast, top_m=float(np.quantile(hgt, 0.999)), keep=keep, local_sigma=local)


def _truck_points(above: np.ndarray, xyz_g: np.ndarray, centre_xy, cfg: MeasureConfig, res: float, timings: dict,
                  source: str, ground_m: float = 0.0):
    """Algorithm 2 and the truck filters: (truck points in the ground frame, their mask over ``above``, the
    TruckFilter, ε in metres, cluster stats).

    above: points above the ground (input frame); xyz_g: the same in the ground frame; ground_m: the ground's removal
    thickness d_h (m; scraps of ground stand up to about twice it). Adds 'fof' and 'truck' to timings.
    With a centre hint (the orbit's centre) and no truck-like cluster at it, the clustering is repeated at 2, 4, ...
    x ε up to ``eps_retry_max``: a large truck's plain walls reconstructed in patches fall apart at the ε of its
    point spacing (on tuning seed 2051 a clean full-scale semi-trailer came out as 3274 clusters, the longest 3.6 m
    of its 14.9). Of the ε that give a truck at the hint the smallest is kept whose truck holds 90 % of the points
    the coarsest one's does: at a gap barely bridged only part of the truck joins. A vehicle parked beside the
    truck, a width or more away, lies far beyond 4 ε (12 spacings). Two clusters covering the hint at a coarser ε
    are skipped (seen from above vehicles do not overlap: they are one truck's halves, joined at the next ε); at
    the first ε they stay refused and are not retried, unless one lies inside the other's footprint or adds no
    width to it (``TruckFilter.contained_part_share``, ``part_union_width_rel``: then they are one truck at any ε).
    """
    from measure.truck import NoTruckError

    eps = cfg.eps_m or cfg.eps_res * res
    try:
        truck, in_truck, filt, cstats = _truck_at(above, xyz_g, centre_xy, cfg, res, eps, timings, source, ground_m)
        cstats["eps_factor"] = 1.0
        return truck, in_truck, filt, eps, cstats
    except NoTruckError as err:
        if centre_xy is None or cfg.eps_retry_max < 2:
            raise
        first = err
    found, tried = [], []
    factor = 2.0
    while factor <= cfg.eps_retry_max:
        tried.append(factor)
        try:
            found.append((factor, _truck_at(above, xyz_g, centre_xy, cfg, res, eps * factor, timings, source, ground_m)))
        except StageError:
            pass   # none at the hint, or two covering it: one truck's halves cut lengthwise, vehicles do not overlap
        factor *= 2
    if not found:
        raise NoTruckError(f"{str(first).removeprefix('measure: ')}; clustered at ε = {eps:.3g} m and again at "
                           f"{' and '.join(f'{f:g}' for f in tried)} x ε")
    # A gap barely bridged joins part of the truck only: take the smallest ε whose truck holds nearly all the
    # points that the coarsest one's does.
    most = max(len(r[0]) for _, r in found)
    factor, (truck, in_truck, filt, cstats) = next((f, r) for f, r in found if len(r[0]) >= 0.9 * most)
    log.info("measure: %s; clustered again at %g x eps", first, factor)
    cstats["eps_factor"] = factor
    return truck, in_truck, filt, eps * factor, cstats


def _truck_at(above: np.ndarray, xyz_g: np.ndarray, centre_xy, cfg: MeasureConfig, res: float, eps: float,
              timings: dict, source: str, ground_m: float = 0.0):
    """FoF at ε = eps (m), the truck filters and the selection: (truck points, mask over ``above``, filter, stats)."""
    from measure.fof import fof_clusters
    from measure.truck import (TruckFilter, check_hint_distance, join_end_scraps, join_opposite_side, merge_truck_parts,
                               select_truck)

    t = time.perf_counter()
    labels = fof_clusters(above, eps)
    timings["fof"] = timings.get("fof", 0.0) + time.perf_counter() - t

    t = time.perf_counter()
    filt = TruckFilter(
        min_points=cfg.min_cluster_points, max_points=cfg.max_cluster_points,
        min_length_m=cfg.min_length_m or cfg.min_length_res * res, max_length_m=cfg.max_length_m,
        min_width_m=cfg.min_width_res * res, min_height_m=cfg.min_height_res * res,
        min_length_to_width=cfg.min_length_to_width, max_length_to_width=cfg.max_length_to_width,
        min_height_to_width=cfg.min_height_to_width, max_height_to_width=cfg.max_height_to_width,
        ambiguity_ratio=cfg.ambiguity_ratio, min_volume_rel=cfg.min_volume_rel,
        contained_part_share=cfg.contained_part_share, contained_part_max_volume_rel=cfg.contained_part_max_volume_rel,
        part_union_width_rel=cfg.part_union_width_rel,
    )
    try:
        chosen, cstats = select_truck(xyz_g, labels, filt, centre_xy, source=source)
        part_min_points = max(cfg.min_cluster_points // 5, 20)   # a part of the truck, not a truck of its own
        if cfg.merge_gap_res > 0:
            parts = merge_truck_parts(xyz_g, labels, chosen, cfg.merge_gap_res * res, part_min_points,
                                      min_width_overlap=cfg.merge_min_width_overlap,
                                      alongside_max_angle_deg=cfg.merge_alongside_max_angle_deg,
                                      alongside_min_length_to_width=cfg.merge_alongside_min_length_to_width,
                                      apart_beside=cfg.merge_apart_beside)
        else:
            parts = [chosen]
        if centre_xy is not None and cfg.opposite_side_max_offset_rel is not None:
            joined = join_opposite_side(xyz_g, labels, parts, centre_xy, part_min_points, cfg.opposite_side_max_offset_rel)
            cstats["opposite_side_labels"] = sorted(set(joined) - set(parts))
            parts = joined
        in_truck = np.isin(labels, parts)
        if centre_xy is not None and cfg.max_hint_distance_rel is not None:
            cstats["hint_distance_m"] = check_hint_distance(xyz_g[in_truck], centre_xy, cfg.max_hint_distance_rel, source)
        if cfg.merge_gap_res > 0 and cfg.end_scraps_min_height_rel is not None:
            # Only once a truck stands at the hint: scraps lengthen a truck found, they do not make one (a truck
            # in patches is clustered again coarser instead, _truck_points).
            joined = join_end_scraps(xyz_g, labels, parts, cfg.merge_gap_res * res, cfg.end_scraps_min_height_rel,
                                     min_height_m=2 * ground_m)
            cstats["end_scrap_labels"] = sorted(set(joined) - set(parts))
            parts = joined
            in_truck = np.isin(labels, parts)
        cstats["merged_labels"] = parts
        if cfg.side_by_side_split:
            in_truck = _one_of_side_by_side(xyz_g, in_truck, centre_xy, cfg, filt, res, ground_m, cstats, source)
    finally:
        timings["truck"] = timings.get("truck", 0.0) + time.perf_counter() - t
    return xyz_g[in_truck], in_truck, filt, cstats


def _one_of_side_by_side(xyz_g: np.ndarray, in_truck: np.ndarray, centre_xy, cfg: MeasureConfig, filt, res: float,
                         ground_m: float, cstats: dict, source: str) -> np.ndarray:
    """The truck's mask when its points hold two vehicles side by side (``measure.truck.side_by_side_vehicles``):
    the one at the centre hint (else the larger; StageError when that is ambiguous or it is not truck-like),
    else ``in_truck`` unchanged. Records the split in cstats['side_by_side']."""
    from measure.truck import _choose, _filter_reason, check_hint_distance, cuboid, side_by_side_vehicles

    idx = np.flatnonzero(in_truck)
    pieces = side_by_side_vehicles(xyz_g[idx], res, ground_m, max_height_to_width=cfg.side_by_side_max_height_to_width,
                                   min_along_overlap=cfg.side_by_side_min_along_overlap)
    if pieces is None:
        return in_truck
    boxes = [cuboid(xyz_g[idx[m], :2], xyz_g[idx[m], 2]) for m in pieces]
    dims = " and ".join(f"{b['length_m']:.3g} x {b['width_m']:.3g} x {b['height_m']:.3g} m" for b in boxes)
    try:
        k, rule = _choose(list(enumerate(boxes)), filt, centre_xy, source)
    except StageError as err:
        raise StageError("measure", f"{source}: two vehicles stand side by side in one cluster ({dims}) and neither is "
                                    f"clearly the truck: {str(err).removeprefix('measure: ')}") from None
    why = _filter_reason(boxes[k], filt)
    if why is not None:
        raise StageError("measure", f"{source}: two vehicles stand side by side in one cluster ({dims}); the one chosen "
                                    f"({rule.replace('_', ' ')}) is not truck-like: {why[1]}")
    out = np.zeros_like(in_truck)
    out[idx[pieces[k]]] = True
    if centre_xy is not None and cfg.max_hint_distance_rel is not None:
        cstats["hint_distance_m"] = check_hint_distance(xyz_g[out], centre_xy, cfg.max_hint_distance_rel, source)
    other = boxes[1 - k]
    cstats["side_by_side"] = {"rule": rule, "kept_points": int(out.sum()), "other_vehicle_points": int(pieces[1 - k].sum()),
                              "gap_points": int(len(idx) - pieces[0].sum() - pieces[1].sum()),
                              "other_vehicle_m": [other["length_m"], other["width_m"], other["height_m"]]}
    log.info("measure: %s: two vehicles side by side in one cluster (%s): kept the one %s", source, dims,
             rule.replace("_", " "))
    return out


def combined_uncertainty(values_m: dict, measurement_u_m: dict, reconstruction_rel_sigma: dict | None,
                         reconstruction_abs_m: dict | None = None):
    """One standard uncertainty per dimension: the measurement's own and the reconstruction's, in quadrature.

    values_m / measurement_u_m: {length, width, height} in metres (the cloud's measurement and its
    uncertainty). reconstruction_rel_sigma: {length, width, height} relative standard error of the
    cloud itself (e.g. 0.0144 = 1.44 % of the width), or None when the cloud is taken as exact.
    reconstruction_abs_m: a further standard error of the cloud in metres per dimension (the depth
    geometry's, ``stereo_recon.app.uncertainty.depth_sigma_m``), or None.
    Returns (uncertainty_m, parts or None); ConfigError for a negative or non-finite share.
    """
    from measure.limits import DIMENSIONS

    if not reconstruction_rel_sigma and not reconstruction_abs_m:
        return dict(measurement_u_m), None
    rel, absolute = {}, {}
    for d in DIMENSIONS:
        for name, table, out in (("reconstruction_rel_sigma", reconstruction_rel_sigma, rel),
                                 ("reconstruction_abs_m", reconstruction_abs_m, absolute)):
            r = (table or {}).get(d, 0.0)
            if not (isinstance(r, (int, float)) and math.isfinite(r) and r >= 0):
                raise ConfigError(f"{name}[{d!r}] must be a finite number >= 0, got {r!r}")
            out[d] = float(r)
    recon = {d: math.hypot(rel[d] * abs(float(values_m[d])), absolute[d]) for d in rel}
    total = {d: float(math.hypot(float(measurement_u_m[d]), recon[d])) for d in rel}
    parts = {"measurement_m": dict(measurement_u_m), "reconstruction_m": recon, "reconstruction_rel_sigma": rel}
    if reconstruction_abs_m:
        parts["reconstruction_depth_m"] = absolute
    return total, parts


def measure_cloud_file(cloud_path, out_dir, config: MeasureConfig = MeasureConfig(), up_hint=None, centre_hint=None,
                       regulation: str = "cn-2016-62", vehicle_class: str | None = None, scale: float | None = None,
                       plots: bool = True, html: bool = True, k_sigma: float = 2.0,
                       reconstruction_rel_sigma: dict | None = None, progress=None, case: dict | None = None,
                       reconstruction_abs_m: dict | None = None,
                       units: str = "m", centre_strict: bool = False,
                       checks: list[dict] | None = None, camera_centres=None, record_path=None, keyframe=None) -> dict:
    """Measure the truck in a cloud file; write ``out_dir/measurement.json`` (+ PNG plots, report.html).

    Output is written into a staging folder and moved into ``out_dir`` only when everything
    succeeded, so a failure leaves no half-written folder. Returns the JSON dict.

    measurement.json: ``length_m``, ``width_m``, ``height_m`` (metres, real size of what was
    measured, no scale applied), ``uncertainty_m`` {length, width, height} (one standard
    uncertainty: the measurement's own, combined with ``reconstruction_rel_sigma`` x the value when
    given, the parts then under ``uncertainty_parts``), ``verdict`` (measure.limits.over_limit_verdict),
    ``rules`` (which rule gave each number), ``bandwidths_m`` and ``bandwidth_rules`` (Eq. 8), ``bootstrap_std_m``, ``warnings``,
    ``ground_plane`` (normal, offset, inlier rate, rms, iterations, initial normal and its source),
    ``clusters`` (counts, rejections per filter with an example, candidates, selection rule,
    merged labels), ``parameters`` (every MeasureConfig field plus the resolved metres),
    ``frame`` (Eqs. 5-6 rotation/translation), ``axes``, ``input`` {path, sha256,
    n_points}, ``regulation``, ``versions``, ``plots``. Plots: width_density.png,
    length_density.png (paper Figs. 5-6), top_view.png, side_view.png; report.html.
    progress: optional callback (stage, done, total or None): 'measure', 'plots', 'report'.
    case: optional {site, operator, case_id} shown in the report (``case`` in measurement.json).
    When the cloud's folder is a run folder (run.json, poses.txt), ``recording`` names the source video and
    calibration with their sha256 and the recording time; with ``keyframe`` (a callable
    ``(run_dir, measurement, out_path) -> {frame, time_s, path} or None``, e.g.
    ``stereo_recon.app.evidence.keyframe_with_box``) a frame with the measured box joins the plots.
    The record validates against ``measure/schemas/measurement.schema.json`` (``schema_version``).
    ``data_quality`` {ok, checks}: ``checks`` given (the recording's gates) plus the truck's own
    (faces seen; orbit arc and camera motion when ``camera_centres`` (N, 3), cloud frame, are given);
    a failed one makes the verdict ``undecided`` (``measure.quality``). The file holds no times or
    dates (same input, same bytes): they go to ``measure_run.json``.

    units: the cloud's length unit (m, cm, mm). centre_strict: ``centre_hint`` was given by the user,
    so a truck far from it is an error. record_path: the path to record for the cloud (where it will
    live once a run's folder is committed). A cloud that cannot be a vehicle (units, scale, ground
    only) is refused (``measure.quality.check_plausible``).
    """
    from measure.cloud_io import read_cloud_colors
    from measure.limits import load_regulation
    from measure.quality import UNITS_M

    cloud_path = Path(cloud_path)
    report = progress or (lambda stage, done, total: None)
    report("measure", 0, None)
    t0 = time.perf_counter()
    if units not in UNITS_M:
        raise ConfigError(f"--units {units!r}: expected one of {', '.join(UNITS_M)}")
    reg = load_regulation(regulation)   # fail early on a bad table or class, before any work
    reg.limits(vehicle_class)
    pts, colors = read_cloud_colors(cloud_path, min_points=max(100, config.min_cluster_points))
    pts = pts * UNITS_M[units]
    t_read = time.perf_counter() - t0
    recorded = Path(record_path) if record_path is not None else cloud_path.resolve()
    name = str(record_path) if record_path is not None else str(cloud_path)
    centre = None if centre_hint is None else np.asarray(centre_hint, float) * (UNITS_M[units] if centre_strict else 1.0)
    # A user's --centre is a point near the truck, judged by check_centre (within its length); an orbit's
    # centre lies on or next to the footprint of the truck circled.
    hint_cfg = dataclasses.replace(config, max_hint_distance_rel=None) if centre_strict else config
    m = measure_points(pts, hint_cfg, up_hint=up_hint, centre_hint=centre, rng=config.seed, source=name, colors_rgb=colors)
    gates = _quality_gates(m, scale, units, name, centre if centre_strict else None, checks, camera_centres)
    values = {"length": m.length_m, "width": m.width_m, "height": m.height_m}
    uncertainty, parts = combined_uncertainty(values, m.uncertainty_m, reconstruction_rel_sigma, reconstruction_abs_m)
    verdict = _verdict(values, uncertainty, reg, vehicle_class, scale, k_sigma, gates)
    summary = m.summary()
    timings = dict(summary.pop("timings_s"), read=t_read)
    result = _record(m, summary, uncertainty, parts, verdict, gates,
                     {"path": str(recorded), "sha256": sha256_file(cloud_path), "n_points": len(pts), "units": units},
                     {"name": regulation, "vehicle_class": vehicle_class, "scale": scale, "k_sigma": k_sigma}, case)
    run_info = _run_info(cloud_path.parent)
    if run_info:
        result["recording"] = _recording(run_info)
    manifest = {"command": "measure", "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "input": result["input"], "timings_s": timings}
    _write_folder(out_dir, m, result, manifest, report, scale=scale, plots=plots, html=html, run_info=run_info,
                  keyframe=(lambda dest: keyframe(cloud_path.parent, to_jsonable(result), dest)) if keyframe and run_info else None)
    return to_jsonable(result)


def _quality_gates(m: Measurement, scale, units: str, name: str, strict_centre, checks, camera_centres) -> list[dict]:
    """Refuse a cloud that cannot be a vehicle; the data-quality gates: the given ``checks`` plus the truck's own."""
    from measure.quality import check_centre, check_plausible, face_checks, orbit_checks, shape_checks

    check_plausible(m, scale, units, name)
    if strict_centre is not None:
        check_centre(m, strict_centre, name)
    gates = list(checks or []) + face_checks(m) + shape_checks(m)
    if camera_centres is not None and len(camera_centres):
        gates += orbit_checks(m, camera_centres)
    return gates


def _verdict(values: dict, uncertainty: dict, reg, vehicle_class, scale, k_sigma: float, gates: list[dict]) -> dict:
    """The over-limit verdict against the regulation, made ``undecided`` by a failed data-quality gate."""
    from measure.limits import over_limit_verdict
    from measure.quality import apply_data_quality

    verdict = over_limit_verdict(values, uncertainty, reg, vehicle_class=vehicle_class, scale=scale, k_sigma=k_sigma)
    return apply_data_quality(verdict, gates)


def _record(m: Measurement, summary: dict, uncertainty: dict, parts, verdict: dict, gates: list[dict], inp: dict,
            regulation: dict, case: dict | None) -> dict:
    """measurement.json's content (before the recording and plots are added); see :func:`measure_cloud_file`."""
    from measure.quality import data_quality

    result = {
        "schema_version": SCHEMA_VERSION,
        "length_m": m.length_m, "width_m": m.width_m, "height_m": m.height_m, "uncertainty_m": uncertainty,
        **({"uncertainty_parts": parts} if parts else {}),
        "verdict": verdict,
        "data_quality": data_quality(gates),
        **{k: v for k, v in summary.items() if k not in ("length_m", "width_m", "height_m", "uncertainty_m")},
        "input": inp,
        "input_path": inp["path"], "input_sha256": inp["sha256"],
        "regulation": regulation,
        "versions": library_versions(),
        "stage": "measure",
    }
    case = {k: str(v) for k, v in (case or {}).items() if v}
    if case:
        result["case"] = case
    return result


def _write_folder(out_dir, m: Measurement, result: dict, manifest: dict, report, scale, plots: bool, html: bool,
                  run_info: dict | None, keyframe) -> None:
    """Write measurement.json, measure_run.json, the plots, the keyframe and report.html as one folder transaction.

    keyframe: ``keyframe(dest) -> {frame, time_s, path} or None`` drawing the measured box on a frame, or None.
    """
    from stereo_recon.core.atomic import staged_output_dir, write_json_atomic

    with staged_output_dir(out_dir) as tmp:
        out = RunPaths(tmp)
        images: dict[str, Path] = {}
        if plots:
            report("plots", 0, None)
            t = time.perf_counter()
            images = write_plots(m, tmp, scale=scale)
            kf = keyframe(out.keyframe) if keyframe is not None else None
            if kf is not None:
                images["keyframe"] = Path(kf["path"])
                result["recording"]["keyframe"] = {"frame": kf["frame"], "time_s": kf["time_s"]}
            manifest["timings_s"]["plots"] = time.perf_counter() - t
        result["plots"] = {k: v.name for k, v in images.items()}
        write_json_atomic(out.measurement, result)
        write_json_atomic(out.measure_run, manifest)
        if html:
            try:
                from measure.report_html import render_report_html
            except ImportError:
                render_report_html = None
            if render_report_html is not None:
                report("report", 0, None)
                render_report_html(to_jsonable(dict(result, created_utc=manifest["created_utc"])), images, out.report,
                                   run_info=run_info)


def _run_info(folder: Path) -> dict | None:
    """The reconstruction manifest (run.json) of the folder the cloud came from, or None."""
    import json

    try:
        info = json.loads(RunPaths(folder).run_json.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) else None


def _recording(run_info: dict) -> dict:
    """Source video and calibration (path, sha256, from run.json) and the recording time from the container."""
    from measure.evidence import recording_time

    inputs = run_info.get("inputs") or {}
    rec = {k: inputs[k] for k in ("video", "calib") if isinstance(inputs.get(k), dict)}
    video = (inputs.get("video") or {}).get("path")
    if video:
        rec.update(recording_time(video))
    return rec


def write_plots(m: Measurement, folder: Path, scale: float | None = None) -> dict[str, Path]:
    """PNG plots of a measurement (densities like the paper's Figs. 5-6, top and side views).

    scale: model-to-real factor; when given every length is drawn at real size (the verdict's units).
    """
    from measure import plots

    k = float(scale) if scale else 1.0
    units = f"m, real size = model x {k:g}" if scale else "m"
    d = m.details
    out: dict[str, Path] = {}
    xy = m.truck_xyz_ground[:, :2] - d["origin_xy_m"]
    u1, u2 = d["axes_xy"]["length"], d["axes_xy"]["width"]
    a, b = k * (xy @ u1), k * (xy @ u2)
    for name, samples in (("width", b), ("length", a)):
        dens = d["densities"][name]
        e0, e1 = (k * e for e in d["edges_m"][name])
        out[f"{name}_density"] = plots.plot_density(
            folder / f"{name}_density.png", name, k * np.asarray(dens["grid_m"]), np.asarray(dens["density"]) / k,
            samples_m=samples, peaks_m=(e0, e1), markers_m={"start": e0, "end": e1}, units=units,
            facing_density=None if dens.get("facing_density") is None else np.asarray(dens["facing_density"]) / k,
            title=f"{name}: {k * getattr(m, name + '_m'):.3f} m ({m.rules[name]}, h = {k * m.bandwidths_m[name]:.3g} m)")
    # Top and side views in the truck's own axes (length along x).
    (l0, l1), (w0, w1) = ((k * e for e in d["edges_m"][n]) for n in ("length", "width"))
    rect = np.array([[l0, w0], [l1, w0], [l1, w1], [l0, w1]])
    out["top_view"] = plots.plot_top_view(folder / "top_view.png", np.stack([a, b], axis=1), rect, k * m.length_m,
                                          k * m.width_m, units=units)
    out["side_view"] = plots.plot_side_view(folder / "side_view.png", np.stack([a, k * m.truck_xyz_ground[:, 2]], axis=1),
                                            k * m.height_m, units=units)
    return out
