"""The Table 2 benchmark's bookkeeping: truck ranges, error table, averages, verdict check (no rendering)."""

from __future__ import annotations

import json

import pytest

from stereo_recon.app.bench import (PAPER_AVERAGE_ERROR_PCT, bench_summary, parse_truck_range, table_markdown,
                                verdict_matches, write_bench)
from stereo_recon.core.errors import ConfigError


def _result(name, truth, measured, t=10.0):
    err = {d: 100 * abs(measured[i] - truth[i]) / truth[i] for i, d in enumerate(("length", "width", "height"))}
    err["overall"] = sum(err.values()) / 3
    return {"ok": True, "name": name, "truth": dict(zip(("length", "width", "height"), truth)),
            "length_m": measured[0], "width_m": measured[1], "height_m": measured[2], "error_pct": err, "time_s": t}


def test_parse_truck_range():
    assert parse_truck_range("1-3,7, 9-10") == [1, 2, 3, 7, 9, 10]
    for bad in ("0-3", "19-21", "a-b", ""):
        with pytest.raises(ConfigError):
            parse_truck_range(bad)


def test_table_and_summary_average_the_per_truck_errors(tmp_path):
    results = [_result("table2:1", (1.0, 0.2, 0.3), (1.01, 0.2, 0.3), 10.0),        # L +1 %
               _result("table2:2", (2.0, 0.4, 0.4), (2.0, 0.39, 0.404), 30.0),      # W -2.5 %, H +1 %
               {"ok": False, "name": "table2:3", "error": "StageError: poses"}]
    s = bench_summary(results)
    assert (s["n_ok"], s["n_failed"]) == (2, 1)
    assert s["average_error_pct"]["length"] == pytest.approx(0.5)
    assert s["average_error_pct"]["width"] == pytest.approx(1.25)
    assert s["average_error_pct"]["height"] == pytest.approx(0.5)
    assert s["worst_single_dimension_error_pct"] == pytest.approx(2.5)
    assert s["median_time_s"] == pytest.approx(20.0)
    md = table_markdown(results)
    assert "| table2:3 | failed: StageError: poses" in md
    assert "| **Average (ours)** | | | | | | | 0.50% | 1.25% | 0.50% | 0.75% | |" in md
    assert f"{PAPER_AVERAGE_ERROR_PCT['overall']:.2f}%" in md
    md_path, js_path = write_bench(tmp_path, results)
    assert md_path.read_text() == md
    assert json.loads(js_path.read_text())["summary"]["n_ok"] == 2


def test_verdict_matches_truth_vocabulary():
    assert verdict_matches("over-limit", "over")
    assert verdict_matches("within-limits", "within")
    assert not verdict_matches("within-limits", "undecided")
    assert not verdict_matches("over-limit", "within")
    assert verdict_matches(None, "over") is None


def _verdict(height_m, u_m, overall, status, k=2.0):
    return {"overall": overall, "k_sigma": k, "dimensions": {
        "length": {"value_m": 12.0, "uncertainty_m": 0.01, "limit_m": 18.1, "verdict": "within"},
        "height": {"value_m": height_m, "uncertainty_m": u_m, "limit_m": 4.0, "verdict": status}}}


@pytest.mark.parametrize(
    "true_h, expected, verdict, right",
    [
        # a truck built exactly to the 4.0 m limit, measured 3.998 +- 2 x 6 mm: undecided is the honest answer
        (4.0, "within-limits", _verdict(3.998, 0.006, "undecided", "undecided"), True),
        # 3.9 m true, measured 3.99 +- 2 x 10 mm: undecided although the truth is 10 cm under: wrong
        (3.9, "within-limits", _verdict(3.99, 0.010, "undecided", "undecided"), False),
        (3.9, "within-limits", _verdict(3.91, 0.010, "within", "within"), True),
        # "within" for a truck that is over, even by a little: wrong
        (4.01, "over-limit", _verdict(3.97, 0.010, "within", "within"), False),
        (4.3, "over-limit", _verdict(4.29, 0.010, "over", "over"), True),
        # just over, within the uncertainty: undecided is right
        (4.005, "over-limit", _verdict(3.999, 0.006, "undecided", "undecided"), True),
    ],
)
def test_verdict_is_judged_per_dimension_against_the_truth(true_h, expected, verdict, right):
    assert verdict_matches(expected, verdict, {"length": 12.0, "width": 2.5, "height": true_h}) is right


@pytest.mark.parametrize(
    "true_h, expected, verdict, strict, sound",
    [
        # 2.38 m-like knife edge on the height: truth 3.83, 0.170 m = 2.01 sigma under the limit, measured 3.872 +- 2 x
        # 0.0845: the limit lies inside the interval (undecided), and so does the truth: wrong by the letter, sound
        (3.83, "within-limits", _verdict(3.872, 0.0845, "undecided", "undecided"), False, True),
        # undecided although its own interval misses the truth (3.9 true, 3.99 +- 2 x 0.01): wrong either way
        (3.9, "within-limits", _verdict(3.99, 0.010, "undecided", "undecided"), False, False),
        # a confident verdict on the wrong side stays wrong, whatever its interval
        (4.01, "over-limit", _verdict(3.97, 0.030, "within", "within"), False, False),
        (4.3, "over-limit", _verdict(4.29, 0.010, "over", "over"), True, True),
    ],
)
def test_an_undecided_verdict_is_sound_when_its_interval_holds_the_truth(true_h, expected, verdict, strict, sound):
    truth = {"length": 12.0, "width": 2.5, "height": true_h}
    assert verdict_matches(expected, verdict, truth) is strict
    assert verdict_matches(expected, verdict, truth, undecided="interval-covers-truth") is sound
    with pytest.raises(ValueError, match="undecided"):
        verdict_matches(expected, verdict, truth, undecided="maybe")


def test_study_sweeps_the_paper_values_and_scores_our_default(tmp_path):
    """The d_h study re-measures clouds over 0.06-0.08 m and adds our scale-free default as its own row."""
    import numpy as np

    from stereo_recon.core.cloud_io import write_cloud
    from measure.synthetic_cloud import MODEL_TRUCK, make_truck_scene
    from stereo_recon.app.bench import run_study

    pts, truth = make_truck_scene(MODEL_TRUCK, rng=np.random.default_rng(3))
    path = write_cloud(tmp_path / "truck.ply", pts)
    res = run_study("ground-thickness", [("t", path, truth)], tmp_path, up_hints={"t": [0.0, 0.0, 1.0]})
    assert [r["value_m"] for r in res["rows"]] == pytest.approx(list(np.arange(0.06, 0.0801, 0.002)))
    d = res["default"]
    assert d["value_m"] is None and len(d["resolved_m"]) == 1 and d["resolved_m"][0] > 0  # from the point spacing
    assert d["mean_mse_m2"] is not None and d["mean_mse_m2"] < 1e-3  # model truck measured within ~3 cm overall
    md = (tmp_path / "study-ground-thickness.md").read_text()
    assert "default (scale-free" in md and "optimum:" in md
    assert (tmp_path / "study-ground-thickness.png").is_file()
