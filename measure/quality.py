"""Data-quality gates on a measured truck: units and content, faces seen, orbit and camera motion.

A measurement is only as good as what was seen: length is bounded by the front and rear faces (or,
where an end face was not reconstructed, by both side walls and the roof reaching that end together, or
a rounded body's shell reaching it on most of its outline), width by the two side walls (or, where one
was not reconstructed, by the roof and an end face reaching it, or a rounded body's flank seen along
the length), height by the roof (and the ground). A gate that fails turns the verdict into
``undecided`` (``apply_data_quality``); content that cannot be a vehicle at all (a 2 km or 3 mm
"truck", a bump in the ground) is refused with a hint (``check_plausible``).
Checks follow the ``measurement.json["data_quality"]`` contract: ``{"name", "status", "detail"}``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereo_recon.core.errors import InputError, StageError

UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}   # --units: metres per unit of the cloud's coordinates


@dataclass(frozen=True)
class TruckQualityConfig:
    """Thresholds of the truck gates (fractions, metres, degrees)."""

    # Sizes a measured vehicle (or a scale model of one) can have, metres; outside: wrong units.
    min_size_m: float = 0.05
    max_size_m: float = 40.0
    # A road vehicle's length (m) after --scale; outside: the scale factor is wrong.
    min_real_length_m: float = 2.0
    max_real_length_m: float = 40.0
    # A truck stands clear of the ground: height >= this x the ground layer's noise (rms, resolution).
    min_height_to_ground_noise: float = 10.0
    # Faces: share of a face's cells (a grid over its rectangle, 10-90 % of the height) holding points
    # within a band of its plane; below min: not seen, the dimension it bounds is undecided.
    face_grid: tuple[int, int] = (12, 4)       # cells along the face, cells up it
    face_band_rel: float = 0.04                # band half-width: this x the dimension across the face ...
    face_band_res: float = 4.0                 # ... or this x the resolution, whichever is larger
    min_face_coverage: float = 0.25
    # An end whose own face is under min_face_coverage still bounds the length when both side walls and the
    # roof reach it: each covers at least this share of its rim cells (the walls' 8 cells up 10-90 % of the
    # height, the roof's 8 across 10-90 % of the width) within the end's band. A plain end face is often
    # not reconstructed while the walls and roof, seen to their ends, are (tuning seeds 2034-2037: of the
    # 15 draws refused for an end face, 12 had read the length within 2.5 %; the 5 whose rims all reach
    # the end read it within 0.1-2.5 %; the other 10, among them cut or wrong clusters 7.5-34 % off,
    # stay refused). None: off.
    min_rim_coverage: float | None = 0.5
    # Likewise a side wall under min_face_coverage still bounds the width when the roof reaches it (its 8
    # rim cells along 10-90 % of the length, within the side's band at the roof level) and so does one
    # end face (its 8 cells up 10-90 % of the height, within the side's band), each at least
    # min_rim_coverage: a plain wall seen obliquely or not at all (one side of a 240 deg arc) while the
    # roof, seen from above to its edge, is. One end, not both: a semi-trailer's or a flatbed's front is a
    # narrower tractor. On tuning seeds 2045-2046, of 6 draws refused for a side: 2 pass (widths +2.16 and
    # +2.25 %, truth 0.7 and 0.6 sigma off); a model semi-trailer 13.7 % wide, whose roof reached the side
    # but no end, a box whose ends reach it on 38 / 25 % of their cells, a flatbed (its load's top does
    # not reach the deck's edge) and a wrong cluster stay refused. False: off.
    side_rims: bool = True
    min_roof_support: float = 0.02             # share of the truck's points at the roof level (0.10: warn)
    # A rounded top (height rule ``rounded_top_99.5``, a tank's crest) has no roof level: under
    # min_roof_support its height is still bounded when the crest (points within the roof's band of the
    # top) is seen along the length, in at least min_rim_coverage of 8 cells over 10-90 % of it. On tuning
    # seeds 2045-2047 two full-scale tankers were refused for a roof whose heights read -0.15 and -0.78 %.
    # False: off.
    crest_rim: bool = True
    # A rounded body (a tank: height rule ``rounded_top_99.5`` or width rule ``curved_flank_vertex``) whose
    # end face is under min_face_coverage and whose walls and roof edge cannot fill the end's rims (it has
    # neither) still bounds the length when its shell's outline reaches the end: at least min_rim_coverage of
    # 8 sectors of the cross-section (``_outline_rims``). False: off.
    rounded_outline: bool = True
    # Likewise a rounded body's side whose face is under min_face_coverage (a tank's flank touches the side
    # plane along one line only, so most of the face's cells up the height stay empty) still bounds the
    # width when that line is seen along the length: at least min_rim_coverage of 8 cells over 10-90 % of it
    # hold 3 or more points within the side's band (``_cells_hit``). On tuning seeds 2045-2050 (240 clouds)
    # it lifts one refusal, a full-scale tanker read W +1.80 % (0.6 sigma); a tanker whose right side is seen
    # along 25 % of the length and a model tanker read 68 % too wide (12 %) stay refused. False: off.
    rounded_side_line: bool = True
    # Any face under min_face_coverage whose opposite face is seen (at least min_face_coverage) still bounds its
    # dimension when the points within its band, pooled over its rims (the roof's edge, the foot, the walls' or
    # the ends' edges) and what little of the face was matched, reach along it and up it: at least
    # min_rim_coverage of 8 cells over 10-90 % of its width (an end) or length (a side), and of 8 cells up
    # 10-90 % of the height, each holding 3 or more points. The rules above ask each rim to reach it on its
    # own; a face seen only obliquely (the far side of a 240-260 deg arc) often keeps parts of several. Of the
    # 22 draws the face gates refused on tuning seeds 2045-2051 (280 clouds) it lifts six faces on six draws,
    # five now measured, read within 3.0 % (truth 0.0-1.9 sigma off; the sixth stays refused for its other
    # side). Every refused face read 4.9 % or more off stays refused (the nearest: a model flatbed's front
    # read +6 % reaches 50 % of its width but 12 % of its height); so do two sides read right, seen along 12
    # and 25 % of the length. (Counted within the face's own 10-90 % only, it lifts none: its rims carry it.)
    # False: off.
    pooled_rims: bool = True
    # A vehicle is never much wider than it stands tall (trucks 0.8-1.3 x, a car about 1.25 x): a width over this x
    # the height is two vehicles side by side measured as one, or a truck cut low. Over the 345 bench measurements
    # of seeds 2070-2077, the 12 tuning draws of 2062-2066 and Table 2 the widest for its height read 1.35 x; the
    # two pairs of vehicles clustered as one, 1.97 and 2.96 x (W +197 and +201 %). None: off.
    max_width_to_height: float | None = 1.8
    # Orbit: azimuth range of the camera centres around the truck (deg) and their spread seen from it.
    min_orbit_arc_deg: float = 180.0
    warn_orbit_arc_deg: float = 300.0
    # A --centre farther than this x the truck's length from its footprint picked nothing near it.
    max_centre_offset_rel: float = 1.0


def _check(name: str, status: str, detail: str) -> dict:
    return {"name": name, "status": status, "detail": detail}


def check_plausible(m, scale: float | None, units: str, source: str, config: TruckQualityConfig = TruckQualityConfig()):
    """Refuse a measurement that cannot be a vehicle: wrong units, wrong scale, or only the ground.

    m: ``measure.pipeline.Measurement`` (metres after ``units``). Raises InputError with a hint.
    """
    c = config
    dims = {"length": m.length_m, "width": m.width_m, "height": m.height_m}
    big = {d: v for d, v in dims.items() if v > c.max_size_m}
    if big:
        d, v = max(big.items(), key=lambda kv: kv[1])
        fits = [u for u, f in (("cm", 0.01), ("mm", 0.001)) if c.min_size_m <= v / UNITS_M[units] * f <= c.max_size_m]
        hint = f"--units {fits[-1]}" if fits else "--units m|cm|mm"
        raise InputError(f"{source}: the truck's {d} reads {v:.4g} m, which no vehicle has: is the cloud in other "
                         f"units than {units}? ({hint})")
    if dims["length"] < c.min_size_m:
        raise InputError(f"{source}: the truck's length reads {dims['length'] * 1000:.3g} mm, too small for a vehicle or "
                         f"a model of one (>= {c.min_size_m * 100:g} cm): check the cloud's units (--units m|cm|mm) "
                         "or its scale")
    noise = max(float(m.ground.get("rms_m") or 0.0), float(m.ground.get("layer_sigma_m") or 0.0),
                float(m.parameters["resolved"]["resolution_m"]))
    if dims["height"] < c.min_height_to_ground_noise * noise:
        raise StageError("measure", f"{source}: no truck: the best cluster ({m.clusters.get('n_truck_points')} points) is "
                                    f"{dims['height'] * 1000:.3g} mm tall, only {dims['height'] / noise:.1f} x the ground "
                                    f"layer's noise ({noise * 1000:.3g} mm): the cloud holds ground, not a vehicle")
    if scale is not None:
        real = dims["length"] * scale
        if not c.min_real_length_m <= real <= c.max_real_length_m:
            raise InputError(f"--scale {scale:g}: the truck would be {real:.4g} m long, not a road vehicle "
                             f"({c.min_real_length_m:g}-{c.max_real_length_m:g} m); --scale is the model-to-real factor "
                             "(e.g. 14 for a 1:14 model); for a cloud in other units use --units m|cm|mm")


def check_centre(m, centre_in: np.ndarray, source: str, config: TruckQualityConfig = TruckQualityConfig()) -> None:
    """Refuse a ``--centre`` (input frame, metres) that is far from the truck chosen (and so from every candidate)."""
    c_g = m.frame_rotation @ np.asarray(centre_in, float) + m.frame_translation
    rect = np.asarray(m.details["rectangle_xy_m"], float)
    lo, hi = rect.min(axis=0), rect.max(axis=0)
    dist = float(np.linalg.norm(np.maximum(0.0, np.maximum(lo - c_g[:2], c_g[:2] - hi))))
    if dist > config.max_centre_offset_rel * m.length_m:
        raise InputError(f"--centre {','.join(f'{v:g}' for v in centre_in)}: {dist:.1f} m from the nearest truck-like "
                         f"cluster in {source} (a {m.length_m:.2f} m truck): no vehicle there")


def _truck_axes(m):
    """Truck points in its own axes: along the length a, across b, height z; and the edges (the side walls'
    peaks where the width was read at a rounded flank's widest height)."""
    d = m.details
    xy = m.truck_xyz_ground[:, :2] - np.asarray(d["origin_xy_m"])
    a = xy @ np.asarray(d["axes_xy"]["length"])
    b = xy @ np.asarray(d["axes_xy"]["width"])
    return a, b, m.truck_xyz_ground[:, 2], d["edges_m"]["length"], d.get("width_wall_edges_m", d["edges_m"]["width"])


def _coverage(along: np.ndarray, up: np.ndarray, span: tuple[float, float], height: float, grid) -> float:
    """Share of a face's grid cells (10-90 % of its span and of the height) that hold at least one point.

    The outer tenth at each side is left out: there the neighbouring faces (a side wall's end at a
    rear face that was never seen) would fill the cells.
    """
    n_along, n_up = grid
    s0, s1 = span[0] + 0.1 * (span[1] - span[0]), span[1] - 0.1 * (span[1] - span[0])
    i = np.floor((along - s0) / max(s1 - s0, 1e-12) * n_along).astype(int)
    j = np.floor((up - 0.1 * height) / (0.8 * height) * n_up).astype(int)
    ok = (i >= 0) & (i < n_along) & (j >= 0) & (j < n_up)
    return len(set(zip(i[ok].tolist(), j[ok].tolist()))) / float(n_along * n_up)


def _cells_hit(x: np.ndarray, lo: float, hi: float, n: int = 8, min_points: int = 1) -> float:
    """Share of n equal cells spanning the middle 80 % of [lo, hi] (m) that hold at least min_points of x (m)."""
    i = np.floor((x - (lo + 0.1 * (hi - lo))) / max(0.8 * (hi - lo), 1e-12) * n).astype(int)
    return float(np.count_nonzero(np.bincount(i[(i >= 0) & (i < n)], minlength=n) >= min_points)) / float(n)


def _end_rims(a, b, z, end: float, band_end: float, walls: tuple[float, float], band_side: float, H: float,
              band_roof: float) -> tuple[float, float, float]:
    """Shares of the rim cells of an end (m along the length) holding points: each side wall's 8 cells up
    10-90 % of the height H, and the roof's 8 cells across 10-90 % of the width, within band_end of it."""
    near = np.abs(a - end) <= band_end
    w0, w1 = walls
    return (_cells_hit(z[near & (np.abs(b - w0) <= band_side)], 0.0, H),
            _cells_hit(z[near & (np.abs(b - w1) <= band_side)], 0.0, H),
            _cells_hit(b[near & (np.abs(z - H) <= band_roof)], w0, w1))


def _outline_rims(a, b, z, end: float, band_end: float, ends: tuple[float, float], mid: float, H: float, band: float,
                  n: int = 8, min_hits: int = 3) -> float:
    """Share of n sectors of the body's cross-section outline that reach an end (m along the length): the
    sectors split 0-180 deg about (mid, H/2) across the width and height (one side, over the top, the other
    side); a sector reaches the end where at least min_hits points within band_end of it lie within band
    (m) of the body's outline there (the 99th percentile radius of its points over the rest of the
    length, ends l0..l1 in m). A box's outline is its walls and roof, a tank's its rounded shell."""
    r = np.hypot(b - mid, z - 0.5 * H)
    k = np.floor(np.degrees(np.arctan2(z - 0.5 * H, b - mid)) / (180.0 / n)).astype(int)
    up = (k >= 0) & (k < n)
    near = up & (np.abs(a - end) <= band_end)
    rest = up & (a > ends[0] + band_end) & (a < ends[1] - band_end)
    hits = 0
    for s in range(n):
        body = r[rest & (k == s)]
        if len(body) < 20:
            continue
        hits += int(np.count_nonzero(r[near & (k == s)] >= np.quantile(body, 0.99) - band) >= min_hits)
    return hits / n


def _side_rims(a, b, z, side: float, band_side: float, ends: tuple[float, float], band_end: float, H: float,
               band_roof: float) -> tuple[float, float, float]:
    """Shares of the rim cells of a side wall (m across the width) holding points: the roof's 8 cells along
    10-90 % of the length (ends l0..l1, m) at the roof level H, and each end face's 8 cells up 10-90 % of
    the height, within band_side of it."""
    near = np.abs(b - side) <= band_side
    l0, l1 = ends
    return (_cells_hit(a[near & (np.abs(z - H) <= band_roof)], l0, l1),
            _cells_hit(z[near & (np.abs(a - l0) <= band_end)], 0.0, H),
            _cells_hit(z[near & (np.abs(a - l1) <= band_end)], 0.0, H))


def face_checks(m, config: TruckQualityConfig = TruckQualityConfig()) -> list[dict]:
    """Per-face point support: front/rear (length), both side walls (width), roof (height)."""
    c = config
    a, b, z, (l0, l1), (w0, w1) = _truck_axes(m)
    res = float(m.parameters["resolved"]["resolution_m"])
    H = m.height_m
    band_end = max(c.face_band_rel * m.length_m, c.face_band_res * res)
    band_side = max(c.face_band_rel * m.width_m, c.face_band_res * res)
    band_roof = max(c.face_band_rel * H, c.face_band_res * res)
    cover = {
        "rear": _coverage(b[np.abs(a - l0) <= band_end], z[np.abs(a - l0) <= band_end], (w0, w1), H, (c.face_grid[1] * 2, c.face_grid[1])),
        "front": _coverage(b[np.abs(a - l1) <= band_end], z[np.abs(a - l1) <= band_end], (w0, w1), H, (c.face_grid[1] * 2, c.face_grid[1])),
        "right": _coverage(a[np.abs(b - w0) <= band_side], z[np.abs(b - w0) <= band_side], (l0, l1), H, c.face_grid),
        "left": _coverage(a[np.abs(b - w1) <= band_side], z[np.abs(b - w1) <= band_side], (l0, l1), H, c.face_grid),
    }
    out = []
    rules = getattr(m, "rules", None) or {}
    rounded = rules.get("height") == "rounded_top_99.5" or rules.get("width") == "curved_flank_vertex"
    for dim, faces in (("length", ("front", "rear")), ("width", ("left", "right"))):
        low = [f for f in faces if cover[f] < c.min_face_coverage]
        txt = ", ".join(f"{f} {100 * cover[f]:.0f}%" for f in faces)
        by_rims = []
        if dim == "length" and c.min_rim_coverage is not None:
            for f in list(low):
                rims = _end_rims(a, b, z, l1 if f == "front" else l0, band_end, (w0, w1), band_side, H, band_roof)
                if min(rims) >= c.min_rim_coverage:
                    low.remove(f)
                    by_rims.append(f"{f} bounded by both side walls and the roof reaching it "
                                   f"({'/'.join(f'{100 * r:.0f}' for r in rims)}% of their rims)")
                elif c.rounded_outline and rounded:
                    # A rounded body has no walls or roof edge to fill the rims: its shell's outline reaches the end.
                    share = _outline_rims(a, b, z, l1 if f == "front" else l0, band_end, (l0, l1), 0.5 * (w0 + w1), H,
                                          band_side)
                    if share >= c.min_rim_coverage:
                        low.remove(f)
                        by_rims.append(f"{f} bounded by the rounded body's outline reaching it ({100 * share:.0f}% of "
                                       "its sectors)")
        if dim == "width" and c.min_rim_coverage is not None:
            for f in list(low):
                side = w0 if f == "right" else w1
                if c.side_rims:
                    roof_rim, rear_rim, front_rim = _side_rims(a, b, z, side, band_side, (l0, l1), band_end, H, band_roof)
                    if roof_rim >= c.min_rim_coverage and max(rear_rim, front_rim) >= c.min_rim_coverage:
                        low.remove(f)
                        by_rims.append(f"{f} bounded by the roof and an end reaching it ({100 * roof_rim:.0f}% of the "
                                       f"roof's rim, {100 * rear_rim:.0f}/{100 * front_rim:.0f}% of the rear/front's)")
                        continue
                if c.rounded_side_line and rounded:
                    # A rounded flank meets the side plane along one line, not over the face's height.
                    line = _cells_hit(a[np.abs(b - side) <= band_side], l0, l1, min_points=3)
                    if line >= c.min_rim_coverage:
                        low.remove(f)
                        by_rims.append(f"{f} bounded by the rounded body's flank seen along {100 * line:.0f}% of the "
                                       "length")
        if c.pooled_rims and c.min_rim_coverage is not None:
            for f in list(low):
                # The rim rules above ask each rim to reach the face; a face seen only obliquely (the far side of a
                # short arc) often keeps parts of several: pooled, they still place its plane.
                if cover[faces[1] if f == faces[0] else faces[0]] < c.min_face_coverage:
                    continue   # the opposite face unseen too: nothing holds the dimension's other end
                if dim == "length":
                    near = np.abs(a - (l1 if f == "front" else l0)) <= band_end
                    along = _cells_hit(b[near], w0, w1, min_points=3)
                else:
                    near = np.abs(b - (w0 if f == "right" else w1)) <= band_side
                    along = _cells_hit(a[near], l0, l1, min_points=3)
                up = _cells_hit(z[near], 0.0, H, min_points=3)
                if min(along, up) >= c.min_rim_coverage:
                    low.remove(f)
                    by_rims.append(f"{f} bounded by its rims, pooled: its band holds points along {100 * along:.0f}% of "
                                   f"its {'width' if dim == 'length' else 'length'} and up {100 * up:.0f}% of its height")
        status = "fail" if low else ("warn" if by_rims else "pass")
        out.append(_check(f"faces_{dim}", status,
                          f"{txt} of the face covered (need {100 * c.min_face_coverage:.0f}%)"
                          + (f": {' and '.join(low)} not seen, the {dim} is not bounded" if low else "")
                          + (f"; {'; '.join(by_rims)}" if by_rims else "")))
    roof = float(m.details.get("roof_support") or 0.0)
    status = "fail" if roof < c.min_roof_support else ("warn" if roof < 0.10 else "pass")
    crest = ""
    if status == "fail" and c.crest_rim and c.min_rim_coverage is not None and m.rules.get("height") == "rounded_top_99.5":
        # A rounded top has no roof level to hold points: its crest, seen along the length, bounds the height.
        along = _cells_hit(a[np.abs(z - H) <= band_roof], l0, l1)
        if along >= c.min_rim_coverage:
            status, crest = "warn", f"; the rounded top's crest seen along {100 * along:.0f}% of the length bounds it"
    out.append(_check("faces_height", status, f"{100 * roof:.1f}% of the truck's points at the roof level"
                      + (": the roof was not seen, the height is not bounded" if status == "fail" else "") + crest))
    return out


def shape_checks(m, config: TruckQualityConfig = TruckQualityConfig()) -> list[dict]:
    """The measured outline's proportions: a width over ``max_width_to_height`` x the height is no vehicle's."""
    c = config
    if c.max_width_to_height is None or m.height_m <= 0:
        return []
    ratio = m.width_m / m.height_m
    if ratio > c.max_width_to_height:
        return [_check("vehicle_shape", "fail", f"the width reads {m.width_m:.3g} m, {ratio:.2f} x the height ({m.height_m:.3g} m): "
                       f"no vehicle is wider than {c.max_width_to_height:g} x its height; two vehicles side by side "
                       "were measured as one, or the truck was cut low")]
    return [_check("vehicle_shape", "pass", f"the width is {ratio:.2f} x the height")]


def orbit_checks(m, camera_centres: np.ndarray, config: TruckQualityConfig = TruckQualityConfig()) -> list[dict]:
    """Orbit arc around the truck, from camera centres (N, 3; cloud frame, m)."""
    c = config
    d = m.details
    centres = np.asarray(camera_centres, float).reshape(-1, 3) @ m.frame_rotation.T + m.frame_translation
    mid_a, mid_b = np.mean(d["edges_m"]["length"]), np.mean(d["edges_m"]["width"])
    truck_xy = np.asarray(d["origin_xy_m"]) + mid_a * np.asarray(d["axes_xy"]["length"]) + mid_b * np.asarray(d["axes_xy"]["width"])
    rel = centres[:, :2] - truck_xy
    az = np.sort(np.degrees(np.arctan2(rel[:, 1], rel[:, 0])))
    gaps = np.diff(np.concatenate([az, az[:1] + 360.0])) if len(az) > 1 else np.array([360.0])
    arc = float(360.0 - gaps.max())
    status = "fail" if arc < c.min_orbit_arc_deg else ("warn" if arc < c.warn_orbit_arc_deg else "pass")
    out = [_check("orbit_arc", status, f"the cameras cover {arc:.0f} deg around the truck ({len(centres)} poses)"
                  + ("; the faces away from the cameras were seen obliquely or not at all" if status != "pass" else ""))]
    return out


# Which dimensions a failed check leaves unbounded (others: all of them).
_CHECK_DIMENSIONS = {"faces_length": ("length",), "faces_width": ("width",), "faces_height": ("height",)}


def data_quality(checks: list[dict]) -> dict:
    """The ``data_quality`` block: ok unless a check failed."""
    return {"ok": not any(ch["status"] == "fail" for ch in checks), "checks": list(checks)}


def apply_data_quality(verdict: dict, checks: list[dict]) -> dict:
    """The verdict with every failed gate applied: the dimensions it leaves unbounded and the overall
    verdict become ``undecided``, the reason names the failed checks. Unchanged when all pass.

    The overall verdict is ``undecided`` even when a dimension the failed gate does not bound reads over
    the limit: an unseen face is often the sign of a wrong or partial cluster, which the other dimensions
    share. Of the 8 full-scale draws of evaluation seed 2034 refused by a face gate, 4 had a dimension that
    passed its own gate off by 6-74 % (a fragment measured instead of a 6.6 m tanker, heights 6-27 % low);
    an ``over`` or ``within`` read from such a dimension would be a confident wrong verdict.
    """
    failed = [ch for ch in checks if ch["status"] == "fail"]
    if not failed:
        return verdict
    for ch in failed:
        for dim in _CHECK_DIMENSIONS.get(ch["name"], ("length", "width", "height")):
            entry = (verdict.get("dimensions") or {}).get(dim)
            if entry is not None and entry.get("verdict") in ("over", "within"):
                entry["verdict"] = "undecided"
    verdict["overall"] = "undecided"
    verdict["reason"] = "data quality: " + "; ".join(f"{ch['name']}: {ch['detail']}" for ch in failed)
    return verdict
