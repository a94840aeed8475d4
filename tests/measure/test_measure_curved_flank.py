"""The width of a rounded body (``measure.dimensions.curved_flank_width``): a tank is widest at one height only."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from measure.dimensions import DimensionConfig, curved_flank_width, measure_dimensions, wall_plateau, width_profile
from measure.normals import point_normals


def _face(rng, n, x, y, z):
    return np.column_stack([rng.uniform(*x, n), rng.uniform(*y, n), rng.uniform(*z, n)])


def _elliptic_tanker(rng, L=1.6, W=0.26, H=0.40, noise=0.003, n=80_000):
    """The envelope's tanker (``stereo_recon.synthetic.scene``): an elliptic tank (semi-axes W/2 across,
    (H - z_floor)/2 up) from the floor at 0.27 H to the top, a cab 3 % narrower than the tank up to 0.8 H,
    wheels inside; every point scattered by ``noise`` (m) along its surface normal. Truth: W exactly."""
    z_floor = 0.27 * H
    a, b, zc = W / 2, (H - z_floor) / 2, (z_floor + H) / 2
    # Uniform in area: accept angles by arc length.
    t = rng.uniform(0, 2 * np.pi, 3 * n)
    ds = np.hypot(a * np.sin(t), b * np.cos(t))
    t = t[rng.uniform(0, ds.max(), len(t)) < ds][:n]
    x = rng.uniform(-L / 2, 0.25 * L, len(t))
    nrm = np.column_stack([np.zeros_like(t), np.cos(t) / a, np.sin(t) / b])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    tank = np.column_stack([x, a * np.cos(t), zc + b * np.sin(t)]) + rng.normal(0, noise, (len(t), 1)) * nrm
    wc = 0.97 * W
    cab = [_face(rng, n // 8, (0.3 * L, L / 2), (-wc / 2, wc / 2), (0.8 * H, 0.8 * H)),
           _face(rng, n // 16, (L / 2, L / 2), (-wc / 2, wc / 2), (0.1 * H, 0.8 * H))]
    for s in (-1, 1):
        side = _face(rng, n // 6, (0.3 * L, L / 2), (s * wc / 2, s * wc / 2), (0.1 * H, 0.8 * H))
        side[:, 1] += rng.normal(0, noise, len(side))
        cab.append(side)
        cab.append(_face(rng, n // 40, (-0.4 * L, 0.4 * L), (s * 0.4 * W, s * 0.4 * W), (0.0, 0.12 * H)))  # wheels
    return np.vstack([tank, *cab])


def test_a_tank_is_measured_at_its_widest_height():
    """The flank's points over all heights peak inside the tank's widest line (and the cab's flat walls,
    3 % narrower, add to that): the peaks' reading is 2.8 % low here with a 1.1 % sigma (the truth outside
    its 2 sigma), the profile's vertex is within 0.3 % (sigma 1.7 %: it spans both readings). Read over the
    whole length only, the cab's walls merge with the flank's peak in each height slice and pull the vertex
    in: -0.8 % (``flank_length_segments``; the envelope's tankers read 1-3 % narrow that way)."""
    W = 0.26
    for seed in range(3):
        xyz = _elliptic_tanker(np.random.default_rng(seed), W=W)
        m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003)
        assert m["rules"]["width"] == "curved_flank_vertex", m["rules"]
        assert abs(m["width_m"] / W - 1) < 0.004, m["width_m"]                      # measured: -0.18 to -0.24 %
        whole = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=replace(DimensionConfig(), flank_length_segments=1))
        assert whole["rules"]["width"] == "curved_flank_vertex" and whole["width_m"] < m["width_m"] - 0.001, whole["width_m"]
        assert whole["width_m"] / W - 1 < -0.006, whole["width_m"]                  # measured: -0.80 to -0.83 %
        assert abs(m["width_m"] - W) <= 2 * m["uncertainty_m"]["width"], m["uncertainty_m"]
        assert m["width_walls_m"] < m["width_m"] and m["uncertainty_m"]["width"] >= (m["width_m"] - m["width_walls_m"]) / 2
        assert any("rounded flank" in w for w in m["warnings"])
        peaks = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003,
                                   config=replace(DimensionConfig(), curved_flank_min_drop=None, crest_flank_min_drop=None))
        assert peaks["width_m"] < 0.98 * W, peaks["width_m"]     # the failure: the flank read inside ...
        assert W - peaks["width_m"] > 2 * peaks["uncertainty_m"]["width"], peaks["uncertainty_m"]   # ... confidently


