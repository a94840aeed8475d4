"""Shared test fixtures: where the real data lives, and seeded RNGs."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="module", autouse=True)
def _free_module_scratch(request, tmp_path_factory):
    """Removes what this module's tests and fixtures wrote under pytest's base temp once the module is done.

    Why: kept to the session's end, a full run's clouds, videos and work files add up to ~1.5 GB, more than a CI
    machine's disk has had free (ENOSPC in the last module's reconstructions). Kept when one of the module's
    tests failed, for the post-mortem. Session-scoped fixtures must not write under base temp (none do).
    """
    base = tmp_path_factory.getbasetemp()
    before = set(base.iterdir())
    failed_before = request.session.testsfailed
    yield
    if request.session.testsfailed == failed_before:
        for path in set(base.iterdir()) - before:
            shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def shared_data() -> Path:
    """``../shared/data``; tests needing it skip with a clear reason when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (it lives beside the repository in ../shared/data)")
    return SHARED_DATA


@pytest.fixture
def benchmark_module():
    """Loader of a script in ``benchmarks/`` (not a package) as a module: ``benchmark_module("bench_x")``."""
    import importlib.util

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def box_on_ground():
    """Factory: an Open3D ray-casting scene of an axis-aligned box (min, max corners, m) on a square
    ground slab (top at z = 0, half-size ``ground_half_m``), for exact-depth renders."""
    o3d = pytest.importorskip("open3d")

    def make(box_min, box_max, ground_half_m: float = 3.0):
        box = o3d.geometry.TriangleMesh.create_box(*(np.asarray(box_max) - np.asarray(box_min)))
        box.translate(np.asarray(box_min, dtype=float))
        ground = o3d.geometry.TriangleMesh.create_box(2 * ground_half_m, 2 * ground_half_m, 0.01)
        ground.translate([-ground_half_m, -ground_half_m, -0.01])
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(box + ground))
        return scene

    return make
