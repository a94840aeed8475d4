"""Batch machinery: one failing job is reported and does not stop the others; a typed summary.csv that
``--resume`` merges into; job folders that travel between a Ray node and the driver (without Ray)."""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from pathlib import Path

import pytest

from stereo_recon.app.batch import SUMMARY_COLUMNS, run_jobs, write_summary_csv
from stereo_recon.app.jobs import Job, substitute_paths
from stereo_recon.app.batch_ray import _input_state, land, run_on_node
from stereo_recon.core.errors import ConfigError

# json.loads is a picklable, module-level function that returns a dict or raises: a stand-in for run_video.
GOOD = [Job(f"rec{i}", json.loads, (json.dumps({"length_m": 10.0 + i, "width_m": 2.5, "height_m": 3.9}),)) for i in range(3)]
BAD = Job("broken", json.loads, ("{not json",))


@pytest.mark.parametrize("workers", [1, 2])
def test_failed_job_does_not_stop_others(workers, tmp_path):
    seen = []
    results = run_jobs([GOOD[0], BAD, GOOD[1], GOOD[2]], workers=workers, progress=lambda r: seen.append(r["name"]))
    assert [r["name"] for r in results] == ["rec0", "broken", "rec1", "rec2"]
    assert sorted(seen) == sorted(r["name"] for r in results)  # every job reported once, as it finished
    assert [r["ok"] for r in results] == [True, False, True, True]
    assert "JSONDecodeError" in results[1]["error"]
    assert [r["length_m"] for r in results if r["ok"]] == [10.0, 11.0, 12.0]
    path = write_summary_csv(tmp_path / "summary.csv", results)
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 4 and rows[1]["ok"] == "false" and rows[2]["ok"] == "true"
    assert rows[2]["length_m"] == "11.000" and rows[1]["length_m"] == ""


def test_unknown_executor_is_a_config_error():
    with pytest.raises(ConfigError, match="executor"):
        run_jobs(GOOD, executor="slurm")


def _job_result(tmp_path: Path, name: str, length_m: float, ok: bool = True, **measurement) -> dict:
    """A finished job's result dict and its output folder with measurement.json / run.json."""
    out = tmp_path / name
    out.mkdir(parents=True, exist_ok=True)
    (out / "measurement.json").write_text(json.dumps({"length_m": length_m, **measurement}))
    (out / "run.json").write_text(json.dumps({"inputs": {"video": {"path": f"/data/{name}.avi", "sha256": "ab" * 32}}}))
    verdict = {"overall": "over-limit", "regulation": {"name": "cn-2016-62"}, "vehicle_class": "any"}
    return {"name": name, "video": f"/data/{name}.avi", "ok": ok, "length_m": length_m, "width_m": 2.5501, "height_m": 4.0,
            "uncertainty_m": {"length": 0.01234, "width": 0.01, "height": 0.02}, "verdict": verdict,
            "out_dir": str(out), "time_s": 12.345, "host": "node-1", "error": None}


def test_summary_csv_is_typed_and_complete(tmp_path):
    dq = {"ok": False, "checks": [{"name": "ground", "status": "fail", "detail": "no ground plane"}]}
    results = [_job_result(tmp_path, "truckA", 18.31749, warnings=["roof seen at 17°", "thin\nwalls"], data_quality=dq),
               _job_result(tmp_path, "truckB", 12.0)]  # an older measurement.json without data_quality
    rows = list(csv.DictReader(write_summary_csv(tmp_path / "summary.csv", results).open(newline="")))
    assert tuple(rows[0]) == SUMMARY_COLUMNS and all(c.endswith("_m") for c in SUMMARY_COLUMNS if "length" in c)
    a, b = rows
    assert (a["video"], a["ok"], a["length_m"], a["width_m"], a["u_length_m"]) == ("/data/truckA.avi", "true", "18.317", "2.550", "0.012")
    assert (a["regulation"], a["verdict"], a["vehicle_class"]) == ("cn-2016-62", "over-limit", "any")
    assert a["data_quality_ok"] == "false" and b["data_quality_ok"] == ""
    assert a["warnings"] == "roof seen at 17°; thin walls" and b["warnings"] == ""
    assert a["video_sha256"] == "ab" * 32 and a["time_s"] == "12.3" and a["host"] == "node-1"


def test_resume_merges_rows_by_video(tmp_path):
    first = [_job_result(tmp_path, n, 10.0) for n in ("truckA", "truckB", "truckC")]
    write_summary_csv(tmp_path / "summary.csv", first)
    again = [_job_result(tmp_path, "truckB", 11.0), _job_result(tmp_path, "truckD", 13.0)]
    rows = list(csv.DictReader(write_summary_csv(tmp_path / "summary.csv", again, merge=True).open(newline="")))
    assert [(Path(r["video"]).stem, r["length_m"]) for r in rows] == \
           [("truckA", "10.000"), ("truckB", "11.000"), ("truckC", "10.000"), ("truckD", "13.000")]
    rows = list(csv.DictReader(write_summary_csv(tmp_path / "summary.csv", again).open(newline="")))
    assert len(rows) == 2  # without --resume the summary is this run's


@dataclass(frozen=True)
class _Cfg:
    measure_config: Path | None = None


def test_substitute_paths_reaches_into_dataclasses():
    cfg = _Cfg(measure_config=Path("/driver/m.toml"))
    out = substitute_paths(("/driver/v.avi", cfg, {"k": "/driver/v.avi"}, 3), {"/driver/v.avi": "/node/v.avi", "/driver/m.toml": "/node/m.toml"})
    assert out == ("/node/v.avi", _Cfg(Path("/node/m.toml")), {"k": "/node/v.avi"}, 3)


