"""``run --resume`` reuses a reconstruction only when every input that made it is the same and its files are intact."""

from __future__ import annotations

import json
from dataclasses import replace

from stereo_recon.core.atomic import write_json_atomic
from stereo_recon.motion_stereo import MotionStereoConfig
from stereo_recon.app.pipeline import input_fingerprint, output_record, reuse_problem
from stereo_recon.core.paths import RunPaths
from stereo_recon.reconstruct import ReconstructConfig


def _finished_run(tmp_path, video, calib, rcfg) -> RunPaths:
    paths = RunPaths(tmp_path / "out")
    paths.root.mkdir()
    for name in ("cloud.ply", "poses.txt", "run.json"):
        (paths.root / name).write_bytes(name.encode() * 100)
    write_json_atomic(paths.summary, {"fingerprint": input_fingerprint(video, calib, rcfg),
                                      "outputs": output_record(paths.root, ("cloud.ply", "poses.txt", "run.json"))})
    return paths


def _inputs(tmp_path):
    video, calib = tmp_path / "v.avi", tmp_path / "SN1.conf"
    video.write_bytes(b"frames")
    calib.write_text("[STEREO]\nBaseline=120\n")
    return video, calib


def test_resume_reuses_only_identical_inputs(tmp_path):
    video, calib = _inputs(tmp_path)
    rcfg = ReconstructConfig()
    paths = _finished_run(tmp_path, video, calib, rcfg)
    assert reuse_problem(paths, input_fingerprint(video, calib, rcfg)) is None
    why = reuse_problem(paths, input_fingerprint(video, calib, replace(rcfg, motion_stereo=MotionStereoConfig())))
    assert why.startswith("reconstruction parameters changed: motion_stereo")
    assert "depth_max_m (None -> 10.0)" in reuse_problem(paths, input_fingerprint(video, calib, replace(rcfg, depth_max_m=10.0)))
    calib.write_text("[STEREO]\nBaseline=132\n")  # baseline +10 %
    assert reuse_problem(paths, input_fingerprint(video, calib, rcfg)).startswith("the calibration changed")
    video.write_bytes(b"other frames")
    assert "the video changed" in reuse_problem(paths, input_fingerprint(video, calib, rcfg))


def test_resume_notices_inline_calibration_and_version(tmp_path):
    video, _ = _inputs(tmp_path)
    rcfg = ReconstructConfig()
    paths = _finished_run(tmp_path, video, "500,500,320,240,0.12", rcfg)
    assert reuse_problem(paths, input_fingerprint(video, "500,500,320,240,0.12", rcfg)) is None
    assert "calibration changed" in reuse_problem(paths, input_fingerprint(video, "500,500,320,240,0.132", rcfg))
    job = json.loads(paths.summary.read_text())
    job["fingerprint"]["version"] = "0.0.1"
    paths.summary.write_text(json.dumps(job))
    assert "program version changed (0.0.1 ->" in reuse_problem(paths, input_fingerprint(video, "500,500,320,240,0.12", rcfg))


def test_resume_detects_truncated_or_replaced_outputs(tmp_path):
    video, calib = _inputs(tmp_path)
    rcfg = ReconstructConfig()
    fp = input_fingerprint(video, calib, rcfg)
    paths = _finished_run(tmp_path, video, calib, rcfg)
    data = paths.cloud.read_bytes()
    paths.cloud.write_bytes(data[: len(data) // 2])
    assert "cloud.ply is 450 bytes, the run wrote 900 (truncated or modified)" in reuse_problem(paths, fp)
    paths.cloud.write_bytes(data[::-1])
    assert "cloud.ply is not the file the run wrote" in reuse_problem(paths, fp)
    paths.cloud.unlink()
    assert "cloud.ply is missing" in reuse_problem(paths, fp)
    paths.summary.unlink()
    assert "no record of an earlier run" in reuse_problem(paths, fp)
