"""End to end on the bundled sample: `stereo-recon run` with no flags measures the truck within 2 % of truth."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from measure.schema import read_measurement  # every measurement.json a test writes is checked against its schema
from stereo_recon.app.cli import main

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data"


TRUTH = json.loads((SAMPLE / "truth.json").read_text())


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
    for dim in ("length", "width", "height"):
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


def test_run_with_missing_video_is_one_line_error(tmp_path, capsys):
    rc = main(["run", str(tmp_path / "nope.avi"), "--calib", str(SAMPLE / "rig.yaml"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and "\n" not in err and "nope.avi" in err
    assert not (tmp_path / "o").exists()
