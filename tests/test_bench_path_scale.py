"""benchmarks/bench_path_scale.py: a run's camera path against the rendered one, in scale."""

from __future__ import annotations

import json

import numpy as np

from stereo_recon.trajectory import Trajectory, write_tum


def _orbit(n: int, radius_m: float, seed: int) -> Trajectory:
    rng = np.random.default_rng(seed)
    a = np.linspace(0, 1.5 * np.pi, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.stack([radius_m * np.cos(a), radius_m * np.sin(a), 5 + 0.1 * rng.standard_normal(n)], 1)
    return Trajectory(np.arange(n), np.arange(n) / 15.0, T)


def _bench_folder(root, errors: dict[str, float], scale: str = "full"):
    for i, (name, e) in enumerate(errors.items()):
        gt = _orbit(30, 12.0, i)
        run, draw = root / "runs" / name, root / "draws" / name
        run.mkdir(parents=True)
        draw.mkdir(parents=True)
        est = gt.T_wc.copy()
        est[:, :3, 3] = (1 + e) * est[:, :3, 3] + np.array([3.0, -1.0, 0.5])   # another origin, the path e too large
        write_tum(draw / "poses_gt.txt", gt)
        write_tum(run / "poses.txt", Trajectory(gt.indices, gt.timestamps_s, est))
        (draw / "truth.json").write_text(json.dumps({"fps": 15.0, "scale": scale, "random_spec": {"truck": {"kind": "box"}}}))
        (run / "run.json").write_text(json.dumps({"counts": {"far_scene": True, "trajectory_scale_from_rig": 1.01}}))
    return root


def test_the_paths_scale_error_is_read_and_summarized(benchmark_module, tmp_path, capsys):
    mod = benchmark_module("bench_path_scale")
    out = _bench_folder(tmp_path / "a", {"draw_000": 0.02, "draw_001": -0.005})
    res = mod.folder(out)
    assert abs(res["draw_000"]["scale_error_pct"] - 2.0) < 1e-6
    assert abs(res["draw_001"]["scale_error_pct"] + 0.5) < 1e-6
    assert res["draw_001"]["kind"] == "box" and res["draw_001"]["far"]
    other = _bench_folder(tmp_path / "b", {"draw_000": 0.001, "draw_001": 0.0})
    assert mod.main([str(out), str(other)]) == 0
    text = capsys.readouterr().out
    assert "mean |error| 1.25 %, bias +0.75 %, max |error| 2.00 %" in text
    assert "mean |error| 0.05 %" in text


def test_a_folder_that_is_no_bench_output_is_refused(benchmark_module, tmp_path, capsys):
    mod = benchmark_module("bench_path_scale")
    assert mod.main([str(tmp_path)]) == 2
    assert "not a `stereo-recon bench --random` output folder" in capsys.readouterr().err