def test_under_a_crest_a_noisy_flank_is_still_read_at_its_widest_height():
    """A tank fused with 9 mm of noise (3.5 % of its width; tuning tankers' profiles scatter as much): the
    strict vertex test rejects the ragged profile and the peaks over all heights read 3.2-4.4 % low, their
    sigma 1.1-1.3 %: the truth lies 2.6-3.9 sigma out. The crest (``rounded_top_99.5``) already shows the
    body is rounded, so the vertex is read with only the fall on both sides (``crest_flank_min_drop``):
    within 1.5 %, and the uncertainty spans both readings. A flat-roofed box is no crest: unchanged."""
    W = 0.26
    for seed in range(4):
        xyz = _elliptic_tanker(np.random.default_rng(seed), W=W, noise=0.009, n=20_000)
        m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.009)
        assert m["rules"]["height"] == "rounded_top_99.5" and m["rules"]["width"] == "curved_flank_vertex", m["rules"]
        assert abs(m["width_m"] / W - 1) < 0.015 and abs(m["width_m"] - W) <= 2 * m["uncertainty_m"]["width"], m["width_m"]
        assert m["uncertainty_m"]["width"] >= (m["width_m"] - m["width_walls_m"]) / 2
        strict = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.009, config=replace(DimensionConfig(), crest_flank_min_drop=None))
        assert strict["rules"]["width"] == "kde_two_peaks", strict["rules"]     # the failure: read inside ...
        assert W - strict["width_m"] > 2 * strict["uncertainty_m"]["width"], (strict["width_m"], strict["uncertainty_m"])  # ... confidently
    box = _flaring_box(np.random.default_rng(3))
    on = measure_dimensions(box, resolution_m=0.004, noise_m=0.003)
    off = measure_dimensions(box, resolution_m=0.004, noise_m=0.003, config=replace(DimensionConfig(), crest_flank_min_drop=None))
    assert on["rules"]["height"] != "rounded_top_99.5" and on["width_m"] == off["width_m"], (on["rules"], on["width_m"], off["width_m"])


def _flaring_box(rng, L=2.0, W=0.38, H=0.40):
    """A box's walls, noisy (4 mm) and with their top tenth flared 1.5 cm outwards (stereo fattening at the
    roof's rim), a roof and two ends. Truth: W."""
    pts = [_face(rng, 40_000, (-L / 2, L / 2), (-W / 2, W / 2), (H, H))]
    for s in (-1, 1):
        wall = _face(rng, 40_000, (-L / 2, L / 2), (s * W / 2, s * W / 2), (0.1 * H, H))
        wall[:, 1] += rng.normal(0, 0.004, len(wall))
        rim = wall[:, 2] > 0.9 * H
        wall[rim, 1] += s * 0.015 * (wall[rim, 2] - 0.9 * H) / (0.1 * H)
        pts.append(wall)
    for x in (-L / 2, L / 2):
        pts.append(_face(rng, 10_000, (x, x), (-W / 2, W / 2), (0.1 * H, H)))
    return np.vstack(pts)


def test_flat_walls_and_a_flaring_rim_keep_the_walls_reading():
    """A box's flaring rim (``_flaring_box``): no concave maximum inside the profile, so the profile's vertex
    changes nothing (the shoulder rule reads the flare, +6 % here: its own limit, not this rule's; the
    walls' plateau, below, reads past it)."""
    xyz = _flaring_box(np.random.default_rng(3))
    no_plateau = replace(DimensionConfig(), wall_plateau_slices=None)
    m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=no_plateau)
    off = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=replace(no_plateau, curved_flank_min_drop=None))
    assert m["rules"]["width"] != "curved_flank_vertex", m["rules"]
    assert m["width_m"] == off["width_m"] and m["uncertainty_m"] == off["uncertainty_m"], (m["width_m"], off["width_m"])


