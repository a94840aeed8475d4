"""Batch machinery: one failing job is reported and does not stop the others; same results locally and on Ray."""

from __future__ import annotations

import csv
import importlib.util
import json

import pytest

from stereo_recon.batch import Job, run_jobs, write_summary_csv
from stereo_recon.errors import ConfigError

# json.loads is a picklable, module-level function that returns a dict or raises: a stand-in for run_video.
GOOD = [Job(f"rec{i}", json.loads, (json.dumps({"length_m": 10.0 + i, "width_m": 2.5, "height_m": 3.9}),)) for i in range(3)]
BAD = Job("broken", json.loads, ("{not json",))


@pytest.mark.parametrize("workers", [1, 2])
def test_failed_job_does_not_stop_others(workers, tmp_path):
    results = run_jobs([GOOD[0], BAD, GOOD[1], GOOD[2]], workers=workers)
    assert [r["name"] for r in results] == ["rec0", "broken", "rec1", "rec2"]
    assert [r["ok"] for r in results] == [True, False, True, True]
    assert "JSONDecodeError" in results[1]["error"]
    assert [r["length_m"] for r in results if r["ok"]] == [10.0, 11.0, 12.0]
    path = write_summary_csv(tmp_path / "summary.csv", results)
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 4 and rows[1]["ok"] == "False" and rows[2]["length_m"] == "11.0"


def test_unknown_executor_is_a_config_error():
    with pytest.raises(ConfigError, match="executor"):
        run_jobs(GOOD, executor="slurm")


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is an optional extra and is not installed")
def test_ray_executor_matches_local():
    local = run_jobs([GOOD[0], BAD, GOOD[1]], workers=1)
    remote = run_jobs([GOOD[0], BAD, GOOD[1]], workers=2, executor="ray")
    assert [(r["name"], r["ok"], r.get("length_m")) for r in remote] == [(r["name"], r["ok"], r.get("length_m")) for r in local]
