"""The fast VO path of ``reconstruct``: pose-spread fusion views, subsampled fusion, prefetching, sparse stereo."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest

from stereo_recon.odometry import sparse_stereo_depth
from stereo_recon.reconstruct import PoseViewSelector, ReconstructConfig, _prefetch, subsample_for_fusion
from stereo_recon.core.errors import ConfigError
from stereo_recon.synthetic.flight import look_at  # noqa: E402


def _orbit(n=120, radius=1.7, altitude=1.0):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return [look_at(np.array([radius * np.cos(t), radius * np.sin(t), altitude]), np.array([0, 0, 0.15])) for t in a]


def test_pose_views_spread_evenly_over_an_orbit():
    # 3 deg per frame around the target; the camera turns with the orbit angle (its relative rotation is
    # a turn about the vertical), so a 17.9 deg threshold selects every 6th frame (20 views). The
    # translation threshold (0.4 x 2 m = 0.8 m, a 27 deg chord) must not trigger first.
    sel = PoseViewSelector(rotation_deg=17.9, translation_rel=0.4)
    picked = []
    for i, T in enumerate(_orbit()):
        if sel.is_view(T):
            sel.set_view(T)
            sel.set_depth(2.0)
            picked.append(i)
    assert picked[0] == 0
    assert len(picked) == 20
    assert set(np.diff(picked)) == {6}
    assert not sel.is_view(None)  # a lost frame (no pose) is never a view


def test_pose_views_by_translation_on_a_straight_pass():
    # Pure translation along x, 5 cm per frame, scene 2 m away: a new view every 0.25 x 2 m = 0.5 m.
    sel = PoseViewSelector(rotation_deg=18.0, translation_rel=0.25)
    picked = []
    for i in range(60):
        T = np.eye(4)
        T[0, 3] = 0.05 * i
        if sel.is_view(T):
            sel.set_view(T)
            sel.set_depth(2.0)
            picked.append(i)
    assert picked == list(range(0, 60, 10))


def test_subsampled_fusion_frame_projects_consistently():
    rng = np.random.default_rng(0)
    K = np.array([[700.0, 0, 641.3], [0, 700.0, 359.7], [0, 0, 1]])
    h, w = 720, 1280
    depth = rng.uniform(1.0, 3.0, (h, w)).astype(np.float32)
    color = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    c2, d2, K2 = subsample_for_fusion(color, depth, K, 2)
    assert d2.shape == (360, 640) and c2.shape == (360, 640, 3) and d2.flags.c_contiguous
    # Back-project subsampled pixels with K2: the same 3-D points as the full-resolution pixels they came from.
    v2, u2 = np.mgrid[0:360:37, 0:640:53]
    z = d2[v2, u2]
    X2 = np.stack([(u2 - K2[0, 2]) / K2[0, 0] * z, (v2 - K2[1, 2]) / K2[1, 1] * z], -1)
    u, v = 2 * u2, 2 * v2
    X = np.stack([(u - K[0, 2]) / K[0, 0] * depth[v, u], (v - K[1, 2]) / K[1, 1] * depth[v, u]], -1)
    np.testing.assert_allclose(X2, X, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(c2, color[::2, ::2])
    assert subsample_for_fusion(color, depth, K, 1)[2] is K


def test_prefetch_keeps_order_and_raises_the_producers_error():
    assert list(_prefetch(iter(range(50)), 2)) == list(range(50))

    def broken():
        yield 1
        raise ValueError("corrupt frame 2")

    got = []
    with pytest.raises(ValueError, match="corrupt frame 2"):
        for x in _prefetch(broken(), 2):
            got.append(x)
    assert got == [1]
    # Leaving the loop early stops the producer thread (no thread left blocked on a full queue).
    before = threading.active_count()
    gen = _prefetch(iter(range(10_000)), 2)
    assert next(gen) == 0
    gen.close()
    assert threading.active_count() <= before


def _reference_sparse(left, right, uv, fb, d_lo, d_hi, r=4, min_ncc=0.8, uniqueness=0.05):
    """The per-point cv2.matchTemplate formulation sparse_stereo_depth replaces (same rules)."""
    h, w = left.shape
    z = np.full(len(uv), np.nan)
    for k, (u, v) in enumerate(np.rint(uv).astype(int)):
        if v - r < 0 or v + r >= h or u - r < 0 or u + r >= w:
            continue
        x0, x1 = max(r, u - d_hi), u - d_lo
        if x1 - x0 < 2:
            continue
        s = cv2.matchTemplate(right[v - r:v + r + 1, x0 - r:x1 + r + 1], left[v - r:v + r + 1, u - r:u + r + 1],
                              cv2.TM_CCOEFF_NORMED).ravel()
        i = int(np.argmax(s))
        best = s[i]
        if not best >= min_ncc or i == 0 or i == len(s) - 1:
            continue
        far = np.concatenate([s[: max(0, i - 2)], s[i + 3:]])
        if far.size and far.max() > best - uniqueness:
            continue
        den = s[i - 1] - 2 * best + s[i + 1]
        delta = 0.5 * (s[i - 1] - s[i + 1]) / den if den < 0 else 0.0
        disp = u - (x0 + i + delta)
        if disp > 0:
            z[k] = fb / disp
    return z


def test_vectorised_sparse_stereo_matches_matchtemplate_and_truth():
    rng = np.random.default_rng(1)
    h, w = 120, 400
    # Smooth random texture; right image = left shifted by a known sub-pixel disparity per row band.
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (h, w + 80)).astype(np.float32), (0, 0), 1.5)
    disp_true = 23.4
    xs = np.arange(w, dtype=np.float32)
    left = tex[:, 40:40 + w]
    right = cv2.remap(tex, (xs[None, :] + 40 + disp_true).repeat(h, 0), np.arange(h, dtype=np.float32)[:, None].repeat(w, 1),
                      cv2.INTER_CUBIC)
    left, right = (np.clip(a, 0, 255).astype(np.uint8) for a in (left, right))
    f, B = 500.0, 0.12
    uv = np.column_stack([rng.uniform(-5, w + 5, 400), rng.uniform(-5, h + 5, 400)])
    z = sparse_stereo_depth(left, right, uv, f, B, 0.3, 20.0)
    fb = f * B
    ref = _reference_sparse(left, right, uv, fb, max(1, int(np.floor(fb / 20.0))), int(np.ceil(fb / 0.3)))
    np.testing.assert_array_equal(np.isfinite(z), np.isfinite(ref))
    ok = np.isfinite(z)
    assert ok.sum() > 200
    np.testing.assert_allclose(z[ok], ref[ok], rtol=1e-4)
    # And the depth is the true one: the parabola's sub-pixel peak is within 0.2 px of 23.4 px (its
    # peak-locking bias on this texture is up to 0.13 px).
    np.testing.assert_allclose(z[ok], fb / disp_true, rtol=0.2 / disp_true)


def test_speed_path_config_is_validated():
    with pytest.raises(ConfigError):
        ReconstructConfig(fuse_rotation_deg=0.0)
    with pytest.raises(ConfigError):
        ReconstructConfig(fusion_depth_max_rel=0.5)
    with pytest.raises(ConfigError):
        ReconstructConfig(fusion_min_width_px=4)
    with pytest.raises(ConfigError, match="refine_max"):
        ReconstructConfig(refine_max_move_rel=0.0)
    with pytest.raises(ConfigError, match="refine_max"):
        ReconstructConfig(refine_max_turn_deg=-1.0)


@pytest.mark.parametrize("kw", [dict(consistency_views=0), dict(consistency_views=2, consistency_min_views=3),
                                dict(consistency_views=2, consistency_rel_tol=0.0)])
def test_consistency_settings_are_checked(kw):
    with pytest.raises(ConfigError, match="consistency"):
        ReconstructConfig(**kw)
