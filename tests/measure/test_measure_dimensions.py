"""Width rules of ``measure.dimensions`` on fused-cloud-like truck points (ground frame, exact truth)."""

from __future__ import annotations

import numpy as np

from measure.dimensions import measure_dimensions


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
