"""``batch --executor ray``: the real pipeline on two short recordings through a local Ray instance
and through a cluster started here on loopback gives the same files as ``--executor local``."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest


REPO = Path(__file__).resolve().parents[3]
SAMPLE = REPO / "sample_data"
CALIB = SAMPLE / "SN28000001.conf"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                       reason="Ray is not installed: the tests of batch --executor ray need the 'ray' extra (pip install -e .[ray])"),
]

# Keys of measurement.json that differ between any two runs (wall-clock), whatever the executor.
VOLATILE = ("timings_s", "created_utc")


def _cut(src: Path, dst: Path, start: int, n_frames: int) -> Path:
    """Frames [start, start + n_frames) of the sample as their own MJPG AVI: a short recording (~6 s of pipeline)."""
    import cv2

    cap = cv2.VideoCapture(str(src))
    fps = cap.get(cv2.CAP_PROP_FPS)
    cap.set(cv2.CAP_PROP_POS_FRAMES, start)
    writer = None
    for _ in range(n_frames):
        ok, frame = cap.read()
        assert ok, f"{src}: fewer than {start + n_frames} frames"
        if writer is None:
            writer = cv2.VideoWriter(str(dst), cv2.VideoWriter_fourcc(*"MJPG"), fps, (frame.shape[1], frame.shape[0]))
        writer.write(frame)
    writer.release()
    cap.release()
    return dst


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Two 16-frame recordings (a third of the sample's orbit each) and a truncated, corrupt one."""
    d = tmp_path_factory.mktemp("videos")
    a = _cut(SAMPLE / "video.avi", d / "truckA.avi", 0, 16)
    b = _cut(SAMPLE / "video.avi", d / "truckB.avi", 16, 16)
    bad = d / "broken.avi"
    bad.write_bytes(a.read_bytes()[:100_000])
    return a, b, bad


