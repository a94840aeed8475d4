"""Width rules of ``measure.dimensions`` on fused-cloud-like truck points (ground frame, exact truth)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from measure.dimensions import DimensionConfig, measure_dimensions


def _face(rng, n, x, y, z):
    """n points uniform in the box x, y, z ranges (a degenerate range makes a face)."""
    return np.column_stack([rng.uniform(*x, n), rng.uniform(*y, n), rng.uniform(*z, n)])


def _truck(rng, L=2.1, W=0.38, H=0.38, wall_sigma=0.0, load=None, n=40_000, cab_w=None):
    """Side walls (optionally scattered across their plane), roof, rear/front faces of a box truck.

    load: (load_width, deck_height) makes a flatbed: a full-width deck and a narrower, taller load.
    """
    pts = []
    if load is None:
        for s in (-1, 1):
            wall = _face(rng, n, (-L / 2, L / 2), (s * W / 2, s * W / 2), (0.1 * H, H))
            wall[:, 1] += rng.normal(0.0, wall_sigma, n) if wall_sigma else 0.0
            pts.append(wall)
        pts.append(_face(rng, n, (-L / 2, L / 2), (-W / 2, W / 2), (H, H)))
    else:
        lw, zd = load
        cab_w = W if cab_w is None else cab_w
        pts.append(_face(rng, n, (-L / 2, 0.3 * L), (-W / 2, W / 2), (zd, zd)))            # deck top
        for s in (-1, 1):
            pts.append(_face(rng, n // 10, (-L / 2, 0.3 * L), (s * W / 2, s * W / 2), (0.6 * zd, zd)))  # deck edges
            pts.append(_face(rng, n, (-L / 2, 0.3 * L), (s * lw / 2, s * lw / 2), (zd, 0.9 * H)))   # load sides
            pts.append(_face(rng, n // 2, (0.35 * L, L / 2), (s * cab_w / 2, s * cab_w / 2), (0.1 * H, H)))  # cab sides
        pts.append(_face(rng, n, (-L / 2, 0.3 * L), (-lw / 2, lw / 2), (0.9 * H, 0.9 * H)))   # load top
        pts.append(_face(rng, n // 2, (0.35 * L, L / 2), (-cab_w / 2, cab_w / 2), (H, H)))    # cab roof
    for x in (-L / 2, L / 2):
        pts.append(_face(rng, n // 4, (x, x), (-W / 2, W / 2), (0.1 * H, H)))
    return np.vstack(pts)


def test_scattered_walls_with_a_stray_tail_keep_the_two_peak_width():
    """A fused cloud's weakly textured walls scatter far more (here 8 mm) than the ground noise (2 mm)
    and carry a thin tail of stray points: neither may be read as a wider part."""
    rng = np.random.default_rng(0)
    xyz = _truck(rng, wall_sigma=0.008)
    stray = _face(rng, 1500, (-1.0, 1.0), (0.19, 0.23), (0.05, 0.38))  # 1 % of the points, up to 4 cm outside
    m = measure_dimensions(np.vstack([xyz, stray]), resolution_m=0.004, noise_m=0.002)
    assert m["rules"]["width"] == "kde_two_peaks", m["rules"]
    assert abs(m["width_m"] - 0.38) < 0.004, m["width_m"]


def test_flatbed_width_is_the_deck_not_the_narrower_load():
    """A load 20 % and a cab 10 % narrower than the deck: the load's walls are the strongest peaks, the
    cab's the outermost ones, but the truck's width is the deck's (a shoulder outside those peaks)."""
    rng = np.random.default_rng(1)
    xyz = _truck(rng, L=2.1, W=0.38, H=0.38, load=(0.8 * 0.38, 0.12), cab_w=0.9 * 0.38)
    xyz[:, 1] += rng.normal(0.0, 0.002, len(xyz))
    m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.002)
    assert m["rules"]["width"] == "kde_peaks_plus_outer_shoulder", (m["rules"], m["width_m"])
    assert abs(m["width_m"] - 0.38) < 0.38 * 0.01, m["width_m"]


