"""FoF clustering: the same partition as scipy query_pairs + connected_components and as Open3D DBSCAN(min_points=1)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from measure.fof import fof_clusters, fof_reference_scipy, same_partition


def _open3d_labels(points: np.ndarray, eps: float) -> np.ndarray:
    """Open3D cluster_dbscan(eps, min_points=1) with its singletons mapped to -1 (our noise label)."""
    o3d = pytest.importorskip("open3d")
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    lab = np.asarray(pc.cluster_dbscan(eps, 1, print_progress=False))
    u, c = np.unique(lab, return_counts=True)
    out = lab.copy()
    out[c[np.searchsorted(u, lab)] < 2] = -1
    return out


# eps values whose square is exact or deliberately not (sqrt(2)**2 != 2 in float64).
EPS = [1.0, 2.0, 1.5, float(np.sqrt(2.0)), float(np.sqrt(3.0)), float(np.sqrt(5.0)), 2.5]


@st.composite
def integer_clouds(draw):
    n = draw(st.integers(1, 60))
    span = draw(st.integers(1, 8))
    coords = draw(st.lists(st.tuples(*[st.integers(0, span)] * 3), min_size=n, max_size=n))
    scale = draw(st.sampled_from([1.0, 0.5, 0.25]))   # exact binary fractions keep distances exact
    eps = draw(st.sampled_from(EPS)) * scale
    return np.asarray(coords, dtype=np.float64) * scale, eps


@pytest.mark.slow
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(integer_clouds())
def test_fof_matches_scipy_and_open3d_on_exact_distances(cloud):
    pts, eps = cloud
    # Strict rule (d < eps): Open3D's and the paper's.
    ours = fof_clusters(pts, eps)
    assert same_partition(ours, fof_reference_scipy(pts, eps, inclusive=False))
    assert same_partition(ours, _open3d_labels(pts, eps))
    # Inclusive rule (d <= eps): scipy query_pairs' own comparison.
    ours_incl = fof_clusters(pts, eps, inclusive=True)
    assert same_partition(ours_incl, fof_reference_scipy(pts, eps, inclusive=True))


def test_points_exactly_eps_apart_follow_the_comparison():
    pts = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [5.0, 0, 0], [5.0, 3.0, 4.0]])
    strict = fof_clusters(pts, 1.0)
    assert (strict == -1).all()                    # at exactly eps nobody is a friend
    incl = fof_clusters(pts, 1.0, inclusive=True)
    assert incl[0] == incl[1] == incl[2] >= 0 and incl[3] == incl[4] == -1
    assert same_partition(fof_clusters(pts, 5.0, inclusive=True), fof_reference_scipy(pts, 5.0, inclusive=True))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([0.02, 0.05, 0.11]))
def test_fof_matches_references_on_random_float_clouds(seed, eps):
    rng = np.random.default_rng(seed)
    # Clumps of different density plus scattered points, so every code path is used.
    centres = rng.random((5, 3))
    pts = np.concatenate([c + rng.normal(0, rng.uniform(0.01, 0.05), (rng.integers(5, 80), 3)) for c in centres] + [rng.random((30, 3))])
    ours = fof_clusters(pts, eps)
    assert same_partition(ours, fof_reference_scipy(pts, eps))
    assert same_partition(ours, _open3d_labels(pts, eps))


def test_fof_on_a_truck_scene_matches_reference():
    from measure.synthetic_cloud import SceneSpec, TruckShape, make_truck_scene

    pts, _ = make_truck_scene(TruckShape(2.1, 0.38, 0.38), SceneSpec(spacing_m=0.012, noise_m=0.003, outlier_fraction=0.01, distractors=3, second_vehicle_gap_m=0.1), rng=2)
    for eps in (0.02, 0.036):
        ours = fof_clusters(pts, eps)
        assert same_partition(ours, fof_reference_scipy(pts, eps))


def test_labels_are_ordered_by_size_and_min_size_marks_noise():
    rng = np.random.default_rng(0)
    a = rng.random((50, 3)) * 0.1
    b = rng.random((20, 3)) * 0.1 + 5
    c = rng.random((3, 3)) * 0.01 + 10
    pts = np.concatenate([c, b, a, [[20.0, 20, 20]]])
    lab = fof_clusters(pts, 0.2)
    assert (lab[-51:-1] == 0).all() and (lab[3:23] == 1).all() and (lab[:3] == 2).all() and lab[-1] == -1
    lab5 = fof_clusters(pts, 0.2, min_size=5)
    assert (lab5[:3] == -1).all() and (lab5[3:23] == 1).all()


def test_edge_cases():
    assert fof_clusters(np.zeros((0, 3)), 1.0).shape == (0,)
    assert fof_clusters(np.zeros((1, 3)), 1.0).tolist() == [-1]
    dup = np.zeros((4, 3))
    assert fof_clusters(dup, 1e-6).tolist() == [0, 0, 0, 0]   # duplicates are at distance 0 < eps
    with pytest.raises(ValueError):
        fof_clusters(np.zeros((3, 2)), 1.0)
    with pytest.raises(ValueError):
        fof_clusters(np.zeros((3, 3)), 0.0)


def test_huge_extent_still_matches():
    rng = np.random.default_rng(1)
    pts = np.concatenate([rng.random((200, 3)) * 0.05, [[1e6, 0, 0], [1e6 + 1e-4, 0, 0]]])
    ours = fof_clusters(pts, 0.01)
    assert same_partition(ours, fof_reference_scipy(pts, 0.01))
    assert ours[-1] == ours[-2] >= 0


def test_far_flung_points_are_squeezed_not_sent_to_the_slow_path(monkeypatch):
    import measure.fof as fof

    rng = np.random.default_rng(4)
    near = rng.random((3000, 3)) * [2.0, 1.0, 0.5]
    far = np.array([[5000.0, 0, 0], [5000.03, 0, 0], [0, -3000.0, 800.0], [0, -3000.0, 800.04]])
    pts = np.concatenate([near, far])
    ref = fof_reference_scipy(pts, 0.05)

    def no_fallback(*a, **k):
        raise AssertionError("kd-tree fallback used")

    monkeypatch.setattr(fof, "fof_reference_scipy", no_fallback)
    ours = fof.fof_clusters(pts, 0.05)
    assert same_partition(ours, ref)
    assert ours[-1] == ours[-2] >= 0 and ours[-3] == ours[-4] >= 0 and ours[-1] != ours[-3]


def test_a_chain_crossing_the_core_box_to_far_points_stays_connected():
    rng = np.random.default_rng(8)
    core = rng.random((4000, 3))
    core[:50, 0] = 0.999 + 0.001 * rng.random(50)   # some core points at the chain's start
    xs = 1.0 + 0.02 * np.arange(30)
    chain = np.c_[xs, np.full(30, 0.5), np.full(30, 0.5)]   # leaves the core box
    far = np.array([[900.0, 900.0, 900.0], [900.02, 900.0, 900.0], [-700.0, -700.0, -700.0]])
    pts = np.concatenate([core, chain, far])
    import measure.fof as fof

    assert fof._split_far_points(pts, 0.05, False) is not None   # this cloud takes the split path
    for eps in (0.03, 0.05):
        assert same_partition(fof_clusters(pts, eps), fof_reference_scipy(pts, eps))
        assert same_partition(fof_clusters(pts, eps, inclusive=True), fof_reference_scipy(pts, eps, inclusive=True))
