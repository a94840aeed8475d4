"""Shared test fixtures: where the real data lives, and seeded RNGs."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


# The longest modules, longest first (seconds of one worker, measured 2026-12-01 on the 2-core AMD EPYC machine with
# `pytest --durations=80`, a bench running beside it: 1179, 688, 649, 553, 498, 348, 271; the rest of the suite ~1000).
# Why: with --dist loadfile each module runs on one worker, and workers take modules in collection order, in which
# the envelope slice came last: one worker ran it alone for its last ~10 minutes. Started first, the long modules
# overlap the many short ones (a list schedule of the measured durations: 2896 -> 2620 s of wall time, the two
# workers' balanced bound being 2600 s). Only the order changes: every test still runs, each module's tests together.
LONGEST_MODULES_FIRST = (
    "tests/test_envelope_slice.py",
    "tests/stereo_recon/test_reconstruct_synth.py",
    "tests/measure/test_measure_dimensions.py",
    "tests/stereo_recon/app/test_batch_ray.py",
    "tests/stereo_recon/test_bad_inputs.py",
    "tests/stereo_recon/test_far_scene_roof.py",
    "tests/measure/test_measure_pipeline.py",
)


def pytest_collection_modifyitems(config, items):
    """Moves the modules of ``LONGEST_MODULES_FIRST`` to the front, in that order; the others keep theirs."""
    rank = {m: k for k, m in enumerate(LONGEST_MODULES_FIRST)}

    def key(indexed):
        k, item = indexed
        path = Path(str(item.fspath)).resolve()
        rel = path.relative_to(REPO).as_posix() if path.is_relative_to(REPO) else path.as_posix()
        return (rank.get(rel, len(rank)), k)

    items[:] = [item for _, item in sorted(enumerate(items), key=key)]


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
