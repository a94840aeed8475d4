"""End to end on the bundled sample: `stereo-recon run` with no flags measures the truck within 2 % of truth (the
width's 2 % is a strict known failure on the 2026-11-26 machine: see test_sample_width_within_two_percent)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from measure.schema import read_measurement  # every measurement.json a test writes is checked against its schema
from stereo_recon.app.cli import main

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data"


TRUTH = json.loads((SAMPLE / "truth.json").read_text())
_MEASURED: dict = {}   # the sample's measurement, once per session (the run takes ~15 s)


def _sample_error(dim: str, m: dict) -> tuple[float, str]:
    err = abs(m[f"{dim}_m"] - TRUTH[f"{dim}_m"]) / TRUTH[f"{dim}_m"]
    return err, f"{dim}: measured {m[f'{dim}_m']:.4f} m, truth {TRUTH[f'{dim}_m']:.4f} m ({100 * err:.2f} %)"


@pytest.mark.slow
def test_run_on_sample_data_matches_truth(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the default output folder is ./out/run
    assert main(["run"]) == 0
    out = tmp_path / "out" / "run"
    for name in ("cloud.ply", "poses.txt", "run.json", "measurement.json", "report.html", "job.json"):
        assert (out / name).is_file(), name
    m = read_measurement(out)
    _MEASURED.update(m)
    for dim in ("length", "height"):   # the width: test_sample_width_within_two_percent
        err, text = _sample_error(dim, m)
        assert err < 0.02, text
    # The report's evidence: source video and calibration with sha256, a keyframe with the box; a log of the run.
    assert m["recording"]["video"]["sha256"] and m["recording"]["calib"]["sha256"] and "keyframe" in m["recording"]
    assert (out / "keyframe.jpg").is_file() and (out / "log.txt").is_file()
    html = (out / "report.html").read_text(encoding="utf-8")
    assert m["recording"]["video"]["sha256"] in html and "video.avi" in html
    # A model truck gets no legal verdict without a scale factor.
    assert m["verdict"]["overall"] == "not-applicable"
    printed = capsys.readouterr().out
    assert "length" in printed and "report" in printed


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "known (2026-11-26, issue 12): on the AMD EPYC machine of that date the sample's width reads -2.31 % (-2.45 % "
    "with OPENBLAS_CORETYPE unset), identically before and after that date's changes; it read -1.46 % on the "
    "2026-11-24 machine. The fused walls sit on the truth (median offsets +0.4 / -0.4 mm mid-wall, "
    "benchmarks/bench_error_budget.py); the peaks of the width's density lie ~4 mm inside each wall. Remove this "
    "mark when the width meets 2 % again; a machine where it does shows it as XPASS"))
def test_sample_width_within_two_percent(tmp_path, monkeypatch):
    if not _MEASURED:
        monkeypatch.chdir(tmp_path)
        assert main(["-q", "run"]) == 0
        _MEASURED.update(read_measurement(tmp_path / "out" / "run"))
    err, text = _sample_error("width", _MEASURED)
    assert err < 0.02, text


def test_run_with_missing_video_is_one_line_error(tmp_path, capsys):
    rc = main(["run", str(tmp_path / "nope.avi"), "--calib", str(SAMPLE / "rig.yaml"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and "\n" not in err and "nope.avi" in err
    assert not (tmp_path / "o").exists()
