"""Stereo VO on the synth package's rendered ZED2 model-truck orbit (exact depth and poses)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stereo_recon.synthetic.sequence")


@pytest.mark.slow
def test_vo_on_rendered_model_truck_orbit(tmp_path):
    import cv2

    from calib.io import load_rig
    from stereo_recon.odometry import StereoVO, VOConfig
    from stereo_recon.synthetic.render import RenderConfig
    from stereo_recon.synthetic.sequence import render_sequence
    from stereo_recon.trajectory import absolute_trajectory_error, read_tum, scale_error
    from stereo_recon.video import open_stereo_source

    out = tmp_path / "mt"
    frames = 24
    render_sequence("model-truck", out, seed=3, frames=frames, rectified=True, resolution="VGA", depth=True,
                    arc_deg=90.0, render_config=RenderConfig(shadows=False))
    src = open_stereo_source(out / "video.avi")
    rig = load_rig(out / "rig.yaml", image_size=src.eye_size)
    rect = rig.rectification()
    gt = read_tum(out / "poses_gt.txt", fps=src.fps)
    # VGA (672 px wide): corner spacing and LK window scaled down from the HD720 defaults.
    vo = StereoVO(rect.K_rect, rect.baseline_m, VOConfig(feature_min_distance_px=7.0, lk_window_px=11), fps=src.fps)
    for fr in src:
        gray = cv2.cvtColor(fr.left, cv2.COLOR_BGR2GRAY)
        assert vo.track(fr.index, gray, np.load(out / "depth" / f"{fr.index:06d}.npy"), fr.timestamp_s) is not None
    est = vo.finish()
    assert len(est) == frames and est.stats["tracking_gaps"] == []
    ate = absolute_trajectory_error(est, gt, with_scale=True)
    assert ate["rmse_rel_path"] <= 0.01, ate
    assert abs(scale_error(est, gt)) <= 0.005
    np.testing.assert_allclose(est.timestamps_s, gt.timestamps_s[:frames], atol=1e-6)
