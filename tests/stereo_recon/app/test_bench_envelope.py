"""The random-envelope bench's bookkeeping: failures, error statistics, coverage, verdicts, factor splits, outputs."""

import json

import numpy as np
import pytest

from stereo_recon.app.bench import envelope_row, envelope_summary, write_envelope
from stereo_recon.synthetic.envelope import draw_spec


def _result(spec, rel_err=(0.01, -0.02, 0.005), sigma_rel=(0.006, 0.006, 0.006), ok=True, error=None, data_quality=None, verdict=None):
    t = spec.truck
    if not ok:
        return {"name": spec.name, "ok": False, "error": error, "time_s": 1.0}
    true = (t.length_m, t.width_m, t.height_m)
    meas = [v * (1 + e) for v, e in zip(true, rel_err)]
    return {"name": spec.name, "ok": True, "error": None, "time_s": 2.0, "out_dir": "x", "length_m": meas[0], "width_m": meas[1],
            "height_m": meas[2], "uncertainty_m": dict(zip(("length", "width", "height"), (v * s for v, s in zip(true, sigma_rel)))),
            "verdict": verdict, "data_quality": data_quality}


def _spec(scale):
    for i in range(100):
        s = draw_spec(1, i)
        if s.truck.scale == scale:
            return s
    raise AssertionError


def test_rows_count_failures_refusals_and_coverage():
    m = _spec("model")
    ok = envelope_row(_result(m), m)
    assert ok["ok"] and ok["failure_reason"] is None
    assert ok["error_pct"]["length"] == pytest.approx(1.0) and ok["error_pct"]["width"] == pytest.approx(-2.0)
    # |error| <= 2 sigma: length (1 % vs 1.2 %) and height are covered, width (2 % vs 1.2 %) is not.
    assert ok["within_2sigma"] == {"length": True, "width": False, "height": True}
    crashed = envelope_row(_result(m, ok=False, error="measure: no ground plane (...)"), m)
    assert not crashed["ok"] and crashed["failure_reason"].startswith("measure: no ground plane")
    dq = {"ok": False, "checks": [{"name": "two-trucks", "status": "fail", "detail": "two equally plausible trucks"}]}
    refused = envelope_row(_result(m, data_quality=dq), m)
    assert not refused["ok"] and "two equally plausible trucks" in refused["failure_reason"]
    nan = _result(m)
    nan["height_m"] = float("nan")
    assert envelope_row(nan, m)["failure_reason"] == "not measured: height"


def test_summary_statistics_and_factor_splits():
    specs = [draw_spec(2, i) for i in range(6)]
    errs = [(0.01, -0.02, 0.005), (0.0, 0.03, -0.01), (0.002, 0.001, -0.004), (-0.01, 0.0, 0.02), (0.005, -0.005, 0.0)]
    rows = [envelope_row(_result(s, e), s) for s, e in zip(specs, errs)]
    rows.append(envelope_row(_result(specs[5], ok=False, error="reconstruct: boom"), specs[5]))
    s = envelope_summary(rows)
    all_errs = 100 * np.array(errs)
    o = s["dimensions"]["overall"]
    assert s["draws"] == 6 and s["failed_draws"] == 1
    assert o["failed"] == 3 and o["failure_rate"] == pytest.approx(3 / 18)
    assert o["mean_abs_pct"] == pytest.approx(np.abs(all_errs).mean())
    assert o["p90_abs_pct"] == pytest.approx(np.percentile(np.abs(all_errs), 90))
    assert o["max_abs_pct"] == pytest.approx(3.0) and o["bias_pct"] == pytest.approx(all_errs.mean())
    assert o["within_2sigma"] == pytest.approx(np.mean(np.abs(all_errs) <= 1.2))
    assert s["dimensions"]["width"]["median_abs_pct"] == pytest.approx(np.median(np.abs(all_errs[:, 1])))
    # Every draw lands in exactly one level of every factor.
    for name, levels in s["by_factor"].items():
        assert sum(v["n"] for v in levels.values()) == 18, name


def test_full_scale_verdicts_are_judged_against_the_truth():
    f = _spec("full")
    t = f.truck
    limits = {"length": 18.1, "width": 2.55, "height": 4.0}
    true = {"length": t.length_m, "width": t.width_m, "height": t.height_m}
    exact = {d: {"value_m": true[d], "uncertainty_m": 0.01, "limit_m": limits[d],
                 "verdict": "over" if true[d] > limits[d] else "within"} for d in limits}
    overall = "over" if any(true[d] > limits[d] for d in limits) else "within"
    right = envelope_row(_result(f, (0, 0, 0), verdict={"overall": overall, "dimensions": exact, "k_sigma": 2.0}), f)
    assert right["verdict_right"] is True and right["verdict_sound"] is True
    flipped = {d: {**e, "verdict": "within" if e["verdict"] == "over" else "over"} for d, e in exact.items()}
    wrong = envelope_row(_result(f, (0, 0, 0), verdict={"overall": "over" if overall == "within" else "within",
                                                          "dimensions": flipped, "k_sigma": 2.0}), f)
    assert wrong["verdict_right"] is False and wrong["verdict_sound"] is False
    failed = envelope_row(_result(f, ok=False, error="x"), f)
    assert failed["verdict_right"] is False and failed["verdict_sound"] is False
    s = envelope_summary([right, wrong, failed])
    assert s["verdicts"]["n_full_scale"] == 3 and s["verdicts"]["right"] == 1 and s["verdicts"]["sound"] == 1
    assert s["verdicts"]["wrong"] == [f.name] and s["verdicts"]["failed"] == [f.name]


def test_write_envelope_outputs(tmp_path):
    specs = [draw_spec(3, i) for i in range(4)]
    rows = [envelope_row(_result(s), s) for s in specs[:3]] + [envelope_row(_result(specs[3], ok=False, error="measure: no ground"), specs[3])]
    write_envelope(tmp_path, {"seed": 3, "count": 4, "max_frames": 40}, rows)
    data = json.loads((tmp_path / "envelope.json").read_text())
    assert len(data["draws"]) == 4 and data["summary"]["failed_draws"] == 1
    md = (tmp_path / "envelope.md").read_text()
    assert "TUNING seed" in md and "measure: no ground" in md and "## By factor" in md
    assert (tmp_path / "envelope.png").stat().st_size > 10_000


def test_random_bench_takes_the_ray_options(tmp_path, monkeypatch, capsys):
    # bench --random hands --address and the per-job resources to the executor, as Table 2 bench and batch do.
    from stereo_recon.app import batch
    from stereo_recon.app.cli import main

    seen = {}

    def fake_run_jobs(jobs, workers=1, executor="local", progress=None, ray_options=None):
        seen.update(executor=executor, ray_options=ray_options)
        return [{"name": j.name, "ok": False, "error": "not run", "time_s": 0.0} for j in jobs]

    monkeypatch.setattr(batch, "run_jobs", fake_run_jobs)
    main(["bench", "--random", "1", "--out", str(tmp_path / "b"), "--executor", "ray", "--address", "ray://head:10001",
          "--cpus-per-job", "2", "-q"])
    assert seen["executor"] == "ray"
    assert seen["ray_options"].address == "ray://head:10001" and seen["ray_options"].cpus_per_job == 2.0
    assert main(["bench", "--random", "1", "--out", str(tmp_path / "c"), "--address", "auto", "-q"]) == 2
    assert "only with --executor ray" in capsys.readouterr().err
