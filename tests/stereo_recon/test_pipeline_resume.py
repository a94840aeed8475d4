"""``run --resume`` reuses a reconstruction only when the video and the reconstruction settings match."""

from __future__ import annotations

import json
from dataclasses import asdict, replace

from stereo_recon.manifest import sha256_file, to_jsonable
from stereo_recon.motion_stereo import MotionStereoConfig
from stereo_recon.pipeline import RunPaths, _stage_done
from stereo_recon.reconstruct import ReconstructConfig


def _finished_run(tmp_path, video, rcfg) -> RunPaths:
    paths = RunPaths(tmp_path / "out")
    paths.root.mkdir()
    paths.cloud.write_bytes(b"ply\n")
    meta = {"inputs": {"video": {"path": str(video), "sha256": sha256_file(video)}},
            "parameters": to_jsonable({"reconstruct": asdict(rcfg)})}
    paths.run_json.write_text(json.dumps(meta))
    return paths


def test_resume_needs_same_video_and_settings(tmp_path):
    video = tmp_path / "v.avi"
    video.write_bytes(b"frames")
    rcfg = ReconstructConfig()
    paths = _finished_run(tmp_path, video, rcfg)
    assert _stage_done(paths, video, rcfg)
    assert not _stage_done(paths, video, replace(rcfg, motion_stereo=MotionStereoConfig()))
    assert not _stage_done(paths, video, replace(rcfg, depth_max_m=10.0))
    video.write_bytes(b"other frames")
    assert not _stage_done(paths, video, rcfg)
