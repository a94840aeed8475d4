"""Optional GPU path: never imported by the CPU install; matches the CPU path when torch+CUDA exist."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from stereo_recon import gpu


def test_cpu_install_never_imports_torch():
    code = ("import sys, stereo_recon.gpu, stereo_recon.reconstruct, stereo_recon.app.reconstruct_cli, "
            "stereo_recon.disparity, stereo_recon.fusion, stereo_recon.video; print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_backproject_cpu_reference(rng):
    K = np.array([[500.0, 0, 100.0], [0, 480.0, 60.0], [0, 0, 1]])
    z = rng.uniform(1, 5, (120, 200))
    P = gpu.backproject_cpu(z, K)
    # Re-projecting the points gives back the pixel grid exactly.
    u = K[0, 0] * P[..., 0] / P[..., 2] + K[0, 2]
    v = K[1, 1] * P[..., 1] / P[..., 2] + K[1, 2]
    vv, uu = np.mgrid[0:120, 0:200]
    assert np.abs(u - uu).max() < 1e-9 and np.abs(v - vv).max() < 1e-9
    np.testing.assert_array_equal(P[..., 2], z)


needs_cuda = pytest.mark.skipif(not gpu.cuda_available(), reason="torch with a CUDA device is not available")


@needs_cuda
def test_gpu_remap_matches_cpu_within_0_01_px():
    import cv2
    import torch

    calib_rig = pytest.importorskip("calib.rig")
    w, h = 640, 360
    K = np.array([[500.0, 0, 320], [0, 500, 180], [0, 0, 1]])
    D = np.array([-0.1, 0.05, 0.001, -0.001, 0.0])
    R, _ = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))
    rig = calib_rig.StereoRig(K1=K, D1=D, K2=K, D2=D, R=R, T=np.array([-0.12, 0.001, 0.0]), image_size=(w, h))
    rect = rig.rectification(alpha=0.0)
    mx, my = rect.map_left
    # Ramp images whose value is the x (y) source coordinate: the remapped value IS the sample position.
    ramp_x = np.tile(np.arange(w, dtype=np.float32), (h, 1))
    ramp_y = np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w))
    gx = gpu.remap_batch(ramp_x[None], mx, my).cpu().numpy()[0]
    gy = gpu.remap_batch(ramp_y[None], mx, my).cpu().numpy()[0]
    inside = (mx > 1) & (mx < w - 2) & (my > 1) & (my < h - 2)
    assert np.abs(gx - mx)[inside].max() < 0.01 and np.abs(gy - my)[inside].max() < 0.01
    cx = cv2.remap(ramp_x, mx, my, cv2.INTER_LINEAR)
    # OpenCV quantises positions to 1/32 px: GPU vs CPU agree within that, 0.01 px on average.
    assert np.abs(gx - cx)[inside].max() <= 1 / 32 + 1e-3
    assert np.abs(gx - cx)[inside].mean() < 0.01
    # Back-projection on the GPU equals the numpy reference.
    z = np.random.default_rng(0).uniform(1, 10, (2, h, w))
    P = gpu.backproject_batch(z, rect.K_rect).cpu().numpy()
    for b in range(2):
        np.testing.assert_allclose(P[b], gpu.backproject_cpu(z[b], rect.K_rect), atol=1e-9)
    # Full uint8 pair: within one grey level of cv2.remap.
    img = np.random.default_rng(1).integers(0, 256, (h, w, 3), dtype=np.uint8)
    img = cv2.GaussianBlur(img, (7, 7), 2)
    gl, _ = gpu.GpuRectifier(rect).rectify_pair(img, img)
    cl = cv2.remap(img, mx, my, cv2.INTER_LINEAR)
    assert np.abs(gl.astype(int) - cl.astype(int))[inside].max() <= 2
    del torch


@pytest.mark.skipif(gpu.cuda_available(), reason="a CUDA device is present: the benchmark runs instead")
def test_gpu_benchmark_without_cuda_says_so_and_exits_2(benchmark_module, capsys):
    bench = benchmark_module("bench_gpu")
    assert bench.main([]) == 2
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "CUDA" in out[0]
