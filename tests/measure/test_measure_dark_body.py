"""A dark body's height (``DimensionConfig.dark_body_max_brightness``): its roof's depth sags, its rim does not.

On plain dark paint the rig's stereo has no texture over the noise: SGBM carries the background's disparity
into the roof and fusion carves it, so the roof's points lie below it, spread down by several centimetres,
while its rim, matched against the lighter ground, stays at the roof. The densest roof level then reads low;
the top 0.5 % of the points does not.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from measure.dimensions import DimensionConfig, measure_dimensions
from measure.pipeline import body_brightness


def _face(rng, n, x, y, z):
    return np.column_stack([rng.uniform(*x, n), rng.uniform(*y, n), rng.uniform(*z, n)])


def _sagging_box(rng, L=1.6, W=0.30, H=0.45, sag_m=0.04, ramp_m=0.03, rim_kept=0.3, noise=0.002, n=60_000):
    """A box truck whose roof is fused sag_m low (the carved roof) but for its edges: within ramp_m of them it
    rises to H, where the rim's points are sparse (rim_kept of them: a rim is a thin line in the views).
    Truth: H."""
    roof = _face(rng, n, (-L / 2, L / 2), (-W / 2, W / 2), (H, H))
    edge = np.minimum(L / 2 - np.abs(roof[:, 0]), W / 2 - np.abs(roof[:, 1]))
    roof[:, 2] -= sag_m * np.minimum(edge / ramp_m, 1.0)
    roof = roof[(edge > ramp_m / 3) | (rng.uniform(size=len(roof)) < rim_kept)]
    parts = [roof, _face(rng, n // 4, (L / 2, L / 2), (-W / 2, W / 2), (0.05, H)),
             _face(rng, n // 4, (-L / 2, -L / 2), (-W / 2, W / 2), (0.05, H))]
    for s in (-1, 1):
        parts.append(_face(rng, n, (-L / 2, L / 2), (s * W / 2, s * W / 2), (0.05, H)))
    return np.vstack(parts) + rng.normal(0, noise, (sum(len(p) for p in parts), 3))


def test_a_dark_body_is_measured_at_its_rim_and_a_light_one_at_its_roof():
    H = 0.45
    for seed in range(3):
        xyz = _sagging_box(np.random.default_rng(seed), H=H)
        dark = measure_dimensions(xyz, resolution_m=0.004, noise_m=0.002, body_brightness=0.12)
        assert dark["rules"]["height"] == "dark_top_99.5", dark["rules"]
        assert abs(dark["height_m"] / H - 1) < 0.01 and abs(dark["height_m"] - H) <= 2 * dark["uncertainty_m"]["height"]
        # The same points from a light body (or with the rule off) are read at the densest roof level: low.
        for light in (measure_dimensions(xyz, resolution_m=0.004, noise_m=0.002, body_brightness=0.9),
                      measure_dimensions(xyz, resolution_m=0.004, noise_m=0.002, body_brightness=0.12,
                                         config=replace(DimensionConfig(), dark_body_max_brightness=None))):
            assert light["rules"]["height"] != "dark_top_99.5"
            assert light["height_m"] < 0.97 * H, light["height_m"]


def test_body_brightness_is_the_median_luma_over_the_grounds():
    rng = np.random.default_rng(0)
    ground = np.clip(rng.normal(0.45, 0.05, (5000, 3)), 0, 1)
    black = np.clip(rng.normal(0.05, 0.02, (3000, 3)), 0, 1)
    white = np.clip(rng.normal(0.85, 0.05, (3000, 3)), 0, 1)
    assert body_brightness(black, ground) < 0.2 < body_brightness(white, ground)
    assert abs(body_brightness(white, ground) - 0.85 / 0.45) < 0.05
    assert body_brightness(black, np.zeros((10, 3))) is None and body_brightness(black[:0], ground) is None