def _batch(tmp: Path, label: str, videos, *options: str, env: dict | None = None) -> tuple[int, Path, str]:
    """``stereo-recon batch`` in a fresh process (as a user runs it) into tmp/out, then the tree moved to
    tmp/<label>: every run writes the same paths. Returns (exit code, tree, stderr)."""
    out = tmp / "out"
    pythonpath = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    proc = subprocess.run([sys.executable, "-m", "stereo_recon.app.cli", "batch", *map(str, videos), "--calib", str(CALIB),
                           "--out", str(out), *options], capture_output=True, text=True, timeout=600,
                          env={**{k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"},
                               "PYTHONPATH": pythonpath, "MPLBACKEND": "Agg", **(env or {})})
    if out.exists():
        out.rename(tmp / label)
    return proc.returncode, tmp / label, proc.stderr


@pytest.fixture(scope="module")
def local_run(recordings, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("batch")
    rc, tree, err = _batch(tmp, "local", recordings[:2], "--workers", "2")
    assert rc == 0
    return tmp, tree


def _same_outputs(tree: Path, reference: Path, names=("truckA", "truckB")) -> None:
    for name in names:
        assert (tree / name / "cloud.ply").read_bytes() == (reference / name / "cloud.ply").read_bytes(), name
        got = json.loads((tree / name / "measurement.json").read_text())
        want = json.loads((reference / name / "measurement.json").read_text())
        for key in VOLATILE:   # older records kept wall-clock keys; measurement.json now holds none
            got.pop(key, None), want.pop(key, None)
        # Same keys, same values, same paths (the driver's, not a node's scratch folder).
        assert json.dumps(got, sort_keys=True) == json.dumps(want, sort_keys=True), name
        assert sorted(p.name for p in (tree / name).iterdir()) == sorted(p.name for p in (reference / name).iterdir())


def _rows(tree: Path) -> dict[str, dict]:
    with (tree / "summary.csv").open(newline="") as f:
        return {Path(r["video"]).name: r for r in csv.DictReader(f)}


def test_local_ray_instance_matches_local_pool(recordings, local_run):
    tmp, local = local_run
    rc, tree, err = _batch(tmp, "ray-local", recordings, "--executor", "ray", "--workers", "2")
    assert rc == 1, err  # the corrupt recording fails alone
    _same_outputs(tree, local)
    rows = _rows(tree)
    assert [rows[n]["ok"] for n in ("truckA.avi", "truckB.avi", "broken.avi")] == ["true", "true", "false"]
    for name in ("truckA.avi", "truckB.avi"):
        want = _rows(local)[name]
        assert {k: rows[name][k] for k in ("length_m", "width_m", "height_m", "verdict", "video_sha256")} == \
               {k: want[k] for k in ("length_m", "width_m", "height_m", "verdict", "video_sha256")}
        assert rows[name]["out_dir"] == str(tmp / "out" / Path(name).stem)  # the driver's folder
    # One line per job as it finishes (k/N), the failure naming its video; no traceback.
    lines = [ln for ln in err.splitlines() if ln.startswith("[")]
    assert sorted(ln.split("]")[0] for ln in lines) == ["[1/3", "[2/3", "[3/3"]
    failed = [ln for ln in lines if "FAILED" in ln]
    assert len(failed) == 1 and str(recordings[2]) in failed[0]
    assert "Traceback" not in err


def test_ray_side_crash_is_one_line_and_others_finish(loopback_cluster, monkeypatch, capfd, tmp_path):
    from stereo_recon.app import batch_ray
    from stereo_recon.app.batch import run_jobs
    from stereo_recon.app.jobs import Job

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    # An input that vanishes after the driver looked at it cannot be shipped: that job alone fails.
    gone = str(tmp_path / "gone.avi")
    looked = batch_ray._input_state
    monkeypatch.setattr(batch_ray, "_input_state", lambda p: ("file", 10) if p == gone else looked(p))
    # With no address a fresh local instance starts, even while another cluster runs on this machine.
    # os._exit kills the Ray worker: Ray itself reports the failure, not the job's own code.
    jobs = [Job("crash", os._exit, (3,)), Job("fine", json.loads, ('{"length_m": 2.0}',)),
            Job("gone", json.loads, ("{}",), inputs=(gone,))]
    results = run_jobs(jobs, workers=2, executor="ray", ray_options=batch_ray.RayOptions(ship_inputs="always"))
    assert [r["ok"] for r in results] == [False, True, False] and results[1]["length_m"] == 2.0
    assert results[2]["error"].startswith("cannot send its files to the cluster: FileNotFoundError") and gone in results[2]["error"]
    assert "\n" not in results[0]["error"] and "Traceback" not in results[0]["error"]
    assert "Worker" in results[0]["error"] or "crash" in results[0]["error"].lower(), results[0]["error"]
    printed = capfd.readouterr()
    assert "worker died" not in (printed.out + printed.err).lower()  # Ray's own many-line notice goes to the log


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop_group(proc: subprocess.Popen) -> None:
    """Stop the cluster by its own process group (never by name: other Ray instances may run here)."""
    for sig, grace_s in ((signal.SIGTERM, 2.0), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        deadline = time.monotonic() + grace_s
        while time.monotonic() < deadline:
            proc.poll()
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.2)


@pytest.fixture(scope="module")
def loopback_cluster():
    """``ray start --head`` on 127.0.0.1 with 2 CPUs and token authentication; stopped afterwards whatever happens."""
    ray_cli = Path(sys.executable).parent / "ray"
    if not ray_cli.is_file():
        pytest.skip(f"the ray command is not beside {sys.executable}")
    token = secrets.token_hex(32)
    auth = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": token}
    env = {**os.environ, **auth, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    temp_dir = tempfile.mkdtemp(prefix="sr-ray-")  # short: Ray's socket paths must fit in 107 bytes
    port = _free_port()
    log_path = Path(temp_dir) / "head.log"
    with log_path.open("w") as log:
        proc = subprocess.Popen(
            [str(ray_cli), "start", "--head", "--node-ip-address", "127.0.0.1", "--num-cpus", "2", "--port", str(port),
             "--block", "--include-dashboard", "false", "--disable-usage-stats", "--temp-dir", temp_dir],
            env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        while "Ray runtime started" not in log_path.read_text():
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"ray start did not come up:\n{log_path.read_text()[-2000:]}")
            time.sleep(0.5)
        yield f"127.0.0.1:{port}", auth
    finally:
        _stop_group(proc)
        shutil.rmtree(temp_dir, ignore_errors=True)


def test_existing_loopback_cluster_matches_local_pool(recordings, local_run, loopback_cluster):
    tmp, local = local_run
    address, auth = loopback_cluster
    # --address wins over RAY_ADDRESS (pointing nowhere here); the inputs are shipped through Ray's
    # object store (as to a node without the recordings) and the outputs come back.
    rc, tree, err = _batch(tmp, "ray-cluster", recordings[:2], "--executor", "ray", "--address", address,
                           "--ship-inputs", "always", env={**auth, "RAY_ADDRESS": "127.0.0.1:1"})
    assert rc == 0, err
    _same_outputs(tree, local)
    rows = _rows(tree)
    for name in ("truckA.avi", "truckB.avi"):
        assert rows[name]["video"] == str(recordings[0].parent / name)  # the driver's path, not the shipped copy
        assert rows[name]["length_m"] == _rows(local)[name]["length_m"]
    assert "Traceback" not in err

    # --resume on one recording: its finished reconstruction travels to the node and is reused there;
    # its row is replaced in summary.csv, the other recording's row stays.
    tree.rename(tmp / "out")
    rc, tree, err = _batch(tmp, "ray-cluster-resumed", recordings[:1], "--executor", "ray", "--address", address,
                           "--resume", env=auth)
    assert rc == 0, err
    assert json.loads((tree / "truckA" / "job.json").read_text())["stages"]["reconstruct"]["status"] == "reused"
    _same_outputs(tree, local)
    assert sorted(_rows(tree)) == ["truckA.avi", "truckB.avi"]

    # RAY_ADDRESS alone (how Ray users point every tool at their cluster); a failure there is one line.
    rc, tree, err = _batch(tmp, "ray-cluster-bad", recordings[2:], "--executor", "ray", env={**auth, "RAY_ADDRESS": address})
    assert rc == 1 and _rows(tree)["broken.avi"]["ok"] == "false"
    failed = [ln for ln in err.splitlines() if "FAILED" in ln]
    assert len(failed) == 1 and str(recordings[2]) in failed[0], err
    assert "Traceback" not in err