def _faint_flatbed(rng, L=1.5, W=0.30, H=0.45, n=40_000, sigma=0.005, cab_points=None, deck_points=None):
    """A model flatbed as the operating-envelope draws show it: a load 10 % and a cab 3 % narrower than the
    deck, whose thin edges and narrow strip beside the load hold only ~2 % of the points, all scattered by
    a depth noise (5 mm) close to the 15 mm the deck sticks out by. cab_points, deck_points: per cab side and
    deck edge (None: n / 6, n / 50)."""
    lw, cw, zd = 0.9 * W, 0.97 * W, 0.09 * H
    pts = [_face(rng, n // 6, (-L / 2, 0.3 * L), (-W / 2, W / 2), (zd, zd))]                       # deck top
    for s in (-1, 1):
        pts.append(_face(rng, deck_points or n // 50, (-L / 2, 0.3 * L), (s * W / 2, s * W / 2), (0.6 * zd, zd)))  # deck edges
        pts.append(_face(rng, n, (-L / 2, 0.3 * L), (s * lw / 2, s * lw / 2), (zd, 0.9 * H)))        # load sides
        pts.append(_face(rng, cab_points or n // 6, (0.35 * L, L / 2), (s * cw / 2, s * cw / 2), (0.1 * H, 0.8 * H)))  # cab sides
    pts.append(_face(rng, n, (-L / 2, 0.3 * L), (-lw / 2, lw / 2), (0.9 * H, 0.9 * H)))
    pts.append(_face(rng, n // 4, (0.35 * L, L / 2), (-cw / 2, cw / 2), (0.8 * H, 0.8 * H)))
    for x in (-L / 2, L / 2):
        pts.append(_face(rng, n // 4, (x, x), (-lw / 2, lw / 2), (0.1 * H, 0.9 * H)))
    p = np.vstack(pts)
    return p + rng.normal(0.0, sigma, p.shape)


def test_faint_flatbed_deck_is_found_beside_a_narrower_load():
    """The load's walls alone give the width 10 % low with a 1 % uncertainty: a confident wrong number.
    The shoulder rule (excess 1.5 x the wall's own tail, >= 1 % of the points) finds the deck. The walls'
    plateau (which reads the load) stands aside: the points outside it lie low on the truck."""
    W = 0.30
    for seed in range(3):
        xyz = _faint_flatbed(np.random.default_rng(seed), W=W)
        m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.005)
        assert m["rules"]["width"] == "kde_peaks_plus_outer_shoulder", (m["rules"], m["width_m"])
        low = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.005, config=replace(DimensionConfig(), wall_plateau_min_outside_height=0.0))
        assert low["rules"]["width"] == "wall_plateau" and low["width_m"] < 0.92 * W, (low["rules"], low["width_m"])
        # Measured: +1.3 to +1.5 %, sigma 3.5 %.
        assert abs(m["width_m"] / W - 1) < 0.02 and abs(m["width_m"] - W) < 2 * m["uncertainty_m"]["width"], m["width_m"]
        # The former thresholds (2 x, 2 %) missed it: the load's width, 10 % low, many sigma off.
        old = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.005,
                                 config=replace(DimensionConfig(), shoulder_excess=2.0, shoulder_min_mass=0.02, wall_plateau_slices=None))
        assert old["rules"]["width"] == "kde_two_peaks" and old["width_m"] < 0.92 * W
        assert W - old["width_m"] > 5 * old["uncertainty_m"]["width"]


def test_a_deck_hidden_in_the_loads_wall_scatter_is_a_reading_the_uncertainty_spans():
    """The faint flatbed with a depth noise (8 mm) half the 15 mm its deck sticks out by: the points outside
    the load's walls are more than the walls' scatter puts there (excess 1-1.5), too few to pass for a
    shoulder. The width stays the load's (9-10 % low), but the width with the shoulders' edges is the other
    reading (``width_shoulder_m``, within 3 % of the deck), and the uncertainty spans it: without it the
    truth lay 9-10 sigma off (as draw 37 of seed 2060, a full-scale flatbed read -9.9 % at 3 sigma: a
    confident `within` for a truck over the width limit)."""
    W = 0.30
    for seed in range(2):
        xyz = _faint_flatbed(np.random.default_rng(seed), W=W, sigma=0.008)
        m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.005)
        assert m["rules"]["width"] == "kde_two_peaks" and m["width_m"] < 0.92 * W, (m["rules"], m["width_m"])
        assert m["width_shoulder_m"] is not None and abs(m["width_shoulder_m"] / W - 1) < 0.03, m["width_shoulder_m"]
        assert abs(m["width_m"] - W) <= 2 * m["uncertainty_m"]["width"], m["uncertainty_m"]   # measured: 1.6 sigma
        assert any("more points lie outside them" in w for w in m["warnings"]), m["warnings"]
        off = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.005, config=replace(DimensionConfig(), shoulder_doubt_excess=None))
        assert off["width_shoulder_m"] is None and W - off["width_m"] > 5 * off["uncertainty_m"]["width"]


def test_a_deck_within_the_grounds_noise_but_beyond_the_walls_own_scatter_is_found():
    """A full-scale flatbed whose fused load walls are sharp (20 mm) while the ground where it stands is
    noisy (87 mm: seed 2063's draw 13, a 17.9 m flatbed read W -9.8 % at 4.9 sigma, a wrong `within`): its deck
    and cab stick out 0.13 and 0.09 m, inside the noise's reach of the walls (2.5 x 87 mm) but far outside
    their own. Looked for beyond the walls' own scatter (``shoulder_reach_own_flank``), the deck is found.
    Measured: -1.0 %, sigma 8 % (the load's walls the other reading); the noise's reach: -10.0 % at 23 sigma."""
    W = 2.6
    for seed in range(2):
        xyz = _faint_flatbed(np.random.default_rng(seed), L=15.0, W=W, H=3.5, sigma=0.02, cab_points=1500, deck_points=4000)
        m = measure_dimensions(xyz, resolution_m=0.016, noise_m=0.087)
        assert m["rules"]["width"] == "kde_peaks_plus_outer_shoulder", (m["rules"], m["width_m"])
        assert abs(m["width_m"] / W - 1) < 0.02 and abs(m["width_m"] - W) < 2 * m["uncertainty_m"]["width"], m["width_m"]
        off = measure_dimensions(xyz, resolution_m=0.016, noise_m=0.087, config=replace(DimensionConfig(), shoulder_reach_own_flank=False))
        assert off["rules"]["width"] == "kde_two_peaks" and off["width_m"] < 0.92 * W, (off["rules"], off["width_m"])
        assert W - off["width_m"] > 5 * off["uncertainty_m"]["width"], off["uncertainty_m"]


def test_a_shoulder_on_one_side_takes_the_doubtful_one_on_the_other():
    """``_width_rule`` on a deck 10 % wider than its load: its right edge band holds 4 % of the points (a
    shoulder), its left one 2 % (more than the wall's scatter puts there, too few to pass alone). A truck is
    symmetric about its length axis: with the right shoulder found, the left one is taken too (width within
    3 % of the deck's); alone it is only the other reading. A left band of 0.6 % stays the wall's scatter."""
    from measure.dimensions import _width_rule
    from measure.kde import linear_binning

    Wl, W, n, s = 0.27, 0.30, 40_000, 0.004
    step, lo = 0.0002, -0.3
    nb = int(0.6 / step)
    grid = lo + step * np.arange(nb)
    for left_share, taken in ((0.02, True), (0.006, False)):
        rng = np.random.default_rng(0)
        walls = np.concatenate([k * Wl / 2 + rng.normal(0.0, s, n) for k in (-1, 1)])
        roof = rng.uniform(-Wl / 2, Wl / 2, n)
        n_r, n_l = int(0.04 * 3 * n), int(left_share * 3 * n)
        right = rng.uniform(Wl / 2, W / 2, n_r) + rng.normal(0.0, s, n_r)
        left = -rng.uniform(Wl / 2, W / 2, n_l) + rng.normal(0.0, s, n_l)
        counts = linear_binning(np.concatenate([walls, roof, right, left]), lo, step, nb)
        alone = _width_rule(counts, grid, 0.002, step, replace(DimensionConfig(), shoulder_pair=False), noise=0.003)
        pair = _width_rule(counts, grid, 0.002, step, DimensionConfig(), noise=0.003)
        assert alone[1] == pair[1] == "kde_peaks_plus_outer_shoulder"
        assert abs(alone[2][1] - W / 2) < 0.005 and abs(alone[2][0] + Wl / 2) < 0.002, alone[2]   # the right shoulder only
        if taken:
            assert alone[5] is not None and abs(alone[5] / W - 1) < 0.03, alone[5]               # the left one: a reading
            assert abs(pair[0] / W - 1) < 0.03 and pair[5] is None, (pair[0], pair[5])          # measured: -2.5 %
        else:
            assert alone[5] is None and pair[0] == alone[0], (alone, pair)


def test_a_fringe_under_the_roof_beside_a_wall_is_no_shoulder():
    """A box whose far roof edge SGBM fattened over the ground beyond: a band 40 mm outside its right wall
    just under the roof (0.8-0.95 of the top), 5 % of the points. As a shoulder it would widen the truck by
    its band (and take a doubtful other side with it, the pair rule); lying mostly near the top it is a
    fringe: the width stays the walls', and the width with the band is the other reading the uncertainty
    spans. The same band low on the truck (a deck) still widens the truck, out to the band's edge. (The peaks'
    rule alone: the walls' height-profile plateau, which would read this box, is off.)"""
    W, H = 0.38, 0.38
    peaks = replace(DimensionConfig(), wall_plateau_slices=None)
    rng = np.random.default_rng(7)
    box = _truck(rng, W=W, H=H)
    # The deck's band at a deck's height (0.2-0.35 of the top): lower down it would be the ground's skirt.
    for z, fringe in (((0.8 * H, 0.95 * H), True), ((0.2 * H, 0.35 * H), False)):
        band = _face(rng, int(0.05 * len(box)), (-1.0, 1.0), (W / 2 + 0.008, W / 2 + 0.04), z)
        xyz = np.vstack([box, band]) + rng.normal(0.0, 0.003, (len(box) + len(band), 3))
        m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=peaks)
        off = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=replace(peaks, shoulder_fringe_height=None))
        # Low on the truck the band is a deck: a shoulder, or read in its own height slice (``ledge_blurs``).
        wider = ("kde_peaks_plus_outer_shoulder",) if fringe else ("kde_peaks_plus_outer_shoulder", "low_ledge")
        assert off["rules"]["width"] in wider and off["width_m"] > W + 0.025, (off["rules"], off["width_m"])
        if fringe:
            # Measured: W -0.03 % (sigma 3.6 %), the other reading +7.0 %; without the test +7.0 % at 1.8 sigma.
            assert m["rules"]["width"] == "kde_two_peaks" and abs(m["width_m"] / W - 1) < 0.02, (m["rules"], m["width_m"])
            assert m["width_shoulder_m"] is not None and m["width_shoulder_m"] > W + 0.025, m["width_shoulder_m"]
            assert abs(m["width_m"] - W) < m["uncertainty_m"]["width"], m["uncertainty_m"]
            assert off["width_m"] / W - 1 > 0.06, off["width_m"]
        else:
            assert m["rules"]["width"] in wider and m["width_m"] == off["width_m"], (m["rules"], m["width_m"])
            assert abs(m["width_m"] - (W + 0.04)) < 0.01, m["width_m"]   # out to the band's outer edge


def test_stray_points_outside_a_broad_wall_do_not_veto_the_walls():
    """A weakly seen side wall, broad (25 mm scatter) and 1.5 % of the points strayed up to 0.4 m outside it:
    the two walls must still count as walls (the 1 % quantile extent used to veto them, and the width
    then ran to the strays' extreme)."""
    rng = np.random.default_rng(4)
    W = 0.38
    xyz = _truck(rng, W=W)
    left = xyz[:, 1] < -0.9 * W / 2
    xyz[left, 1] += rng.normal(0.0, 0.025, left.sum())           # the broad wall
    stray = _face(rng, int(0.015 * len(xyz)), (-1.0, 1.0), (-W / 2 - 0.4, -W / 2 - 0.05), (0.05, 0.38))
    m = measure_dimensions(np.vstack([xyz, stray]), resolution_m=0.004, noise_m=0.004)
    # Measured: +0.7 % (sigma 0.8 %) with 2.5 % quantiles; with 1 % ones, one wall + the strays' extreme: +99 % at a 2.3 % sigma.
    assert m["rules"]["width"] != "one_peak_plus_extreme", (m["rules"], m["width_m"])
    assert abs(m["width_m"] / W - 1) < 0.03 and m["uncertainty_m"]["width"] < 0.05 * W, (m["width_m"], m["uncertainty_m"])
    old = measure_dimensions(np.vstack([xyz, stray]), resolution_m=0.004, noise_m=0.004,
                             config=replace(DimensionConfig(), core_fraction=0.01, wall_plateau_slices=None))
    assert old["rules"]["width"] == "one_peak_plus_extreme" and old["width_m"] > 1.5 * W


def test_a_skirt_of_ground_remnants_at_the_trucks_foot_does_not_replace_a_wall():
    """A full-scale box whose foot carries a skirt of ground remnants on one side (the ground's noise tail and
    the shadowed ground beside the wheels, 0-12 % of the height, reaching 1.5 m out, 6 % of the points): the
    skirt moved the 2.5 % extent out, the walls no longer spanned it and the width ran to the skirt's edge.
    Judged above the skirt (``width_min_height``), the two walls stand. The walls' plateau is off, as it is
    under a tank's crest or beside a flatbed's deck, where it does not apply. Measured: -0.04 % (sigma 0.5 %);
    without: one wall and the skirt's extreme, +59 %."""
    rng = np.random.default_rng(7)
    W = 2.5
    xyz = _truck(rng, L=10.0, W=W, H=3.5, wall_sigma=0.02)
    n = int(0.06 * len(xyz))
    skirt = np.column_stack([rng.uniform(-5.0, 5.0, n), W / 2 + rng.uniform(0.0, 1.5, n), rng.uniform(0.0, 0.42, n)])
    cfg = replace(DimensionConfig(), wall_plateau_slices=None)
    m = measure_dimensions(np.vstack([xyz, skirt]), resolution_m=0.016, noise_m=0.02, config=cfg)
    assert m["rules"]["width"] != "one_peak_plus_extreme", (m["rules"], m["width_m"])
    assert abs(m["width_m"] / W - 1) < 0.01 and abs(m["width_m"] - W) <= 2 * m["uncertainty_m"]["width"], m["width_m"]
    old = measure_dimensions(np.vstack([xyz, skirt]), resolution_m=0.016, noise_m=0.02,
                             config=replace(cfg, width_min_height=None))
    assert old["rules"]["width"] == "one_peak_plus_extreme" and old["width_m"] > 1.2 * W, (old["rules"], old["width_m"])


def test_a_shoulder_reading_carries_the_walls_reading_in_its_uncertainty():
    """Full-scale box walls with a fringe of stray points that thins outwards, heavier than a Gaussian
    tail (the flying pixels under a body's bottom edge): the shoulder rule reads it as a wider part.
    The walls' own peak-to-peak distance is the other reading, and the uncertainty must span it.
    Measured: 2.628 m (+5.1 %); sigma 0.042 m before (truth 3.1 sigma off), 0.076 m now (1.7 sigma).
    The walls' plateau stands aside: the fringe lies low on the truck, where a flatbed's deck would."""
    rng = np.random.default_rng(5)
    W = 2.5
    xyz = _truck(rng, L=10.0, W=W, H=3.5, wall_sigma=0.02)
    n = int(0.04 * len(xyz))
    side = rng.choice([-1.0, 1.0], n)
    fringe = np.column_stack([rng.uniform(-5.0, 5.0, n), side * (W / 2 + rng.exponential(0.12, n)), rng.uniform(0.1, 1.0, n)])
    m = measure_dimensions(np.vstack([xyz, fringe]), resolution_m=0.016, noise_m=0.02)
    assert m["rules"]["width"] == "kde_peaks_plus_outer_shoulder", m["rules"]
    walls = m["width_walls_m"]
    assert abs(walls - W) < 0.01 * W, walls
    assert m["width_m"] > W * 1.03                     # the fringe read as a wider part: the number is off ...
    assert abs(m["width_m"] - W) <= 2 * m["uncertainty_m"]["width"], m["uncertainty_m"]   # ... but not confidently
    assert m["uncertainty_m"]["width"] >= abs(m["width_m"] - walls) / 2
    assert any("walls alone" in w for w in m["warnings"])


def test_two_clean_walls_report_no_second_reading():
    rng = np.random.default_rng(6)
    m = measure_dimensions(_truck(rng, wall_sigma=0.002), resolution_m=0.004, noise_m=0.002)
    assert m["rules"]["width"] == "kde_two_peaks" and m["width_walls_m"] is None
    assert m["uncertainty_m"]["width"] < 0.01 * 0.38


def test_a_sparse_roof_above_the_densest_level_gives_the_height_and_the_uncertainty_spans_both():
    """A roof seen by only 0.8 % of the points (under the 1 % a roof level needs) above a dense cab roof at
    85 % of the height: the densest level is the cab's, 15 % low (the paper's rule, the default, reads
    that, and its uncertainty spans the top). With ``top_above_roof_sigmas`` the points above it that the
    noise does not explain are read as the truck's top: the height is read there, the roof level is kept
    as the second reading and the uncertainty spans both; a clean flat roof keeps the roof level and a
    tight uncertainty either way."""
    top_rule = replace(DimensionConfig(), top_above_roof_sigmas=3.0)
    rng = np.random.default_rng(7)
    L, W, H = 2.0, 0.4, 0.4
    walls = np.vstack([_face(rng, 30_000, (-L / 2, L / 2), (s * W / 2, s * W / 2), (0.1 * H, 0.85 * H)) for s in (-1, 1)])
    cab_roof = _face(rng, 20_000, (-L / 2, L / 2), (-W / 2, W / 2), (0.85 * H, 0.85 * H))
    roof = _face(rng, 700, (-L / 2, L / 2), (-W / 2, W / 2), (H, H))
    xyz = np.vstack([walls, cab_roof, roof])
    xyz[:, 2] += rng.normal(0.0, 0.002, len(xyz))
    m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.002, config=top_rule)
    assert m["rules"]["height"] == "top_quantile_99.5", m["rules"]
    assert abs(m["height_m"] - H) < 0.01, m["height_m"]                    # the default: 0.34 m, 15 % low
    assert abs(m["height_roof_m"] - 0.85 * H) < 0.005, m["height_roof_m"]  # the densest level, as built
    # +-2 sigma reaches the other reading.
    assert m["height_m"] - 2 * m["uncertainty_m"]["height"] <= m["height_roof_m"], m["uncertainty_m"]
    assert any("above the densest roof level" in w for w in m["warnings"])
    paper = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.002)
    assert paper["rules"]["height"] == "roof_peak" and abs(paper["height_m"] - 0.85 * H) < 0.005, paper["height_m"]
    assert paper["height_m"] + 2 * paper["uncertainty_m"]["height"] >= paper["height_top_m"], paper["uncertainty_m"]
    for cfg in (DimensionConfig(), top_rule):
        clean = measure_dimensions(_truck(np.random.default_rng(8), wall_sigma=0.002), resolution_m=0.004, noise_m=0.002, config=cfg)
        assert clean["rules"]["height"] == "roof_peak", clean["rules"]
        assert clean["uncertainty_m"]["height"] < 0.0025, clean["uncertainty_m"]   # half the spacing, as before
        assert not any("points reach" in w or "roof level at" in w for w in clean["warnings"])


def _tank(rng, L=2.0, R=0.2, z_axis=0.25, n=60_000, crest_share=0.04):
    """A tanker's body: a horizontal cylinder of radius R (m) whose axis lies z_axis above the ground
    (crest at z_axis + R), seen from low flights: its sides dense, the crest (within 54 deg of the top)
    holding only crest_share of the body's points; chassis skirts, end caps and a flat cab roof at 68 %."""
    k = int(crest_share * n)
    phi = np.concatenate([rng.uniform(-0.3 * np.pi, 0.3 * np.pi, k),
                          rng.choice([-1, 1], n - k) * rng.uniform(0.3 * np.pi, 0.55 * np.pi, n - k)])  # 0 = the crest
    x = rng.uniform(-L / 2, 0.3 * L, n)
    body = np.column_stack([x, R * np.sin(phi), z_axis + R * np.cos(phi)])
    H = z_axis + R
    skirts = np.vstack([_face(rng, n // 6, (-L / 2, L / 2), (s * R, s * R), (0.1 * H, z_axis)) for s in (-1, 1)])
    cab = np.vstack([_face(rng, n // 4, (0.35 * L, L / 2), (-R, R), (0.68 * H, 0.68 * H)),
                     *[_face(rng, n // 8, (0.35 * L, L / 2), (s * R, s * R), (0.1 * H, 0.68 * H)) for s in (-1, 1)]])
    caps = np.vstack([_face(rng, n // 20, (e, e), (-R, R), (0.1 * H, z_axis)) for e in (-L / 2, 0.3 * L)])
    return np.vstack([body, skirts, cab, caps])


def test_a_sparsely_seen_tank_crest_is_read_at_its_top_not_at_a_lower_density_level():
    """A tank's crest seen only from the side holds few points (here 1 % of the truck's points in its top
    5 %; seed 2032's full-scale tanker had 0.2 %) and has no roof level of its own: the paper's densest-level
    rule reads the tank's flank instead (20 % low here; that tanker 14 % low), with an uncertainty that
    reaches the crest. The top surface falls from the middle of the width towards the flanks (a rounded top,
    ``rounded_top_min_drop``, the default), so the top 0.5 % of the points give the height, within 2 % of the
    crest and inside the reported +-2 sigma; so does ``top_above_roof_sigmas``."""
    rng = np.random.default_rng(11)
    R, za = 0.2, 0.25
    xyz = _tank(rng, R=R, z_axis=za)
    xyz += rng.normal(0.0, 0.003, xyz.shape)
    H = za + R
    paper = measure_dimensions(xyz, resolution_m=0.005, noise_m=0.003, config=replace(DimensionConfig(), rounded_top_min_drop=None))
    assert paper["height_m"] < 0.9 * H, paper["height_m"]  # the failure, as built
    assert abs(paper["height_m"] - H) <= 2 * paper["uncertainty_m"]["height"] + 0.005, paper["uncertainty_m"]
    m = measure_dimensions(xyz, resolution_m=0.005, noise_m=0.003)
    assert m["rules"]["height"] == "rounded_top_99.5", m["rules"]
    assert m["rounded_top_drop"] > 0.1, m["rounded_top_drop"]   # a circle of radius 0.44 H: 0.4 R / H = 0.18
    # Its crest is no roof: the report does not warn that a roof level may read low.
    assert not any("roof barely seen" in w for w in m["warnings"]), m["warnings"]
    for cfg in (DimensionConfig(), replace(DimensionConfig(), rounded_top_min_drop=None, top_above_roof_sigmas=3.0)):
        m = measure_dimensions(xyz, resolution_m=0.005, noise_m=0.003, config=cfg)
        assert abs(m["height_m"] - H) < 0.02 * H, (m["height_m"], H)
        assert abs(m["height_m"] - H) <= 2 * m["uncertainty_m"]["height"], m["uncertainty_m"]
        assert abs(m["height_roof_m"] - m["height_m"]) <= 2 * m["uncertainty_m"]["height"], m["uncertainty_m"]


def test_a_roof_that_bulges_or_sits_over_a_lower_cab_keeps_its_level():
    """A flat roof reconstructed with a bulge (a 30 mm dome in its middle on a 0.40 m box, as the external
    renders' roofs came out) is not a rounded top: the top surface falls by 0.55 of the bulge towards the
    walls' edges, under ``rounded_top_min_drop``, and the height stays the paper's roof level; the same for a roof
    over a cab 15 % lower (the profile across the width is flat)."""
    rng = np.random.default_rng(13)
    L, W, H, bulge = 2.0, 0.38, 0.40, 0.03
    xyz = _truck(rng, L=L, W=W, H=H)
    on_roof = xyz[:, 2] >= H - 1e-9
    r2 = (xyz[on_roof, 1] / (W / 2)) ** 2 * 0.5 + (xyz[on_roof, 0] / (L / 2)) ** 2 * 0.5
    xyz[on_roof, 2] += bulge * np.clip(1.0 - r2, 0.0, None)
    xyz[:, 2] += rng.normal(0.0, 0.002, len(xyz))
    m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.002)
    assert m["rules"]["height"] == "roof_peak", (m["rules"], m["rounded_top_drop"])
    assert 0.0 < m["rounded_top_drop"] < 0.06, m["rounded_top_drop"]
    off = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.002, config=replace(DimensionConfig(), rounded_top_min_drop=None))
    assert m["height_m"] == off["height_m"] and H <= m["height_m"] <= H + bulge, (m["height_m"], off["height_m"])
    cab = _face(rng, 15_000, (0.7, L / 2), (-W / 2, W / 2), (0.85 * H, 0.85 * H))
    front = _truck(rng, L=L, W=W, H=H)
    front = front[front[:, 0] < 0.7]
    m = measure_dimensions(np.vstack([front, cab]), resolution_m=0.004, noise_m=0.002)
    assert m["rules"]["height"] == "roof_peak" and abs(m["rounded_top_drop"]) < 0.02, (m["rules"], m["rounded_top_drop"])
    assert abs(m["height_m"] - H) < 0.01 * H, m["height_m"]


def test_a_few_stray_points_above_a_flat_roof_do_not_move_the_height():
    """Strays above a flat roof (0.2 % of the points, up to 10 cm over it) stay under the top 0.5 %: also
    with ``top_above_roof_sigmas`` the roof level is the height, within the noise."""
    rng = np.random.default_rng(12)
    H = 0.38
    xyz = _truck(rng, H=H, wall_sigma=0.002)
    xyz[:, 2] += rng.normal(0.0, 0.002, len(xyz))
    n = int(0.002 * len(xyz))
    strays = np.column_stack([rng.uniform(-1.0, 1.0, n), rng.uniform(-0.19, 0.19, n), H + rng.uniform(0.0, 0.1, n)])
    m = measure_dimensions(np.vstack([xyz, strays]), resolution_m=0.004, noise_m=0.002,
                           config=replace(DimensionConfig(), top_above_roof_sigmas=3.0))
    assert m["rules"]["height"] == "roof_peak", m["rules"]
    assert abs(m["height_m"] - H) < 0.003, m["height_m"]



def test_walls_are_placed_by_their_sideways_facing_points_not_pulled_inwards():
    """``_width_rule`` on a projection where each wall (a 2 mm Gaussian at +-W/2) has as many points again
    spread on its inner side (a fused wall's inner scatter, a rounded roof edge: half-normal, 8 mm): the
    smoothed density of all points peaks inside the walls (the paper's reading), the sideways-facing points'
    own density on them (the default)."""
    from measure.dimensions import _width_rule
    from measure.kde import linear_binning

    rng = np.random.default_rng(0)
    W, n = 0.38, 40_000
    walls = np.concatenate([s * W / 2 + rng.normal(0.0, 0.002, n) for s in (-1, 1)])
    inner = np.concatenate([s * (W / 2 - np.abs(rng.normal(0.0, 0.008, n))) for s in (-1, 1)])
    roof = rng.uniform(-W / 2, W / 2, 2 * n)
    step, lo = 0.0002, -0.3
    nb = int(0.6 / step)
    grid = lo + step * np.arange(nb)
    side = linear_binning(walls, lo, step, nb)
    every = side + linear_binning(np.concatenate([inner, roof]), lo, step, nb)
    cfg = DimensionConfig()
    paper = _width_rule(every, grid, 0.003, step, cfg, noise=0.002)
    facing = _width_rule(every, grid, 0.003, step, cfg, noise=0.002, side_counts=side)
    assert paper[1] == facing[1] == "kde_two_peaks"
    assert paper[0] < W - 0.002, paper[0]                  # the inward pull exists
    assert abs(facing[0] - W) < 0.0005, facing[0]          # the walls' own points sit on the walls


def test_a_ripple_on_a_roofs_edge_smeared_past_a_wall_is_no_wall():
    """``_width_rule`` on walls at +-W/2 (2 mm Gaussians) under a roof whose edge is smeared 0.04 m past the left
    wall (a dark roof's edge: uniform points, all near the top, so a fringe and no shoulder): the smear's density
    is a fifth of the wall's peak, and its sampling ripples are local maxima that pass the height test. With
    ``peak_min_prominence_sigmas`` (opt-in) the wall is placed at the outermost peak that stands out of the
    density's noise; without it (the default) the outermost ripple is read as the wall."""
    from measure.dimensions import _width_rule
    from measure.kde import linear_binning

    W, n = 0.38, 20_000
    step, lo = 0.0002, -0.3
    nb = int(0.6 / step)
    grid = lo + step * np.arange(nb)
    for seed in range(4):
        rng = np.random.default_rng(seed)
        walls = np.concatenate([s * W / 2 + rng.normal(0.0, 0.002, n) for s in (-1, 1)])
        top = np.concatenate([rng.uniform(-W / 2, W / 2, 4 * n), rng.uniform(-W / 2 - 0.04, -W / 2, n)])
        side = linear_binning(walls, lo, step, nb)
        every = side + linear_binning(top, lo, step, nb)
        up = np.cumsum(linear_binning(top, lo, step, nb))
        off = _width_rule(every, grid, 0.002, step, DimensionConfig(), noise=0.002, side_counts=side, upper_cdf=up)
        on = _width_rule(every, grid, 0.002, step, replace(DimensionConfig(), peak_min_prominence_sigmas=5.0),
                         noise=0.002, side_counts=side, upper_cdf=up)
        assert off[0] > W + 0.02, (seed, off[0])          # a ripple in the smear taken for the wall
        assert on[1] == "kde_two_peaks" and abs(on[0] - W) < 0.001, (seed, on[:2])


def test_point_normals_of_a_box_face_along_its_axes():
    """k-neighbour plane normals on a box's faces (1 mm noise at 4 mm spacing) are within 30 deg of the face's
    axis for nearly all points (the facing selection's |cos| >= 0.7 is 45 deg)."""
    from measure.normals import point_normals

    rng = np.random.default_rng(2)
    wall = _face(rng, 20_000, (-1.0, 1.0), (0.19, 0.19), (0.05, 0.38))
    roof = _face(rng, 20_000, (-1.0, 1.0), (-0.19, 0.19), (0.38, 0.38))
    pts = np.vstack([wall, roof]) + rng.normal(0.0, 0.001, (40_000, 3))
    nrm = point_normals(pts)
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0)
    assert np.mean(np.abs(nrm[:20_000, 1]) >= np.cos(np.radians(30))) > 0.95
    assert np.mean(np.abs(nrm[20_000:, 2]) >= np.cos(np.radians(30))) > 0.95

def test_a_facing_peak_moves_a_surface_only_outwards_and_within_reach():
    """``_outer_peak``: a flat surface just inside a curved one (a cab's wall inside a tank's flank) must
    not take the flank's place; a facing peak beyond reach, or a density still rising there, moves nothing."""
    from measure.dimensions import _outer_peak

    grid = np.linspace(-0.1, 0.1, 2001)
    bump = lambda c: np.exp(-0.5 * ((grid - c) / 0.002) ** 2)  # noqa: E731
    e = 0.05
    assert abs(_outer_peak(grid, bump(0.053), e, 0.007, +1) - 0.053) < 1e-4       # outwards, within reach
    assert _outer_peak(grid, bump(0.047), e, 0.007, +1) == e                       # inwards: stays
    assert _outer_peak(grid, bump(0.070), e, 0.007, +1) == e                       # beyond reach: stays
    assert abs(_outer_peak(grid, bump(-0.053), -e, 0.007, -1) + 0.053) < 1e-4     # the left wall, outwards
    assert _outer_peak(grid, bump(-0.047), -e, 0.007, -1) == -e


def test_wall_plateau_reads_the_widest_stretch_above_the_chassis():
    """The walls' plateau: the highest 13-slice median of a width profile above the chassis; none where a
    stretch of 9 starting lower is wider (a flatbed's deck, wheels and cab beside its narrower load) or no
    stretch has a majority."""
    from measure.dimensions import wall_plateau

    cfg = DimensionConfig()
    win, low = cfg.wall_plateau_slices, cfg.wall_plateau_low_slices
    assert (win, low) == (13, 9)
    box = np.r_[np.full(3, 2.0), np.full(15, 2.5), [2.8, 2.9]]       # chassis, walls, a rim flaring at the roof
    box[8] = np.nan
    assert wall_plateau(box, 9, 3, tol=0.02) == (2.5, 3)
    assert wall_plateau(box, win, 3, 0.02, low) == (2.5, 3)
    flatbed = np.r_[np.full(5, 2.5), np.full(15, 2.25)]                # deck and cab below a load 10 % narrower
    assert wall_plateau(flatbed, 9, 3, tol=0.02) is None
    assert wall_plateau(flatbed, win, 3, 0.02, low) is None
    # Why the test's stretches are shorter: one of 13 from the ground is mostly load, and passes for walls.
    assert wall_plateau(flatbed, win, 3, 0.02) == (2.25, 3)
    assert wall_plateau(flatbed, 9, 3, tol=0.3) == (2.25, 3)           # within the walls' blur: one reading
    sparse = np.full(20, np.nan)
    sparse[::3] = 2.5                                                  # 3 or 4 of every 9 slices
    assert wall_plateau(sparse, 9, 3) is None
    assert wall_plateau(sparse, win, 3, 0.0, low) is None


def test_a_longer_plateau_reads_noisy_walls_with_less_outward_bias():
    """The plateau is the widest of several stretches' medians, so a noisy wall's widest: over 400 profiles of
    walls read with 3 % scatter per slice (as on full-scale boxes' tuning clouds), chassis and a flaring rim,
    13-slice stretches read +0.7 % (9-slice ones +1.3 %), their scatter no larger."""
    from measure.dimensions import wall_plateau

    rng = np.random.default_rng(0)
    cfg = DimensionConfig()
    err = {9: [], cfg.wall_plateau_slices: []}
    for _ in range(400):
        w = np.r_[np.full(3, 0.94), 1 + rng.normal(0, 0.03, 15), 1 + np.abs(rng.normal(0.04, 0.03, 2))]
        for k in err:
            err[k].append(wall_plateau(w, k, 3, 0.02, cfg.wall_plateau_low_slices)[0] - 1)
    bias = {k: float(np.mean(v)) for k, v in err.items()}
    assert bias[cfg.wall_plateau_slices] < 0.008 and bias[9] > bias[cfg.wall_plateau_slices] + 0.004, bias
    assert np.std(err[cfg.wall_plateau_slices]) <= np.std(err[9]), {k: np.std(v) for k, v in err.items()}


def _roof_pieces(rng, L, W, H, z_roof):
    """Walls, ends and a roof whose height z_roof(x) follows the length (m), 2 mm noise."""
    x = rng.uniform(-L / 2, L / 2, 40_000)
    roof = np.column_stack([x, rng.uniform(-W / 2, W / 2, len(x)), z_roof(x)])
    pts = [roof]
    for s in (-1, 1):
        xw = rng.uniform(-L / 2, L / 2, 20_000)
        pts.append(np.column_stack([xw, np.full(len(xw), s * W / 2), rng.uniform(0.1 * H, 1.0, len(xw)) * z_roof(xw)]))
    xyz = np.vstack(pts)
    xyz[:, 2] += rng.normal(0.0, 0.002, len(xyz))
    return xyz


def test_a_cargo_body_higher_than_the_level_found_gives_the_height_and_a_dome_does_not():
    """The roof level of all the points can be a lower cab's crisp roof when the cargo body's plain roof is
    fused as a smear (tuning draw 2036/38, a black semi-trailer: H -23.7 %). When the upper surface along
    the length lies above that level over a stretch from one end (the body), the level is read from the
    stretch's points; a dome in the middle of a roof (as the external renders' roofs came out) is no
    such stretch and keeps the level."""
    from measure.dimensions import _height_bins, _highest_stretch_roof

    rng = np.random.default_rng(31)
    L, W, H = 2.0, 0.38, 0.40
    hz = 0.002
    cfg = DimensionConfig()

    def stretch(xyz, level):
        out: dict = {}
        lo, _ = _height_bins(xyz[:, 2], hz, hz / 4)
        ends = {"length": (-L / 2, L / 2), "width": (-W / 2, W / 2)}
        got = _highest_stretch_roof(xyz[:, 0], xyz[:, 2], ends, level, "roof_peak", 0.1, hz, hz / 4, None, out,
                                    xyz[:, 1], cfg)
        return got, out

    body = _roof_pieces(rng, L, W, H, lambda x: np.where(x < 0.5, H, 0.8 * H))   # cab: the front quarter, 0.8 H
    (level, rule, support), out = stretch(body, 0.8 * H)
    assert rule == "roof_peak_highest_stretch" and abs(level - H) < 0.005, (rule, level)
    assert out["height_roof_all_m"] == 0.8 * H and 0 < support < 1

    dome = _roof_pieces(rng, L, W, H, lambda x: 0.8 * H + 0.1 * H * np.clip(1 - (x / 0.5) ** 2, 0, None))
    (level, rule, _), out = stretch(dome, 0.8 * H)
    assert rule == "roof_peak" and level == 0.8 * H and not out, (rule, level)
    off = measure_dimensions(body, resolution_m=0.004, noise_m=hz, config=replace(cfg, roof_stretch_min_share=None))
    on = measure_dimensions(body, resolution_m=0.004, noise_m=hz)
    assert abs(on["height_m"] - H) < 0.005 and abs(off["height_m"] - H) < 0.005  # a crisp body roof: found either way


def test_a_sagging_roof_is_read_at_its_level_and_the_uncertainty_spans_its_upper_stretch():
    """A plain roof seen at a grazing angle from far sags where its depth is worst (tuning seed 2029 draw 6 on
    the rig alone: 5 cm at its middle, H -14 % at 3 mm): the densest level lies on the sag, and with the ground
    as noisy as there (16 mm) the gap to the top 0.5 % is within 3 x its noise, so neither says the level is low. Its cells' median levels spread far beyond their
    standard error: the uncertainty spans its upper stretch (``roof_cells_quantile``) and the measurement says
    why; without the term the truth is many sigma off. A flat roof keeps its tight uncertainty."""
    rng = np.random.default_rng(11)
    L, W, H, sag = 1.4, 0.22, 0.32, 0.04
    walls = np.vstack([_face(rng, 20_000, (-L / 2, L / 2), (s * W / 2, s * W / 2), (0.1 * H, H)) for s in (-1, 1)])
    ends = np.vstack([_face(rng, 4_000, (x, x), (-W / 2, W / 2), (0.1 * H, H)) for x in (-L / 2, L / 2)])
    roof = _face(rng, 40_000, (-L / 2, L / 2), (-W / 2, W / 2), (H, H))
    roof[:, 2] -= sag * (1 - (2 * roof[:, 0] / L) ** 2)   # deepest at the middle, its ends at H
    xyz = np.vstack([walls, ends, roof])
    xyz[:, 2] += rng.normal(0.0, 0.004, len(xyz))
    m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.016)
    assert m["rules"]["height"] == "roof_peak" and m["height_m"] < H - 0.6 * sag, m["height_m"]
    assert m["height_top_m"] - m["height_roof_m"] < 3 * 0.016, m["height_top_m"]
    assert H - m["height_m"] < 2 * m["uncertainty_m"]["height"], m["uncertainty_m"]
    assert any(w.startswith("roof not level") for w in m["warnings"]), m["warnings"]
    off = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.016, config=replace(DimensionConfig(), roof_cells_quantile=None))
    assert H - off["height_m"] > 4 * off["uncertainty_m"]["height"], off["uncertainty_m"]
    flat = measure_dimensions(_truck(np.random.default_rng(8), wall_sigma=0.002), resolution_m=0.004, noise_m=0.002)
    assert flat["uncertainty_m"]["height"] < 0.0025 and not any(w.startswith("roof not level") for w in flat["warnings"])


def test_the_length_is_read_at_the_end_faces_not_at_a_roof_smeared_past_them():
    """A box seen from far: its roof and walls smear past its end faces along the rays (a 7.6 m plain box from
    20 m, seed 21 draw 0: L +5.3 % between all points' outermost peaks). The end-facing points place the faces
    (``end_facing_cos``); the uncertainty spans the peaks' reading. Past one end only, the outer peak is kept;
    a clean box reads the same either way."""
    rng = np.random.default_rng(5)
    L, W, H, over = 7.6, 2.4, 3.9, 0.25
    walls = np.vstack([_face(rng, 60_000, (-L / 2 - over, L / 2 + over), (s * W / 2, s * W / 2), (0.1 * H, H)) for s in (-1, 1)])
    roof = _face(rng, 60_000, (-L / 2, L / 2), (-W / 2, W / 2), (H, H))
    # The smear: a band of roof and wall-top points past each face, denser than the face at its edge.
    smear = np.vstack([_face(rng, 6_000, tuple(sorted((s * L / 2, s * (L / 2 + over)))), (-W / 2, W / 2), (H, H)) for s in (-1, 1)]
                      + [_face(rng, 3_000, (s * (L / 2 + over) - 0.02, s * (L / 2 + over) + 0.02), (-W / 2, W / 2), (0.8 * H, H))
                         for s in (-1, 1)])
    faces = np.vstack([_face(rng, 12_000, (x, x), (-W / 2, W / 2), (0.1 * H, H)) for x in (-L / 2, L / 2)])
    xyz = np.vstack([walls, roof, smear, faces])
    xyz += rng.normal(0.0, 0.01, xyz.shape)
    paper = measure_dimensions(xyz, resolution_m=0.015, noise_m=0.01, config=replace(DimensionConfig(), end_facing_cos=None))
    assert paper["length_m"] > L + over, paper["length_m"]
    m = measure_dimensions(xyz, resolution_m=0.015, noise_m=0.01)
    assert abs(m["length_m"] / L - 1) < 0.01, m["length_m"]
    assert m["length_peaks_m"] == paper["length_m"]
    assert abs(m["length_peaks_m"] - m["length_m"]) / 2 <= m["uncertainty_m"]["length"] * 1.001
    assert any("end faces' own points" in w for w in m["warnings"]), m["warnings"]
    # Past one end only, the outer points are the body's (a cab's nose ahead of its windscreen): both or neither.
    one_end = np.vstack([walls[walls[:, 0] < L / 2 + 0.01], roof, smear[smear[:, 0] < 0], faces])
    one_end += rng.normal(0.0, 0.01, one_end.shape)
    one = measure_dimensions(one_end, resolution_m=0.015, noise_m=0.01)
    assert one["length_peaks_m"] is None and one["length_m"] > L + 0.8 * over, one["length_m"]
    clean = _truck(np.random.default_rng(9), wall_sigma=0.002)
    a = measure_dimensions(clean, resolution_m=0.004, noise_m=0.002)
    b = measure_dimensions(clean, resolution_m=0.004, noise_m=0.002, config=replace(DimensionConfig(), end_facing_cos=None))
    assert a["length_m"] == b["length_m"] and a["length_peaks_m"] is None


def _skirted_box(rng, L, W, H, skirt_share, bumper=0.0):
    """A full-scale box (walls, roof, end faces) and, 0.2 m past its front face, a skirt of ground points
    hovering 0.07-0.3 m above the ground, skirt_share of the points; bumper (m): a bumper that far ahead of
    the face at 0.15-0.25 of the height, its own face included."""
    xyz = _truck(rng, L=L, W=W, H=H, wall_sigma=0.01)
    n = int(skirt_share * len(xyz))
    skirt = np.column_stack([L / 2 + bumper + rng.normal(0.2, 0.03, n), rng.uniform(-W / 2, W / 2, n), rng.uniform(0.07, 0.3, n)])
    parts = [xyz, skirt]
    if bumper:
        parts.append(_face(rng, 4_000, (L / 2, L / 2 + bumper), (-W / 2, W / 2), (0.25 * H, 0.25 * H)))
        parts.append(_face(rng, 4_000, (L / 2 + bumper, L / 2 + bumper), (-W / 2, W / 2), (0.15 * H, 0.25 * H)))
    return np.vstack(parts) + rng.normal(0.0, 0.005, (sum(len(p) for p in parts), 3))


def test_a_skirt_of_ground_points_past_an_end_face_is_no_end():
    """A 7.6 m box whose front face carries a skirt of ground points hovering past it (SGBM bleeds the nearer
    ground's disparity up a dark or plain face; seed 21's draw 0, a box with a black cab: its front read 0.20 m
    ahead of the cab, L +3.5 %). All points' outermost peak is the skirt's; judged against the extent of the
    points above it (``length_min_height``) it is no end. A bumper ahead of the face at a fifth of the height
    is still read. Measured: -0.003 % (sigma 0.15 %); without, +2.6 % at 17 sigma; the bumper -1 mm (without:
    the skirt, +0.20 m)."""
    L, W, H = 7.6, 2.4, 3.9
    xyz = _skirted_box(np.random.default_rng(3), L, W, H, 0.03)
    m = measure_dimensions(xyz, resolution_m=0.016, noise_m=0.02)
    off = measure_dimensions(xyz, resolution_m=0.016, noise_m=0.02, config=replace(DimensionConfig(), length_min_height=None))
    assert off["length_m"] > L + 0.1, off["length_m"]
    assert abs(m["length_m"] / L - 1) < 0.005, m["length_m"]
    bumped = _skirted_box(np.random.default_rng(3), L, W, H, 0.03, bumper=0.12)
    b = measure_dimensions(bumped, resolution_m=0.016, noise_m=0.02)
    assert abs(b["length_m"] - (L + 0.12)) < 0.03, b["length_m"]
    assert abs(m["length_m"] - L) <= 2 * m["uncertainty_m"]["length"] < off["length_m"] - L, m["uncertainty_m"]


def test_a_skirt_spread_past_an_end_moves_neither_the_end_nor_its_window():
    """A full-scale box with a skirt of ground points spread 0.6 m past its rear face at its foot (2-12 % of the
    height: the ground's noise fused to the truck where the orbit did not cover the rear; seed 2075's draw 18, a
    9.4 m semi-trailer read +5.9 % and refused by the rear face's gate). All points' robust extreme lay at the
    skirt's edge, the end window around it missed the face's peak, and the rear was read at that edge. The
    points above the skirt bound the extremes too (``length_extreme_above_skirt``)."""
    rng = np.random.default_rng(11)
    L, W, H, past = 9.4, 2.5, 4.0, 0.6
    body = _truck(rng, L=L, W=W, H=H, wall_sigma=0.01, n=60_000)
    n = int(0.005 * len(body))
    skirt = np.column_stack([rng.uniform(-L / 2 - past, -L / 2, n), rng.uniform(-W / 2, W / 2, n), rng.uniform(0.02 * H, 0.12 * H, n)])
    xyz = np.vstack([body, skirt]) + rng.normal(0.0, 0.01, (len(body) + n, 3))
    before = measure_dimensions(xyz, resolution_m=0.02, noise_m=0.01, config=replace(DimensionConfig(), length_extreme_above_skirt=False))
    assert before["length_m"] > L + 0.5 * past, before["length_m"]
    m = measure_dimensions(xyz, resolution_m=0.02, noise_m=0.01)
    assert abs(m["length_m"] / L - 1) < 0.005, m["length_m"]
    assert m["rules"]["length"] == "rear_peak_to_front_peak", m["rules"]


def _cab_over_nose(rng, L=2.0, W=0.34, H=0.42, setback=0.035, smear=0.05, n=40_000, sigma=0.003):
    """A model box truck whose cab's lower part (its nose, 0.1-0.5 H) reaches the front at L/2 while its
    windscreen and roof (0.5-0.8 H) stand ``setback`` (m) behind it, as the envelope's cabs do."""
    x_cab0, xf = 0.25 * L, L / 2
    pts = [_face(rng, n, (-L / 2, x_cab0 - 0.02), (s * W / 2, s * W / 2), (0.1 * H, H)) for s in (-1, 1)]
    pts.append(_face(rng, n, (-L / 2, x_cab0 - 0.02), (-W / 2, W / 2), (H, H)))                       # box roof
    pts.append(_face(rng, n // 4, (-L / 2, -L / 2), (-W / 2, W / 2), (0.1 * H, H)))                    # rear face
    pts.append(_face(rng, n // 4, (x_cab0 - 0.02, x_cab0 - 0.02), (-W / 2, W / 2), (0.8 * H, H)))      # box front above the cab
    for s in (-1, 1):
        pts.append(_face(rng, n // 4, (x_cab0, xf), (s * W / 2, s * W / 2), (0.1 * H, 0.5 * H)))       # nose sides
        pts.append(_face(rng, n // 4, (x_cab0, xf - setback), (s * W / 2, s * W / 2), (0.5 * H, 0.8 * H)))  # cab sides
    # A dark nose: few points on its face, no peak of its own among all points.
    pts.append(_face(rng, n // 100, (xf, xf), (-W / 2, W / 2), (0.1 * H, 0.5 * H)))
    pts.append(_face(rng, n // 20, (xf - setback, xf), (-W / 2, W / 2), (0.5 * H, 0.5 * H)))           # ledge at the sill
    pts.append(_face(rng, n // 4, (xf - setback, xf - setback), (-W / 2, W / 2), (0.5 * H, 0.8 * H)))  # windscreen
    pts.append(_face(rng, n // 2, (x_cab0, xf - setback), (-W / 2, W / 2), (0.8 * H, 0.8 * H)))         # cab roof
    # The rear's roof and wall tops smeared past its face along the rays (``end_facing_cos`` moves that end in).
    pts.append(_face(rng, n // 6, (-L / 2 - smear, -L / 2), (-W / 2, W / 2), (H, H)))
    pts.append(_face(rng, n // 12, (-L / 2 - smear - 0.004, -L / 2 - smear + 0.004), (-W / 2, W / 2), (0.8 * H, H)))
    xyz = np.vstack(pts)
    return xyz + rng.normal(0.0, sigma, xyz.shape)


def test_an_end_is_read_at_a_cabs_nose_ahead_of_its_set_back_windscreen():
    """A cab's nose stands ahead of its windscreen and roof (1-2 % of the length in the envelope's cabs). With
    the rear's roof smeared past its face, both ends' facing points lie inside all points' peaks and the ends
    move in to them (``end_facing_cos``), the front to the windscreen, whose facing points outnumber the
    nose's. (Seed 2062's draw 18, a model tanker, read L -2.21 %, its front at the windscreen 2.24 % behind the
    nose, whose peak of all points was too weak to count as an end peak.) Per height the
    end-facing points' main peak finds the nose over a stretch of low heights (``end_step_blurs``); the
    smear at the rear's top is no such stretch. Measured: L -0.005 % (sigma 1.2 %: it spans all points'
    peaks, +2.3 %); without, -1.75 %. A plain box reads the same either way."""
    L, setback = 2.0, 0.035
    xyz = _cab_over_nose(np.random.default_rng(4), L=L, setback=setback)
    off = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=replace(DimensionConfig(), end_step_blurs=None))
    assert off["length_m"] < L - 0.8 * setback, off["length_m"]
    m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003)
    assert abs(m["length_m"] - L) < 0.1 * setback, m["length_m"]
    assert abs(m["length_m"] - L) <= 2 * m["uncertainty_m"]["length"], m["uncertainty_m"]
    assert m["length_peaks_m"] == off["length_peaks_m"] > L
    # A plain box: no stretch stands out, nothing moves.
    clean = _truck(np.random.default_rng(9), wall_sigma=0.002)
    a = measure_dimensions(clean, resolution_m=0.004, noise_m=0.002)
    b = measure_dimensions(clean, resolution_m=0.004, noise_m=0.002, config=replace(DimensionConfig(), end_step_blurs=None))
    assert a["length_m"] == b["length_m"] and a["length_peaks_m"] is None


def _envelope_flatbed(rng, L=12.0, W=2.57, H=3.9, n=40_000, sigma=0.012, deck_points=2000, eroded_m=0.0):
    """A full-scale flatbed laid out as the operating envelope draws it (``stereo_recon.synthetic.scene``): the
    deck (0.35 wheel radii thick, its top at ~0.31 H) spans the width, the load 10 % and the cab 3 % narrower
    stand on it; the deck's strip beside the load and its thin edge face hold few points (deck_points per
    side). eroded_m: the deck's strip and edge face end that far (m) inside the deck's true edge on each side,
    as fusion leaves a thin deck's convex edge."""
    r = min(0.125 * H, 0.2 * W, 0.06 * L)
    zf, zd = 2.15 * r, 2.5 * r            # the deck's underside and top
    lw, cw = 0.9 * W, 0.97 * W
    xr, xb, xc = -L / 2, 0.25 * L, 0.3 * L
    pts = []
    for s in (-1, 1):
        we = W / 2 - eroded_m
        pts.append(_face(rng, deck_points, (xr, xb), tuple(sorted((s * lw / 2, s * we))), (zd, zd)))    # deck strip
        pts.append(_face(rng, deck_points // 2, (xr, xb), (s * we, s * we), (zf, zd)))                  # deck edge face
        pts.append(_face(rng, n, (xr, xb), (s * lw / 2, s * lw / 2), (zd, 0.9 * H)))                     # load sides
        pts.append(_face(rng, n // 6, (xc, L / 2), (s * cw / 2, s * cw / 2), (0.1 * H, 0.85 * H)))       # cab sides
        pts.append(_face(rng, n // 10, (xr, xc), (s * 0.36 * W, s * 0.36 * W), (0.1 * H, zf)))           # chassis
    pts.append(_face(rng, n, (xr, xb), (-lw / 2, lw / 2), (0.9 * H, 0.9 * H)))                           # load top
    pts.append(_face(rng, n // 4, (xc, L / 2), (-cw / 2, cw / 2), (0.85 * H, 0.85 * H)))                 # cab roof
    pts.append(_face(rng, n // 4, (xr, xr), (-lw / 2, lw / 2), (zd, 0.9 * H)))                           # load rear
    pts.append(_face(rng, n // 20, (xr, xr), (-W / 2, W / 2), (zf, zd)))                                 # deck rear
    pts.append(_face(rng, n // 4, (L / 2, L / 2), (-cw / 2, cw / 2), (0.1 * H, 0.85 * H)))               # cab front
    p = np.vstack(pts)
    return p + rng.normal(0.0, sigma, p.shape)


def test_a_flatbeds_deck_is_read_from_its_slice_where_the_cab_makes_the_outer_peaks():
    """A full-scale flatbed whose cab (3 % narrower than the deck) makes all points' outermost peaks, its deck's
    strip and edge beside the load too few points outside them for a shoulder: the width reads the cab's,
    3 % low at 0.45 % sigma (6.7 sigma off; seed 2064's draw 2, a 2.57 m flatbed read -5.7 % at 3 sigma, a
    wrong `within`). In the deck's own thin height slice its points are the outermost peak
    (``ledge_blurs``): the side moves out to where that slice's points end (its half-height crossing).
    Measured on the ideal deck here: +1.47 / +1.58 %, sigma 2.3 % (the edge face's own blur lies outside it; the
    cab's reading the other one). A plain box reads the same either way; so does a box whose sheared top pulls
    the width's centre aside (``tests/measure/test_measure_heading.py``: its walls' plateau is placed off the
    walls, but its low slices stand no further out than its upper ones)."""
    W = 2.57
    for seed in range(2):
        xyz = _envelope_flatbed(np.random.default_rng(seed), W=W)
        off = measure_dimensions(xyz, resolution_m=0.016, noise_m=0.012, config=replace(DimensionConfig(), ledge_blurs=None))
        assert off["rules"]["width"] == "kde_two_peaks" and off["width_m"] < 0.975 * W, (off["rules"], off["width_m"])
        assert W - off["width_m"] > 5 * off["uncertainty_m"]["width"], off["uncertainty_m"]
        m = measure_dimensions(xyz, resolution_m=0.016, noise_m=0.012)
        assert m["rules"]["width"] == "low_ledge", (m["rules"], m["width_m"])
        assert abs(m["width_m"] / W - 1) < 0.02 and abs(m["width_m"] - W) < m["uncertainty_m"]["width"], m["width_m"]
        assert m["width_walls_m"] == off["width_m"] and m["width_wall_edges_m"] == tuple(off["edges_m"]["width"])
        assert any("low on the truck" in w for w in m["warnings"]), m["warnings"]
    # A plain box: its low slices stand where its walls do, nothing moves.
    clean = _truck(np.random.default_rng(9), wall_sigma=0.002)
    a = measure_dimensions(clean, resolution_m=0.004, noise_m=0.002)
    b = measure_dimensions(clean, resolution_m=0.004, noise_m=0.002, config=replace(DimensionConfig(), ledge_blurs=None))
    assert a["width_m"] == b["width_m"] and a["rules"]["width"] == b["rules"]["width"] != "low_ledge"


def test_a_fused_decks_edge_is_where_its_points_end_not_a_walls_blur_inside_it():
    """Fusion leaves a thin deck's edge short of the truth (a median 1.6 % of W inside it on each side, 98 sides
    of 49 flatbeds: README, known limitations): on the tuning seeds' full-scale flatbeds even the deck slice's
    half-height crossing mostly lies inside the deck's true edge (widths read by it +0.1 to -3.4 %, four of
    five narrow). Taking the walls' peak-to-edge offset off that crossing as well, as for a wall
    (``ledge_less_walls_offset``), read those five decks 1.7-3.8 % narrow, and where the deck stood less than
    2 blurs out after that offset, not at all: seed 2075's draw 31 read -5.1 %, seed 2070's draw 16 -4.6 %. Here the
    deck's strip and face end 1 cm (0.4 % of W, under a blur) inside its edge: with the offset taken off (and
    the 2 blurs the test then asked) no ledge is found and the width is the cab's, -3.0 % at 0.45 % sigma; the
    slice's edge as it is, 2.5 blurs out, reads +0.6 / +0.7 %, inside 2 sigma."""
    W = 2.57
    for seed in range(2):
        xyz = _envelope_flatbed(np.random.default_rng(seed), W=W, eroded_m=0.01)
        old = measure_dimensions(xyz, resolution_m=0.016, noise_m=0.012,
                                 config=replace(DimensionConfig(), ledge_less_walls_offset=True, ledge_blurs=2.0))
        assert old["rules"]["width"] != "low_ledge" and W - old["width_m"] > 5 * old["uncertainty_m"]["width"], (
            old["rules"], old["width_m"], old["uncertainty_m"])
        m = measure_dimensions(xyz, resolution_m=0.016, noise_m=0.012)
        assert m["rules"]["width"] == "low_ledge", (m["rules"], m["width_m"])
        assert abs(m["width_m"] / W - 1) < 0.01 and abs(m["width_m"] - W) < 2 * m["uncertainty_m"]["width"], m["width_m"]


def _flared_box(rng, L=2.0, W=0.4, H=0.4, flare=0.08, n=40_000, sigma=0.003):
    """A model box whose right wall's foot flares into the ground as fusion rounds the corner: from 0.3 H down
    to 0.1 H its points move out linearly, ``flare`` (m) beyond the wall at the bottom, along 80 % of the length."""
    pts = [_face(rng, n, (-L / 2, L / 2), (s * W / 2, s * W / 2), (0.1 * H, H)) for s in (-1, 1)]
    z0, z1, m = 0.1 * H, 0.3 * H, n // 4
    z = rng.uniform(z0, z1, m)
    pts.append(np.column_stack([rng.uniform(-0.4 * L, 0.4 * L, m), W / 2 + flare * (z1 - z) / (z1 - z0), z]))
    pts.append(_face(rng, n, (-L / 2, L / 2), (-W / 2, W / 2), (H, H)))
    pts += [_face(rng, n // 4, (x, x), (-W / 2, W / 2), (0.1 * H, H)) for x in (-L / 2, L / 2)]
    p = np.vstack(pts)
    return p + rng.normal(0.0, sigma, p.shape)


def test_a_walls_foot_flaring_into_the_ground_is_no_ledge():
    """A wall's foot flaring outwards down to the lowest slice (fusion rounding the corner into the ground) is
    no deck: a deck sits on a narrower chassis, so its slice stands out of a lower one (``ledge_below_blurs``).
    Seed 2070's draws 1, 21 and 29 (a full-scale flatbed, a model flatbed, a model semi-trailer) read W +12.2,
    +11.4 and +15.0 % through the lowest slice of such a foot; real decks on tuning seeds 2062-2065 and Table 2's
    truck 6 stand 0.4-4.5 blurs out of a slice below them. Measured here: +13.9 % with any slice, +2.7 to +3.0 %
    with the rule (a shoulder of the flare, inside 2 sigma)."""
    W = 0.4
    for seed in range(3):
        xyz = _flared_box(np.random.default_rng(seed), W=W)
        old = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003, config=replace(DimensionConfig(), ledge_below_blurs=None))
        assert old["rules"]["width"] == "low_ledge" and old["width_m"] > 1.1 * W, (old["rules"], old["width_m"])
        m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.003)
        assert m["rules"]["width"] != "low_ledge" and m["width_m"] < 1.04 * W, (m["rules"], m["width_m"])
        assert abs(m["width_m"] - W) <= 2 * m["uncertainty_m"]["width"], m["uncertainty_m"]


def _box_skirted_beside(rng, L=1.4, W=0.3, H=0.5, reach=0.04, n=40_000, sigma=0.004):
    """A model box on its wheels (its walls from 0.25 H up) whose right wall's foot carries a skirt of ground
    points fused to it below 0.14 H, thinning out to about ``reach`` (m) beyond the wall, and under both roof
    edges a sparse fringe out to 40 mm (SGBM smearing the roof over the ground beyond it: it moves the
    extent out past the skirt)."""
    pts = [_face(rng, n, (-L / 2, L / 2), (s * W / 2, s * W / 2), (0.25 * H, H)) for s in (-1, 1)]
    m = n // 4
    pts.append(np.column_stack([rng.uniform(-0.45 * L, 0.45 * L, m), W / 2 + rng.exponential(reach / 2, m),
                                rng.uniform(0.0, 0.14 * H, m)]))
    pts.append(_face(rng, n, (-L / 2, L / 2), (-W / 2, W / 2), (H, H)))
    pts += [_face(rng, n // 100, (-L / 2, L / 2), tuple(sorted((s * W / 2, s * (W / 2 + 0.04)))), (0.9 * H, H)) for s in (-1, 1)]
    pts += [_face(rng, n // 4, (x, x), (-W / 2, W / 2), (0.25 * H, H)) for x in (-L / 2, L / 2)]
    p = np.vstack(pts)
    return p + rng.normal(0.0, sigma, p.shape)


def test_the_grounds_skirt_at_a_walls_foot_is_no_shoulder():
    """Points outside a wall lying mostly near the ground (below ``shoulder_skirt_height`` x the top) are its
    skirt fused to the wall's foot, not a wider part (a deck or a cab stands higher): at most a doubtful
    shoulder whose reading the uncertainty spans. Seed 2071's two model boxes read W +13.9 / +13.6 % through
    such a skirt (75-76 % of one side's outside points under 0.15 of the top). The walls' plateau is off here, as
    it was on those draws (it would read these walls either way). Measured: +5.1 to +6.3 % with the skirt as a
    shoulder, -0.03 to +0.06 % (sigma 2.7-3.3 %) without."""
    W = 0.3
    cfg = replace(DimensionConfig(), wall_plateau_slices=None)
    for seed in range(2):
        for reach in (0.02, 0.06):
            xyz = _box_skirted_beside(np.random.default_rng(seed), W=W, reach=reach)
            old = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.004, config=replace(cfg, shoulder_skirt_height=None))
            assert old["rules"]["width"] == "kde_peaks_plus_outer_shoulder" and old["width_m"] > 1.04 * W, (old["rules"], old["width_m"])
            m = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.004, config=cfg)
            assert m["rules"]["width"] == "kde_two_peaks" and abs(m["width_m"] / W - 1) < 0.005, (m["rules"], m["width_m"])
            assert m["width_shoulder_m"] is not None and m["width_shoulder_m"] > 1.04 * W, m["width_shoulder_m"]
            assert m["uncertainty_m"]["width"] > 0.5 * (m["width_shoulder_m"] - m["width_m"]) / 2, m["uncertainty_m"]


def test_one_wall_and_an_extreme_is_read_alike_in_a_mirror_and_spans_the_walls():
    """Both walls stand as peaks, but a fringe beyond one of them (8 % of the points, up to 12 cm out, high on
    the body, as a roof edge's depth smeared into the background) moves the extent out until the walls fail
    its span test, and the width falls back to one wall and the other side's extreme. Which side goes to its
    extreme was the width axis' sign (the first that passed: a mirror image read +31 % one way, +7 % the
    other; seed 2068 draw 22, a model flatbed, +33 %). Now: the narrower, the same in the mirror, with the
    walls' own reading in its uncertainty (truth within 2 sigma). The walls' plateau is off, as beside a
    flatbed's deck."""
    rng = np.random.default_rng(11)
    W, H = 0.38, 0.38
    xyz = _truck(rng, W=W, H=H, wall_sigma=0.003)
    far = _face(rng, int(0.08 * len(xyz)), (-1.0, 1.0), (-W / 2 - 0.12, -W / 2), (0.5 * H, 0.9 * H))
    near = _face(rng, int(0.01 * len(xyz)), (-1.0, 1.0), (W / 2, W / 2 + 0.03), (0.5 * H, 0.9 * H))
    pts = np.vstack([xyz, far, near])
    cfg = replace(DimensionConfig(), wall_plateau_slices=None)
    m, mirror = (measure_dimensions(pts * np.array([1.0, s, 1.0]), resolution_m=0.004, noise_m=0.003, config=cfg) for s in (1, -1))
    # Measured: +7.1 % (sigma 0.0151 m, 1.8 sigma from the truth) both ways; the walls' reading -0.02 %.
    for r in (m, mirror):
        assert r["rules"]["width"] == "one_peak_plus_extreme", r["rules"]
        assert r["width_m"] < W + 0.06, r["width_m"]                       # not the fringe's extreme
        assert abs(r["width_walls_m"] / W - 1) < 0.01, r["width_walls_m"]
        assert abs(r["width_m"] - W) <= 2 * r["uncertainty_m"]["width"], (r["width_m"], r["uncertainty_m"])
    assert abs(m["width_m"] - mirror["width_m"]) < 1e-4, (m["width_m"], mirror["width_m"])
