"""``run``, ``reconstruct``, ``batch``, ``bench`` and ``calib-check`` on bad or awkward input.

Each case asserts the exit code, the one-line message (no traceback) and what is or is not left on
disk. Plain mistakes are refused before any reconstruction; recordings that are readable but wrong
(swapped or identical eyes, a calibration of another size, an already rectified video, a cut file,
a static camera) are refused or reach the verdict through the data-quality gates. One real run of
the bundled sample is shared by the module (resume, determinism, a good folder kept intact).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from stereo_recon.app.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # tests/: shared helpers (importlib import mode)
from cli_outcome import folder_state, no_temp_left, refused  # noqa: E402
from sample_variants import SAMPLE_CONF, SAMPLE_VIDEO, read_pairs, rectified_pairs, write_video  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    """Short variants of the sample: swapped eyes, identical eyes, a static camera, rectified, cut in half."""
    d = tmp_path_factory.mktemp("videos")
    pairs = read_pairs(6, step=8)
    rect, calib_text = rectified_pairs(pairs[:3])
    data = SAMPLE_VIDEO.read_bytes()
    (d / "half.avi").write_bytes(data[: len(data) // 2])
    (d / "not_video.avi").write_text("hello")
    return {"swapped": write_video(d / "swapped.avi", [(r, l) for l, r in pairs]),
            "identical": write_video(d / "identical.avi", [(l, l) for l, _ in pairs]),
            "static": write_video(d / "static.avi", [pairs[0]] * 16),
            "rectified": write_video(d / "rectified.avi", rect), "rectified_calib": calib_text,
            "half": d / "half.avi", "not_video": d / "not_video.avi"}


@pytest.fixture(scope="module")
def rigs(tmp_path_factory):
    """Calibration files: a .conf with fx = 0, one with the baseline +10 %, 1920x1080 rigs (exact, misfit)."""
    from calib.io import load_rig, save_rig

    d = tmp_path_factory.mktemp("rigs")
    text = SAMPLE_CONF.read_text()
    (d / "fx0.conf").write_text("\n".join("fx=0" if line.startswith("fx=") else line for line in text.splitlines()))
    lines = []
    for line in text.splitlines():
        if line.startswith("Baseline="):
            line = f"Baseline={float(line.split('=')[1]) * 1.1!r}"
        lines.append(line)
    (d / "SN28000001.conf").write_text("\n".join(lines))
    rig = load_rig(SAMPLE_CONF, image_size=(1280, 720)).scaled((1920, 1080))
    save_rig(rig, d / "fhd.yaml")
    a = np.radians(1.0)   # the right eye turned by 1 deg about x: rows 9 px apart after rectification
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    save_rig(replace(rig, R=Rx @ rig.R), d / "fhd_misfit.yaml")
    return {"fx0": d / "fx0.conf", "baseline110": d / "SN28000001.conf", "fhd": d / "fhd.yaml",
            "fhd_misfit": d / "fhd_misfit.yaml"}


@pytest.fixture(scope="module")
def good_run(tmp_path_factory):
    """One real run of the bundled sample: (out folder, its file hashes, measurement.json bytes)."""
    out = tmp_path_factory.mktemp("run") / "out"
    assert main(["-q", "run", "--out", str(out)]) == 0
    return out, folder_state(out), (out / "measurement.json").read_bytes()


# ---- options, files, tables, configs: refused before any work ---------------------------------------

RUN_BAD = [
    (["--scale", "nan"], "--scale nan"), (["--scale", "inf"], "--scale inf"), (["--scale", "0"], "--scale 0"),
    (["--regulation", "BAD"], "unknown regulation"), (["--vehicle-class", "bogus"], "unknown vehicle class 'bogus'"),
    (["--reconstruction-sigma-pct", "nan,1,1"], "--reconstruction-sigma-pct"),
    (["--calib", "0,500,640,360,0.12"], "fx and fy must be > 0"),
    (["--calib", "/nonexistent/SN1.conf"], "file not found"),
]


@pytest.mark.parametrize("argv, pattern", RUN_BAD)
def test_run_refuses_bad_option_before_any_work(tmp_path, capsys, argv, pattern):
    out = tmp_path / "out"
    calib = [] if "--calib" in argv else ["--calib", SAMPLE_CONF]
    refused(capsys, ["run", SAMPLE_VIDEO, *calib, "--out", out, *argv], pattern)
    assert not out.exists()
    no_temp_left(tmp_path)


def test_run_refuses_bad_config_file_naming_it(tmp_path, capsys):
    cfg = tmp_path / "measure.yaml"
    cfg.write_text("eps_m: 0.05\nnot_a_key: 2\n")
    refused(capsys, ["run", "--out", tmp_path / "out", "--config", cfg], f"{cfg}: unknown key(s) not_a_key")
    assert not (tmp_path / "out").exists()


def test_conf_with_zero_focal_names_file_and_section(tmp_path, capsys, rigs):
    refused(capsys, ["run", SAMPLE_VIDEO, "--calib", rigs["fx0"], "--out", tmp_path / "out"],
            f"{rigs['fx0']}: [LEFT_CAM_HD] fx = 0")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("which, pattern", [("missing", "no such file"), ("not_video", "cannot open as a video")])
def test_run_refuses_bad_video(tmp_path, capsys, videos, which, pattern):
    video = tmp_path / "none.avi" if which == "missing" else videos[which]
    refused(capsys, ["run", video, "--calib", SAMPLE_CONF, "--out", tmp_path / "out"], pattern)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["run", "reconstruct", "calib-check"])
@pytest.mark.parametrize("where", ["under_file", "proc"])
def test_output_path_problem_is_one_line(tmp_path, capsys, command, where):
    f = tmp_path / "file.txt"
    f.write_text("x")
    out = f / "out" if where == "under_file" else Path("/proc/x")
    if command == "calib-check":
        out = out.with_name("check.json")
    argv = {"run": ["run", SAMPLE_VIDEO, "--calib", SAMPLE_CONF, "--out", out],
            "reconstruct": ["reconstruct", SAMPLE_VIDEO, "--calib", SAMPLE_CONF, "--out", out],
            "calib-check": ["calib-check", SAMPLE_VIDEO, "--calib", SAMPLE_CONF, "--frames", "1", "--out", out]}[command]
    refused(capsys, argv, "is a file, not a folder" if where == "under_file" else "cannot write in /proc")
    assert f.read_text() == "x"
    no_temp_left(tmp_path)


RECONSTRUCT_BAD = [(["--fps", "0"], "--fps 0"), (["--fps", "nan"], "--fps nan"), (["--voxel-m", "nan"], "--voxel-m nan"),
                   (["--depth-min-m", "nan"], "--depth-min-m nan"), (["--depth-max-m", "inf"], "--depth-max-m inf"),
                   (["--step", "0"], "--step 0"), (["--frames", "9:3"], "STOP must be greater than START")]


@pytest.mark.parametrize("argv, pattern", RECONSTRUCT_BAD)
def test_reconstruct_refuses_bad_option(tmp_path, capsys, argv, pattern):
    out = tmp_path / "out"
    refused(capsys, ["reconstruct", SAMPLE_VIDEO, "--calib", SAMPLE_CONF, "--out", out, *argv], pattern)
    assert not out.exists()


@pytest.mark.parametrize("argv, pattern", [
    (["bench", "--workers", "0"], "--workers 0"), (["bench", "--frames", "0"], "--frames 0"),
    (["batch", str(SAMPLE_VIDEO), "--calib", str(SAMPLE_CONF), "--workers", "0"], "--workers 0"),
    (["batch", str(SAMPLE_VIDEO), "--calib", str(SAMPLE_CONF), "--regulation", "BAD"], "unknown regulation")])
def test_bench_and_batch_refuse_bad_numbers(tmp_path, capsys, argv, pattern):
    out = tmp_path / "out"
    refused(capsys, [*argv, "--out", out], pattern)
    assert not out.exists()


# ---- recordings that are readable but wrong ---------------------------------------------------------

def test_swapped_eyes_named(tmp_path, capsys, videos):
    refused(capsys, ["run", videos["swapped"], "--calib", SAMPLE_CONF, "--out", tmp_path / "out"], "eyes swapped")
    assert not (tmp_path / "out").exists()


def test_identical_eyes_named(tmp_path, capsys, videos):
    refused(capsys, ["run", videos["identical"], "--calib", SAMPLE_CONF, "--out", tmp_path / "out"],
            "both eyes identical")
    assert not (tmp_path / "out").exists()


def test_rectified_flag_on_raw_frames_refused(tmp_path, capsys):
    refused(capsys, ["run", SAMPLE_VIDEO, "--calib", SAMPLE_CONF, "--rectified", "--out", tmp_path / "out"],
            "the frames of")
    assert not (tmp_path / "out").exists()


def test_calibration_of_another_size_that_does_not_fit(tmp_path, capsys, rigs):
    err = refused(capsys, ["run", SAMPLE_VIDEO, "--calib", rigs["fhd_misfit"], "--out", tmp_path / "out"],
                  "the calibration is for 1920x1080, the video's eyes are 1280x720")
    assert "pass the calibration made for 1280x720" in err
    assert not (tmp_path / "out").exists()


def _source_and_rig(video, calib):
    from calib.io import parse_calib_arg
    from stereo_recon.reconstruct import ReconstructConfig
    from stereo_recon.video import open_stereo_source

    source = open_stereo_source(video)
    return source, parse_calib_arg(str(calib), image_size=source.eye_size), ReconstructConfig()


def test_calibration_of_another_size_that_fits_is_a_warning(rigs):
    from stereo_recon.quality import check_recording

    source, rig, rcfg = _source_and_rig(SAMPLE_VIDEO, rigs["fhd"])
    _, _, checks = check_recording(source, rig, rcfg, rigs["fhd"])
    by = {c["name"]: c for c in checks}
    assert by["calibration_size"]["status"] == "warn"
    assert "1920x1080" in by["calibration_size"]["detail"] and by["rectification"]["status"] == "pass"


def test_already_rectified_video_uses_the_rectified_camera(videos):
    from stereo_recon.quality import check_recording

    source, rig, rcfg = _source_and_rig(videos["rectified"], SAMPLE_CONF)
    rig2, _, checks = check_recording(source, rig, rcfg, SAMPLE_CONF)
    rect = {c["name"]: c for c in checks}["rectification"]
    assert rect["status"] == "warn" and "already rectified" in rect["detail"]
    fx, fy, cx, cy, b = (float(v) for v in videos["rectified_calib"].split(","))
    assert rig2.rectified and rig2.K1[0, 0] == pytest.approx(fx, abs=1e-3) and rig2.baseline_m == pytest.approx(b, abs=1e-6)
    assert f"--calib {rig2.K1[0, 0]:.3f},{rig2.K1[1, 1]:.3f}" in rect["detail"]


def test_cut_video_reports_the_real_decoded_count(videos, caplog):
    from stereo_recon.quality import checks_from_reconstruction
    from stereo_recon.video import open_stereo_source

    source = open_stereo_source(videos["half"])
    with caplog.at_level(logging.WARNING):
        n = sum(1 for _ in source)
    assert n < 0.7 * source.frame_count
    assert f"({n} frames decoded)" in caplog.text
    (c,) = checks_from_reconstruction({"source": source.describe(), "counts": {"frames_read": n, "bad_frames": []}})
    assert c["status"] == "fail" and f"only {n} of the 48 frames" in c["detail"]


@pytest.mark.slow
def test_cut_video_run_ends_undecided_with_the_reason(tmp_path, capsys, videos):
    out = tmp_path / "out"
    assert main(["-q", "run", str(videos["half"]), "--calib", str(SAMPLE_CONF), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    m = json.loads((out / "measurement.json").read_text())
    by = {c["name"]: c for c in m["data_quality"]["checks"]}
    assert by["frames_decoded"]["status"] == "fail" and "of the 48 frames" in by["frames_decoded"]["detail"]
    assert m["data_quality"]["ok"] is False and m["verdict"]["overall"] == "undecided"
    assert "frames_decoded" in m["verdict"]["reason"] and "data quality: FAILED (frames_decoded" in printed
    assert json.loads((out / "job.json").read_text())["data_quality"]["ok"] is False


def test_failed_gate_turns_any_verdict_undecided():
    from measure.quality import apply_data_quality

    for overall in ("over", "within", "not-applicable"):
        v = {"overall": overall, "reason": "", "dimensions": {d: {"verdict": overall} for d in ("length", "width", "height")}}
        out = apply_data_quality(v, [{"name": "camera_motion", "status": "fail", "detail": "static camera"}])
        assert out["overall"] == "undecided" and "camera_motion: static camera" in out["reason"]
        assert all(e["verdict"] not in ("over", "within") for e in out["dimensions"].values())


def test_static_camera_refused_with_cause(tmp_path, capsys, videos):
    out = tmp_path / "out"
    rc = main(["-q", "run", str(videos["static"]), "--calib", str(SAMPLE_CONF), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "Traceback" not in err and len(err.splitlines()) == 1, err
    assert "static camera" in err
    job = json.loads((out / "job.json").read_text())
    assert job["data_quality"]["ok"] is False and job["stages"]["measure"]["status"] == "failed"
    assert not (out / "measurement.json").exists()   # the reconstruction is kept, no verdict is
    no_temp_left(tmp_path)


@pytest.mark.parametrize("failure", [OSError("921600 requested and 413664 written"),   # numpy's short write
                                     OSError(28, "No space left on device")])
def test_disk_running_out_mid_run_is_one_line_naming_the_folder(tmp_path, capsys, monkeypatch, failure):
    # The disk fills while the views' depth is written: one line that says so and names where, exit 2, and
    # nothing left behind (it used to read "reconstruct: OSError: 921600 requested and 413664 written").
    def full(*args, **kwargs):
        raise failure

    monkeypatch.setattr(np, "save", full)
    out = tmp_path / "out"
    rc = main(["-q", "run", str(SAMPLE_VIDEO), "--calib", str(SAMPLE_CONF), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "Traceback" not in err and len(err.splitlines()) == 1, err
    assert f"{tmp_path}: its disk ran out of space (" in err and "--out" in err, err
    assert not out.exists()
    no_temp_left(tmp_path)


def test_other_write_errors_are_not_called_a_full_disk(tmp_path):
    from stereo_recon.core.validate import disk_full_message

    assert disk_full_message(PermissionError(13, "Permission denied"), tmp_path) is None
    assert disk_full_message(ValueError("921600 requested and 413664 written"), tmp_path) is None
    assert "ran out of space" in disk_full_message(OSError(28, "No space left on device"), tmp_path / "new" / "out")


# ---- transactions --------------------------------------------------------------------------------

def test_sigkill_leaves_temp_that_the_next_run_removes(tmp_path, capsys):
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-m", "stereo_recon.app.cli", "-q", "reconstruct", str(SAMPLE_VIDEO), "--calib",
                             str(SAMPLE_CONF), "--out", str(out)], env=env, cwd=REPO)
    deadline = time.time() + 120
    temps: list[Path] = []
    while time.time() < deadline and not temps:
        temps = [p for p in tmp_path.iterdir() if p.name.startswith(f".out.tmp-{proc.pid}-")]
        time.sleep(0.2)
    time.sleep(1.0)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # The killed run's work is only in its temporary folder; the output folder holds at most its log.txt
    # (opened before the run, it says how far the run got).
    assert temps and temps[0].exists() and (not out.exists() or sorted(os.listdir(out)) == ["log.txt"])
    from stereo_recon.core.cloud_io import write_cloud
    from measure.synthetic_cloud import MODEL_TRUCK, SceneSpec, make_truck_scene

    cloud = write_cloud(tmp_path / "truck.ply", make_truck_scene(MODEL_TRUCK, SceneSpec(spacing_m=0.01), rng=1)[0])
    assert main(["measure", str(cloud), "--out", str(out), "--no-plots"]) == 0
    assert not temps[0].exists()
    no_temp_left(tmp_path)


@pytest.mark.parametrize("argv, pattern", [(["--regulation", "BAD"], "unknown regulation"),
                                           (["--vehicle-class", "bogus"], "unknown vehicle class"),
                                           (["--scale", "nan"], "--scale nan")])
def test_bad_option_into_good_folder_leaves_it_exactly(good_run, capsys, argv, pattern):
    out, state, _ = good_run
    refused(capsys, ["run", "--out", out, *argv], pattern)
    assert folder_state(out) == state
    no_temp_left(out.parent)


def test_bad_config_into_good_folder_leaves_it_exactly(good_run, tmp_path, capsys):
    out, state, _ = good_run
    cfg = tmp_path / "bad.toml"
    cfg.write_text("eps_m = [1\n")
    refused(capsys, ["run", "--out", out, "--config", cfg], f"{cfg}: cannot parse config")
    assert folder_state(out) == state


def test_good_run_has_data_quality_and_summary_line(good_run):
    out, _, data = good_run
    m = json.loads(data)
    assert m["data_quality"]["ok"] is True
    names = {c["name"] for c in m["data_quality"]["checks"]}
    assert {"eyes_distinct", "eye_order", "calibration_size", "rectification", "frames_decoded", "camera_motion",
            "faces_length", "faces_width", "faces_height", "orbit_arc"} <= names
    assert m["input"]["path"] == str(out.resolve() / "cloud.ply")
    assert b"created_utc" not in data and b"tmp-" not in data


@pytest.mark.slow
def test_resume_reuses_same_and_redoes_truncated_with_identical_bytes(good_run, tmp_path, caplog):
    out0, _, data = good_run
    out = tmp_path / "out"
    shutil.copytree(out0, out)
    with caplog.at_level(logging.INFO):
        assert main(["-q", "run", "--out", str(out), "--resume"]) == 0
    assert json.loads((out / "job.json").read_text())["stages"]["reconstruct"]["status"] == "reused"
    cloud = out / "cloud.ply"
    cloud.write_bytes(cloud.read_bytes()[: cloud.stat().st_size - 20_000 * 27])
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(["-q", "run", "--out", str(out), "--resume"]) == 0
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("resume:")]
    assert len(lines) == 1 and "cloud.ply is" in lines[0] and "(truncated or modified)" in lines[0], lines
    assert json.loads((out / "job.json").read_text())["stages"]["reconstruct"]["status"] == "done"
    # Recomputed from scratch: the same measurement.json bytes (determinism of run), the folder's name aside.
    assert (out / "measurement.json").read_bytes() == data.replace(str(out0.resolve()).encode(), str(out.resolve()).encode())


@pytest.mark.slow
def test_resume_after_calibration_change_recomputes(good_run, rigs, tmp_path, caplog):
    out0, _, data = good_run
    out = tmp_path / "out"
    shutil.copytree(out0, out)
    with caplog.at_level(logging.WARNING):
        assert main(["-q", "run", str(SAMPLE_VIDEO), "--calib", str(rigs["baseline110"]), "--out", str(out),
                     "--resume"]) == 0
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("resume:")]
    assert len(lines) == 1 and "the calibration changed" in lines[0], lines
    run = json.loads((out / "run.json").read_text())
    job = json.loads((out / "job.json").read_text())
    new_sha = hashlib.sha256(rigs["baseline110"].read_bytes()).hexdigest()
    assert run["inputs"]["calib"]["sha256"] == new_sha == job["fingerprint"]["calib"]["sha256"]
    assert job["length_m"] == pytest.approx(1.1 * json.loads(data)["length_m"], rel=0.02)


def test_failed_face_gate_leaves_no_over_standing():
    """An unseen face puts the whole cluster in doubt: an over-height read beside an unseen side wall is no
    verdict (on evaluation seed 2034, 4 of 8 face-refused full-scale draws had another dimension 6-74 % off)."""
    from measure.quality import apply_data_quality

    statuses = {"length": "within", "width": "within", "height": "over"}
    v = {"overall": "over", "reason": "", "dimensions": {d: {"verdict": s} for d, s in statuses.items()}}
    out = apply_data_quality(v, [{"name": "faces_width", "status": "fail", "detail": "left 3% of the face covered"}])
    assert out["overall"] == "undecided" and out["reason"].startswith("data quality: faces_width: left 3%")
    assert out["dimensions"]["width"]["verdict"] == "undecided"
    assert out["dimensions"]["height"]["verdict"] == "over"   # per dimension, what the data said stays on record


@pytest.mark.slow
def test_quiet_run_through_colmap_prints_nothing_when_piped(tmp_path):
    """-q is errors only: COLMAP's own (glog) lines must not reach a piped stderr either (they did: 115 lines)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("GLOG_")}
    proc = subprocess.run([sys.executable, "-m", "stereo_recon.app.cli", "-q", "reconstruct", str(SAMPLE_VIDEO), "--calib",
                           str(SAMPLE_CONF), "--poses", "sfm", "--frames", "0:24", "--out", str(tmp_path / "out")],
                          env=dict(env, PYTHONPATH=str(REPO)), cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "out" / "poses.txt").is_file()
    assert proc.stderr == "" and proc.stdout == "", proc.stderr[:2000]