def write_report(video: str, out_dir: str) -> dict:
    """A stand-in job: reads its input, writes an output folder that records both paths (as the pipeline does)."""
    out = Path(out_dir)
    out.mkdir(parents=True)
    (out / "cloud.ply").write_bytes(Path(video).read_bytes()[::-1])
    (out / "measurement.json").write_text(json.dumps({"input_path": str(out / "cloud.ply"), "video": video}, indent=2))
    return {"video": video, "out_dir": str(out), "length_m": 1.0}


def test_job_folder_travels_back_to_the_driver(tmp_path):
    video = tmp_path / "rec" / "trück.avi"  # non-ASCII: JSON escapes it
    video.parent.mkdir()
    video.write_bytes(b"frames" * 100)
    out = tmp_path / "driver-out" / "trück"
    (out).mkdir(parents=True)
    (out / "keep.txt").write_text("an earlier file the job does not write")
    job = Job("trück", write_report, (str(video), str(out)), inputs=(str(video),), outputs=(str(out),))
    states = {str(video): _input_state(str(video))}

    # A node whose copy differs from the driver's asks for the input first ('auto').
    lacking = {str(video): ("file", states[str(video)][1] + 1)}
    assert run_on_node(job, lacking, "auto", ()) == {"missing": [str(video)]}
    assert "not on node" in run_on_node(job, lacking, "never", ())["result"]["error"]

    from stereo_recon.app.batch_ray import _pack

    reply = run_on_node(job, states, "auto", (str(video),), _pack(str(video)))  # shipped: runs on its own copy
    assert reply["result"]["ok"] and reply["result"]["video"] != str(video)
    result = land(reply)
    assert result["video"] == str(video) and result["out_dir"] == str(out)
    assert (out / "cloud.ply").read_bytes() == video.read_bytes()[::-1]
    m = json.loads((out / "measurement.json").read_text())
    assert m == {"input_path": str(out / "cloud.ply"), "video": str(video)}  # the driver's paths, JSON-escaped
    assert "\\u00fc" in (out / "measurement.json").read_text()
    assert (out / "keep.txt").is_file()  # merged like a local run, not replaced
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no staging folder left
    assert os.listdir(out.parent) == ["trück"]


def test_ray_error_with_a_remote_traceback_is_one_line():
    from stereo_recon.app.batch_ray import _ray_error_line

    # The text Ray 2.60 raised on a node whose stereo-recon lacked the module (seen on a loopback cluster).
    cause = RuntimeError(
        "The remote function failed to import on the worker. This may be because needed library dependencies are "
        "not installed in the worker environment or cannot be found from sys.path ['/tmp/x']:\n\n"
        "Traceback (most recent call last):\n  File \"/ray/_private/function_manager.py\", line 314, in fetch\n"
        "    function = pickle.loads(serialized_function)\nModuleNotFoundError: No module named 'stereo_recon.app.batch_ray'\n")
    err = Exception("RayTaskError")
    err.cause = cause
    line = _ray_error_line(err)
    assert "\n" not in line and "Traceback" not in line and "sys.path" not in line
    assert line.startswith("ModuleNotFoundError: No module named 'stereo_recon.app.batch_ray'")
    assert "installed on every node" in line


def test_batch_help_has_description_example_and_every_default(capsys):
    import re

    from stereo_recon.app.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["batch", "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "summary.csv" in text and "examples:" in text and "stereo-recon batch " in text and "RAY_ADDRESS" in text
    # Each option's help (up to the next option) names its default, or says it is required.
    options = re.split(r"\n  (?=-)", text.split("options:", 1)[1].split("examples:", 1)[0])[1:]
    assert len(options) > 15
    for block in options:
        if block.startswith("-h"):
            continue
        flat = " ".join(block.split())
        assert "default" in flat or "(required)" in flat, flat


def test_scratch_of_a_killed_worker_is_removed_by_the_next_job(tmp_path, monkeypatch):
    import subprocess
    import sys
    import tempfile

    from stereo_recon.app.batch_ray import _scratch_dir

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    left = tmp_path / f"stereo-recon-job-{int(dead.stdout)}-x1"
    (left / "out").mkdir(parents=True)
    mine = tmp_path / f"stereo-recon-job-{os.getpid()}-x2"  # a job still running in a live process
    mine.mkdir()
    fresh = _scratch_dir()
    assert fresh.is_dir() and fresh.name.startswith(f"stereo-recon-job-{os.getpid()}-")
    assert not left.exists() and mine.exists()


def test_address_without_ray_executor_is_one_line_error(tmp_path, capsys):
    from stereo_recon.app.cli import main

    rc = main(["batch", str(tmp_path / "v.avi"), "--calib", "1,1,1,1,0.1", "--out", str(tmp_path / "o"), "--address", "auto"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "--address" in err and "--executor ray" in err
    assert not (tmp_path / "o").exists()


def test_ray_options_are_checked_before_anything_runs(monkeypatch):
    import sys

    from stereo_recon.app.batch_ray import RayOptions

    with pytest.raises(ConfigError, match="--cpus-per-job"):
        run_jobs(GOOD, executor="ray", ray_options=RayOptions(cpus_per_job=0))
    with pytest.raises(ConfigError, match="--ship-inputs"):
        run_jobs(GOOD, executor="ray", ray_options=RayOptions(ship_inputs="sometimes"))
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the extra were not installed
    with pytest.raises(ConfigError, match=r"Ray is not installed \(pip install"):
        run_jobs(GOOD, executor="ray")
