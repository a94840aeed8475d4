"""A plain roof seen at a grazing angle from a wide orbit: the rig's depth reads it low, motion stereo does not.

Issue 12's "roofs sagging 3-5 cm when the truck is small in the image". The scene is draw 6 of tuning seed 2029
(48 frames): a 1.4 m model semi-trailer flown at 2 L, 21 deg above its roof, 28.6 rig baselines away. On its roof,
rectified SGBM on the 12 cm rig sits about 1 px of disparity towards the background (the roof is a 10 px strip
whose only edges run along the rows), 10 cm too far at 2.3 m; fused, the roof comes out 5 cm low. The drone's own
motion gives ~3x the rig's disparity there (0.11 x 28.6 baselines), which far scenes use (``ReconstructConfig.far_scene_depth_baselines``).
Measured when written: rig only H -16.5 % (-21 sigma; -2.0 sigma since the height's uncertainty spans the points
above the roof level); default H +0.7 % (+0.3 sigma). 2026-11-28 (another CPU, roof_cells_quantile): rig only
H -14.2 % (-1.1 sigma).
"""

import json
from dataclasses import replace

import pytest

from stereo_recon.app.pipeline import RunConfig, run_video
from stereo_recon.reconstruct_config import ReconstructConfig
from stereo_recon.synthetic.envelope import draw_spec, ensure_rendered

pytestmark = pytest.mark.slow


def test_wide_orbit_roof_is_measured_with_motion_stereo(tmp_path):
    scene = tmp_path / "draw"
    ensure_rendered(draw_spec(2029, 6, max_frames=48), scene)
    video = next(scene.glob("video.*"))
    calib = next(scene.glob("SN*.conf"))
    truth = json.loads((scene / "truth.json").read_text())

    rig_only = run_video(video, calib, tmp_path / "rig", RunConfig(quiet=True, reconstruct=replace(ReconstructConfig(), far_scene_depth_baselines=None)))
    low = rig_only["height_m"] / truth["height_m"] - 1
    # The failure mode is there: on the rig's depth alone the roof reads far low. Since the height's uncertainty
    # spans the points above the roof level (measure.dimensions), it is no longer a confident wrong number:
    # -21 sigma at first, -2.0 sigma with half the gap to the top 0.5 % as the term, -1.0 sigma with the
    # whole gap (H -14.7 %, the top 0.5 % of the points +0.6 %), and the measurement says why. On another
    # CPU (2026-11-28: H -14.2 %, the top -1.0 %) the gap, 2.6 x the ground's noise, fell under the 3 x the
    # term needed: -18 sigma. The roof's cells now show it is not level (their upper tenth 23 mm above the
    # level read, ``roof_cells_quantile``), which brings in the gap to the top whatever its size: -1.1 sigma.
    assert low < -0.08, rig_only
    assert truth["height_m"] - rig_only["height_m"] < 2 * rig_only["uncertainty_m"]["height"], rig_only
    record = json.loads((tmp_path / "rig" / "measurement.json").read_text())
    assert any("points reach" in w or w.startswith("roof not level") for w in record["warnings"]), record["warnings"]
    assert record["height_top_m"] > rig_only["height_m"] + 0.1 * truth["height_m"], record["height_top_m"]
    # Far scenes switched off, the first view's disparity is still recorded: the depth term of the length's and
    # width's uncertainty needs the working distance (it was missing from such runs before 2026-11-28).
    rig_counts = json.loads((tmp_path / "rig" / "run.json").read_text())["counts"]
    assert rig_counts["far_scene"] is False and 0 < rig_counts["first_view_disparity_px"] < 40, rig_counts

    summary = run_video(video, calib, tmp_path / "default", RunConfig(quiet=True))
    counts = json.loads((tmp_path / "default" / "run.json").read_text())["counts"]
    assert counts["far_scene"] and counts["first_view_depth_baselines"] > ReconstructConfig().far_scene_depth_baselines
    err = summary["height_m"] - truth["height_m"]
    assert abs(err) / truth["height_m"] < 0.03 and abs(err) <= 2 * summary["uncertainty_m"]["height"], (err, summary["uncertainty_m"])
