"""The reconstruction's depth-geometry uncertainty (stereo_recon.app.uncertainty) and its combination in measure."""

from __future__ import annotations

import math

import pytest

from measure.pipeline import combined_uncertainty
from stereo_recon.core.errors import ConfigError
from stereo_recon.app.uncertainty import ReconstructionErrorModel, depth_sigma_m


def _meta(disparity_px: float, motion: bool, f: float = 528.0, b: float = 0.12) -> dict:
    return {"rig": {"rectified": {"focal_px": f, "baseline_m": b}},
            "counts": {"first_view_disparity_px": disparity_px, "motion_stereo_views": 12 if motion else 0}}


def test_rig_depth_term_follows_z_squared_over_f_b():
    model = ReconstructionErrorModel()
    s1, p1 = depth_sigma_m(_meta(40.0, False), model)      # Z = 1.58 m
    s2, p2 = depth_sigma_m(_meta(20.0, False), model)      # twice as far: four times the depth error per px
    z1 = 528 * 0.12 / 40
    assert p1["e_z_m_per_px"] == pytest.approx(z1 ** 2 / (528 * 0.12))
    assert p2["e_z_m_per_px"] == pytest.approx(4 * p1["e_z_m_per_px"])
    assert s1["width"] == pytest.approx(model.rig_px["width"] * p1["e_z_m_per_px"])
    assert s2["height"] == pytest.approx(4 * s1["height"])


def test_motion_stereo_uses_the_wide_baseline():
    model = ReconstructionErrorModel()
    s, p = depth_sigma_m(_meta(4.0, True), model)          # a full-scale truck 15.8 m away, wide pairs
    z = 528 * 0.12 / 4.0
    assert p["geometry"]["motion_stereo"] and p["e_z_m_per_px"] == pytest.approx(z / (528 * 0.11))
    assert s["length"] == pytest.approx(model.wide_px["length"] * z / (528 * 0.11))


def test_run_json_without_geometry_gives_no_term():
    assert depth_sigma_m({"counts": {}})[0] is None
    assert depth_sigma_m(_meta(float("nan"), False))[0] is None
    with pytest.raises(ConfigError):
        ReconstructionErrorModel(rig_px={"length": -1.0, "width": 0.1, "height": 0.1})


def test_measure_combines_measurement_floor_and_depth_in_quadrature():
    values = {"length": 10.0, "width": 2.5, "height": 4.0}
    meas = {"length": 0.03, "width": 0.01, "height": 0.02}
    rel = {"length": 0.003, "width": 0.01, "height": 0.005}
    depth = {"length": 0.04, "width": 0.02, "height": 0.0}
    total, parts = combined_uncertainty(values, meas, rel, depth)
    assert total["width"] == pytest.approx(math.sqrt(0.01 ** 2 + 0.025 ** 2 + 0.02 ** 2))
    assert total["height"] == pytest.approx(math.hypot(0.02, 0.02))
    assert parts["reconstruction_depth_m"] == depth
    # Without the depth term: as before.
    assert combined_uncertainty(values, meas, rel)[1].get("reconstruction_depth_m") is None
    with pytest.raises(ConfigError):
        combined_uncertainty(values, meas, rel, {"length": float("nan"), "width": 0, "height": 0})
