"""The synthetic texture is fixed to the world: every eye and every frame sees the same pattern on a surface,
wherever the camera (the texture's reference point) is."""

import numpy as np
import pytest

from stereo_recon.synthetic.texture import _TILE, Material, shade_albedo


@pytest.mark.parametrize("texel_m", [0.0015, 0.01])
def test_texture_does_not_depend_on_the_camera_position(texel_m):
    rng = np.random.default_rng(3)
    pts = rng.uniform(-3.0, 3.0, (2000, 3)).astype(np.float32)
    normals = np.eye(3, dtype=np.float32)[rng.integers(0, 3, len(pts))]   # x-, y- and z-facing panels
    mats = [Material("ground", (0.4, 0.4, 0.4), texture_strength=0.05, texel_m=texel_m, stain_mix=0.5),
            Material("panel", (0.8, 0.7, 0.6), texture_strength=0.02, texel_m=texel_m, stain_mix=0.5)]
    ids = rng.integers(0, 2, len(pts)).astype(np.int32)
    foot = np.zeros(len(pts), np.float32)
    grain = _TILE * texel_m   # the fine tile's period: cameras half of it apart rounded differently before
    ref0 = shade_albedo(pts, normals, ids, mats, foot, ref_m=np.zeros(3))
    for ref in ([0.51 * grain, 0, 1.0], [0, -0.51 * grain, 1.0], [1.7 * grain, 2.3 * grain, 5.0], [-3.49 * grain, 0.6 * grain, 2.0]):
        other = shade_albedo(pts, normals, ids, mats, foot, ref_m=np.asarray(ref, float))
        # float32 texel coordinates: ~1e-3 texel of position error at most
        assert np.max(np.abs(other - ref0)) < 2e-4, ref
    # and the texture is not flat: the comparison above could fail
    assert np.std(ref0[ids == 1, 0]) > 0.002
