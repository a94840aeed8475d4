"""A plain black roof: SGBM carries the background's disparity into it unless pixels without texture get no depth.

Issue 12's "depth on weakly textured panels". The scene is draw 0 of tuning seed 2035 (48 frames): a 1.23 m
model box truck in plain black paint, whose roof's texture lies under the pixel noise. SGBM's paths enter the
plain roof from the background behind it and carry that disparity in; the hole fill then widens it. Both put
parts of the roof behind the truck, and the TSDF carves the roof there (a depth too far carves every voxel in
front of it), so the densest roof level left is the cab's. ``--plain-paint`` (``DisparityConfig.min_texture_snr``) drops the
pixels whose texture the noise drowns and ``fill_occlusion_slack_px`` fills a gap with the background only as
wide as an occlusion can be. Both are opt-in (they drop weakly textured panels too: Table 2 0.66 -> 0.97 %).
Measured when written: H -17.2 % without them, -2.4 % with them (and no same-surface interpolation); the
height's sigma (1.5 mm) does not cover that -2.4 % (3.6 sigma): one reason they stay opt-in. Both read at the
roof level: since issue 12's seventeenth round the measurement reads a dark body's height at its top
(``dark_body_max_brightness``), which on the default depth's carved roof gives +0.5 % (sigma 17.8 %: the
gap between the two readings).
"""

import json
from dataclasses import replace

import pytest

from measure.pipeline import MeasureConfig, measure_cloud_file
from stereo_recon.app.options import PLAIN_PAINT
from stereo_recon.app.pipeline import RunConfig, reconstruction_measure_args, run_video
from stereo_recon.reconstruct_config import ReconstructConfig
from stereo_recon.synthetic.envelope import draw_spec, ensure_rendered

pytestmark = pytest.mark.slow


def test_plain_black_roof_is_not_carved(tmp_path):
    scene = tmp_path / "draw"
    spec = draw_spec(2035, 0, max_frames=48)
    assert spec.truck.body_paint == "black" and spec.panel.texture_class == "plain"
    ensure_rendered(spec, scene)
    video = next(scene.glob("video.*"))
    calib = next(scene.glob("SN*.conf"))
    truth = json.loads((scene / "truth.json").read_text())

    # Read at the roof level (the measurement's dark-body rule off), the depth's effect alone shows.
    roof_level = replace(MeasureConfig(), dark_body_max_brightness=None)
    before = run_video(video, calib, tmp_path / "before", RunConfig(quiet=True, measure=roof_level))
    dark = replace(ReconstructConfig(), disparity_overrides=dict(PLAIN_PAINT))   # what --plain-paint sets
    after = run_video(video, calib, tmp_path / "after", RunConfig(quiet=True, reconstruct=dark, measure=roof_level))
    low = before["height_m"] / truth["height_m"] - 1
    err = after["height_m"] / truth["height_m"] - 1
    # The failure mode is there by default, and gone with the two rules (and no same-surface interpolation).
    assert low < -0.08, before
    assert abs(err) < 0.05 and abs(err) < abs(low) / 2, (err, low)
    # The default depth's carved roof, measured by default: the body is dark, so its height is read at its top
    # (the rim the carving leaves), not at the sagging level.
    run = tmp_path / "before"
    m = measure_cloud_file(run / "cloud.ply", tmp_path / "m", plots=False, html=False,
                           **reconstruction_measure_args(run / "run.json", run / "poses.txt", RunConfig()))
    top = m["height_m"] / truth["height_m"] - 1
    assert m["rules"]["height"] == "dark_top_99.5" and m["body_brightness"] < 0.2, (m["rules"], m["body_brightness"])
    assert abs(top) < abs(low) / 2 and abs(m["height_m"] - truth["height_m"]) <= 2 * m["uncertainty_m"]["height"], (top, m["uncertainty_m"])