def test_a_flaring_rim_is_read_past_by_the_walls_plateau():
    """The same box: the projection over all heights reads the rim's flare as a wider part (+6 %). Its points
    outside the walls lie near the top, a fringe (``shoulder_fringe_height``), so the peaks read the walls
    (+0.1 %, the flare's width the other reading the uncertainty spans); without that test the walls' widest
    stretch of heights (the plateau) is the walls' own width (measured: +0.03 %)."""
    W = 0.38
    xyz = _flaring_box(np.random.default_rng(3), W=W)
    m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003)
    assert m["rules"]["width"] == "kde_two_peaks" and m["width_shoulder_m"] > 1.04 * W, (m["rules"], m["width_shoulder_m"])
    no_fringe = replace(DimensionConfig(), shoulder_fringe_height=None)
    plateau = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=no_fringe)
    assert plateau["rules"]["width"] == "wall_plateau", plateau["rules"]
    for r in (m, plateau):
        assert abs(r["width_m"] / W - 1) < 0.01 and abs(r["width_m"] - W) <= 2 * r["uncertainty_m"]["width"], r["width_m"]
    off = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=replace(no_fringe, wall_plateau_slices=None))
    assert off["width_m"] > 1.04 * W, off["width_m"]


def test_a_rounded_top_keeps_its_flank_off_the_walls_plateau():
    """A tank: its plateau over 65 % of the height lies inside its widest line (over 45 %: 2.9 % here; 3-8 % on
    tuning tankers). Under a rounded top (``rounded_top_drop``) the plateau is not read, even where the vertex
    rule is off."""
    W = 0.26
    xyz = _elliptic_tanker(np.random.default_rng(1), W=W)
    m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=replace(DimensionConfig(), curved_flank_min_drop=None))
    assert m["rounded_top_drop"] >= DimensionConfig().wall_plateau_max_top_drop, m["rounded_top_drop"]
    assert m["rules"]["width"] != "wall_plateau", m["rules"]
    # What the gate keeps out: the flank's plateau, inside the widest line.
    w0, w1 = m["edges_m"]["width"]
    b, z = xyz[:, 1], xyz[:, 2]
    side = np.abs(point_normals(xyz, 16)[:, 1]) >= 0.7
    _, widths = width_profile(b, z, side, 0.5 * (w0 + w1), m["bandwidths_m"]["width"], float(np.quantile(z, 0.995)))
    cfg = DimensionConfig()
    plateau, _ = wall_plateau(widths, cfg.wall_plateau_slices, 3, np.inf, cfg.wall_plateau_low_slices)
    assert plateau < 0.98 * W, plateau


def test_the_profile_rule_on_profiles():
    """A concave profile gives its vertex; a flat noisy one, a step, a rim rising to the top and a single stray
    slice give none."""
    rng = np.random.default_rng(0)
    zs = (np.arange(20) + 0.5) / 20
    tank = np.sqrt(np.clip(1 - ((zs - 0.63) / 0.37) ** 2, 0, None))      # an ellipse's width profile, max 1 at 0.63
    v = curved_flank_width(zs, tank + rng.normal(0, 0.005, 20), window=4, min_drop=0.03, z_min=0.15)
    assert v is not None and abs(v - 1) < 0.01, v
    flat = 1 + rng.normal(0, 0.01, 20)
    assert curved_flank_width(zs, flat, 4, 0.03, 0.15) is None
    rim = np.where(zs > 0.85, 1 + 0.6 * (zs - 0.85), 1.0)
    assert curved_flank_width(zs, rim, 4, 0.03, 0.15) is None
    rim_to_roof = np.where(zs > 0.65, 1 + 0.6 * (zs - 0.65), 1.0)     # a rim flaring up to the roof's edge,
    rim_to_roof[-1] = 0.95                                               # whose last slice falls back
    assert curved_flank_width(zs, rim_to_roof, 4, 0.02, 0.15) is None
    step = np.where(zs < 0.3, 0.79, 1.0)                                 # wheels or a cab narrower than the body
    assert curved_flank_width(zs, step, 4, 0.02, 0.05) is None          # (a quadratic through it overshoots)
    spike = np.ones(20)
    spike[10] = 1.1
    assert curved_flank_width(zs, spike, 4, 0.03, 0.15) is None
    # Slices without both walls are skipped, not read.
    zs_w, widths = width_profile(np.array([-1.0, 1.0] * 40), np.full(80, 0.5), np.ones(80, bool), 0.0, 0.01, 1.0, n_slices=4)
    assert np.isnan(widths[[0, 1, 3]]).all() and abs(widths[2] - 2.0) < 0.01