def test_a_scale_the_run_did_not_correct_fails_its_gate():
    """Odometry 23.5 % short by the rig's depth and not rescaled (beyond max_rescale): no verdict, and why."""
    from stereo_recon.quality import checks_from_reconstruction, trajectory_scale_check

    refused = {"trajectory_scale_from_rig": 1.235, "motion_stereo_depth_scale": 1.0}   # as run.json records it
    c = trajectory_scale_check(refused)
    assert c["status"] == "fail" and "+23.5 %" in c["detail"]
    assert trajectory_scale_check({"trajectory_scale_from_rig": 1.03, "motion_stereo_depth_scale": 1.03})["status"] == "pass"
    assert trajectory_scale_check({"frames_read": 80}) is None   # no motion stereo: no such check
    names = [ch["name"] for ch in checks_from_reconstruction({"source": {}, "counts": {"frames_read": 80, **refused}})]
    assert names == ["frames_decoded", "trajectory_scale"]


def test_a_rejected_or_failed_bundle_adjustment_is_a_warning_in_the_checks():
    """SfM's refinement rejected (its poses another solution) or failed, or another solution kept over odometry's: a
    warning naming why, not a gate."""
    from stereo_recon.quality import checks_from_reconstruction, pose_refinement_check

    applied = {"grafted_frames": 37, "moved_rel_median": 0.01, "turned_deg_median": 0.4}
    assert pose_refinement_check({"sfm_refine": applied})["status"] == "pass"
    assert "guided" not in pose_refinement_check({"sfm_refine": applied})["detail"]
    guided = pose_refinement_check({"sfm_refine": {**applied, "guided_matching": True}})
    assert guided["status"] == "pass" and "matched again guided by epipolar geometry" in guided["detail"], guided
    rejected = {**applied, "rejected": "SfM's poses lie 0.50 of the path's radius and 35.0 deg from VO's"}
    c = pose_refinement_check({"sfm_refine": rejected})
    assert c["status"] == "warn" and "0.50 of the path's radius" in c["detail"] and "odometry's poses kept" in c["detail"]
    assert pose_refinement_check({"sfm_refine": "failed: too few images registered"})["status"] == "warn"
    kept = pose_refinement_check({"sfm_refine": {**applied, "kept_over_odometry": "SfM's poses lie 0.38 of the path's "
                                                 "radius; kept: depth agrees on 49.4 % with SfM's, 33.1 % with VO's"}})
    assert kept["status"] == "warn" and "another solution" in kept["detail"] and "49.4 %" in kept["detail"], kept
    assert pose_refinement_check({"frames_read": 80}) is None   # not a far scene: no bundle adjustment
    names = [ch["name"] for ch in checks_from_reconstruction({"source": {}, "counts": {"frames_read": 80,
                                                                                     "sfm_refine": rejected}})]
    assert names == ["frames_decoded", "pose_refinement"]


def test_a_full_disk_outside_the_stages_is_one_line_too(tmp_path, capsys):
    # A command whose own code meets ENOSPC outside a stage's wrapper still ends in one line naming the folder
    # and exit 2, and leaves no output folder; any other OSError keeps its traceback (a bug to report).
    import argparse
    import errno

    from stereo_recon.app.cli import _run_command

    def full(args):
        raise OSError(errno.ENOSPC, "No space left on device")

    def broken(args):
        raise OSError(errno.EIO, "Input/output error")

    out = tmp_path / "out"
    args = argparse.Namespace(command="run", func=full, verbose=0, quiet=True, out=str(out))
    assert _run_command(args, ["run", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{out}: its disk ran out of space" in err, err
    assert not out.exists()
    with pytest.raises(OSError, match="Input/output"):
        _run_command(argparse.Namespace(command="run", func=broken, verbose=0, quiet=True, out=str(out)), ["run"])