def test_the_face_gates_look_for_the_walls_at_their_peaks():
    """A width read at a rounded flank's widest line moves the edges outwards of most of the flank's points:
    the side-wall gates look for the walls at the peaks' edges (``width_wall_edges_m``), as before."""
    from types import SimpleNamespace

    from measure.quality import face_checks

    rng = np.random.default_rng(2)
    L, W, H = 2.0, 0.2, 0.4
    walls = [_face(rng, 20_000, (-L / 2, L / 2), (s * W / 2, s * W / 2), (0.05 * H, H)) for s in (-1, 1)]
    ends = [_face(rng, 5_000, (e, e), (-W / 2, W / 2), (0.05 * H, H)) for e in (-L / 2, L / 2)]
    xyz = np.vstack([*walls, *ends, _face(rng, 20_000, (-L / 2, L / 2), (-W / 2, W / 2), (H, H))])
    details = {"origin_xy_m": np.zeros(2), "axes_xy": {"length": np.array([1.0, 0.0]), "width": np.array([0.0, 1.0])},
               "edges_m": {"length": (-L / 2, L / 2), "width": (-W / 2 - 0.015, W / 2 + 0.015)}, "roof_support": 0.3}

    def width_gate(det):
        m = SimpleNamespace(details=det, truck_xyz_ground=xyz, parameters={"resolved": {"resolution_m": 0.002}},
                            height_m=H, length_m=L, width_m=det["edges_m"]["width"][1] - det["edges_m"]["width"][0])
        return next(c for c in face_checks(m) if c["name"] == "faces_width")["status"]

    assert width_gate(details) == "fail"          # 15 mm outside the walls, beyond the 9 mm band
    assert width_gate({**details, "width_wall_edges_m": (-W / 2, W / 2)}) == "pass"


def test_a_rounded_tops_crest_seen_along_the_length_bounds_the_height():
    """A tank's crest has no roof level to hold 2 % of the points (two full-scale tankers of the tuning seeds
    were refused for an unseen roof though read within 0.8 %): the crest, seen along the length, bounds the
    height (a warning). A crest missing over most of the length still fails the gate."""
    from types import SimpleNamespace

    from measure.quality import face_checks

    rng = np.random.default_rng(3)
    L, W, H = 1.6, 0.26, 0.40
    xyz = _elliptic_tanker(rng, L=L, W=W, H=H)
    d = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003)
    assert d["rules"]["height"] == "rounded_top_99.5" and abs(d["height_m"] / H - 1) < 0.01, (d["rules"], d["height_m"])

    def height_gate(pts):
        m = SimpleNamespace(details={**d, "roof_support": 0.01}, rules=d["rules"], truck_xyz_ground=pts,
                            parameters={"resolved": {"resolution_m": 0.004}},
                            height_m=d["height_m"], length_m=d["length_m"], width_m=d["width_m"])
        return next(c for c in face_checks(m) if c["name"] == "faces_height")

    seen = height_gate(xyz)
    assert seen["status"] == "warn" and "crest seen along" in seen["detail"], seen
    a = (xyz[:, :2] - d["origin_xy_m"]) @ d["axes_xy"]["length"]
    l0, l1 = d["edges_m"]["length"]
    unseen = (xyz[:, 2] > 0.9 * H) & (a > l0 + 0.3 * (l1 - l0))   # the crest gone over 70 % of the length
    assert height_gate(xyz[~unseen])["status"] == "fail"


def _measured_tanker(seed: int, L: float = 1.6, W: float = 0.26, H: float = 0.40):
    """An elliptic tanker's points (``_elliptic_tanker``), their measurement read as rounded, and the
    points' positions along the length and across the width (m) in its axes."""
    xyz = _elliptic_tanker(np.random.default_rng(seed), L=L, W=W, H=H)
    d = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003)
    assert d["rules"]["height"] == "rounded_top_99.5", d["rules"]
    a = (xyz[:, :2] - d["origin_xy_m"]) @ d["axes_xy"]["length"]
    b = (xyz[:, :2] - d["origin_xy_m"]) @ d["axes_xy"]["width"]
    return xyz, d, a, b


def _face_gate(name: str, d: dict, points: np.ndarray, rules: dict, cfg=None, details: dict | None = None) -> dict:
    """The ``faces_<name>`` check of ``measure.quality.face_checks`` on a measurement d whose truck points
    are ``points`` (ground frame, m), read with ``rules`` (and ``details`` in place of d's)."""
    from types import SimpleNamespace

    from measure.quality import TruckQualityConfig, face_checks

    m = SimpleNamespace(details=d if details is None else details, rules=rules, truck_xyz_ground=points,
                        parameters={"resolved": {"resolution_m": 0.004}},
                        height_m=d["height_m"], length_m=d["length_m"], width_m=d["width_m"])
    return next(c for c in face_checks(m, cfg or TruckQualityConfig()) if c["name"] == f"faces_{name}")


FLAT_SIDED = {"width": "kde_two_peaks", "height": "roof_peak"}


def test_a_rounded_bodys_outline_reaching_an_unseen_end_bounds_the_length():
    """A tank's end cap, plain and seen edge-on, is often not reconstructed (two full-scale tankers of the
    tuning seeds were refused for it though read within 0.02 and 1.7 %), and a tank has no side walls or
    roof edge to fill the end's rims: its shell, reaching the end on most of its outline, bounds the length
    (a warning). Not for a body read as flat-sided, and not where the length runs past the shell's end."""
    from measure.quality import TruckQualityConfig

    L, W, H = 1.6, 0.26, 0.40
    xyz, d, a, b = _measured_tanker(4, L, W, H)
    l0, l1 = d["edges_m"]["length"]
    # As the drone sees it: no underside of the tank, and its crest not at the top's level by the rear end.
    z_floor = 0.27 * H
    keep = ~(((xyz[:, 2] < z_floor + 0.3 * (H - z_floor)) & (np.abs(b) < 0.45 * W))
             | ((a < l0 + 0.06 * L) & (xyz[:, 2] > H - 0.05)))

    def length_gate(rules, edges=(l0, l1), cfg=None):
        details = {**d, "edges_m": {**d["edges_m"], "length": edges}}
        return _face_gate("length", d, xyz[keep], rules, cfg, details)

    seen = length_gate(d["rules"])
    assert seen["status"] == "warn" and "rounded body's outline" in seen["detail"], seen
    assert length_gate(d["rules"], cfg=replace(TruckQualityConfig(), rounded_outline=False))["status"] == "fail"
    assert length_gate({**FLAT_SIDED, "length": d["rules"]["length"]})["status"] == "fail"
    assert length_gate(d["rules"], edges=(l0 - 0.15 * L, l1))["status"] == "fail"   # a length past the shell's end


def test_a_rounded_bodys_flank_seen_along_the_length_bounds_the_width():
    """A tank's flank meets the side plane along one line, so a plain flank matched only near that line
    leaves most of the side face's cells up the height empty (a full-scale tanker of the tuning seeds was
    refused for its sides though its width read +1.8 %): the line, seen along the length, bounds the width
    (a warning). Not for a body read as flat-sided, not when the line is seen along a quarter of the
    length only, and not with the rule turned off."""
    from measure.quality import TruckQualityConfig

    L, W, H = 1.6, 0.26, 0.40
    xyz, d, a, b = _measured_tanker(5, L, W, H)
    l0, l1 = d["edges_m"]["length"]
    zc = 0.5 * (0.27 * H + H)
    # As a plain flank is reconstructed: on both sides only patches of a band about the widest line are
    # matched, one every tenth of the length.
    patch = ((a - l0) / (0.1 * L)) % 1.0 < 0.4
    flank = (np.abs(b) > 0.3 * W) & ((np.abs(xyz[:, 2] - zc) > 0.04 * H) | ~patch)

    assert _face_gate("width", d, xyz, d["rules"])["status"] == "pass"
    seen = _face_gate("width", d, xyz[~flank], d["rules"])
    assert seen["status"] == "warn" and "rounded body's flank seen along" in seen["detail"], seen
    off = replace(TruckQualityConfig(), rounded_side_line=False)
    assert _face_gate("width", d, xyz[~flank], d["rules"], off)["status"] == "fail"
    # Its own flag: the roof-and-end rule turned off leaves it on.
    no_rims = replace(TruckQualityConfig(), side_rims=False)
    assert _face_gate("width", d, xyz[~flank], d["rules"], no_rims)["status"] == "warn"
    assert _face_gate("width", d, xyz[~flank], {**FLAT_SIDED, "length": d["rules"]["length"]})["status"] == "fail"
    # The line seen along the rear quarter only: not bounded.
    short = ~flank & ~((np.abs(b) > 0.3 * W) & (a > l0 + 0.3 * (l1 - l0)))
    assert _face_gate("width", d, xyz[short], d["rules"])["status"] == "fail"
