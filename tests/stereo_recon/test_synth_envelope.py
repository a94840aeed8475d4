"""The random scene generator: every draw inside the operating envelope, reproducible, renderable for every kind."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from stereo_recon.core.errors import ConfigError
from stereo_recon.synthetic import envelope as env
from stereo_recon.synthetic.scene import truck_mesh


def _inside(value, lo_hi, tol=1e-9):
    return lo_hi[0] - tol <= value <= lo_hi[1] + tol


def _check_spec(s: env.RandomSceneSpec) -> None:
    t, p, f, c, sc = s.truck, s.panel, s.flight, s.camera, s.scene
    assert t.scale in env.SCALES and t.kind in env.KINDS
    if t.scale == "model":
        assert _inside(t.length_m, env.MODEL_LENGTH_M)
        assert _inside(t.width_m / t.length_m, env.MODEL_WIDTH_OVER_LENGTH)
        assert _inside(t.height_m / t.width_m, env.MODEL_HEIGHT_OVER_WIDTH)
    else:
        assert _inside(t.length_m, env.FULL_LENGTH_M) and _inside(t.width_m, env.FULL_WIDTH_M) and _inside(t.height_m, env.FULL_HEIGHT_M)
    assert _inside(t.cab_length_frac, env.CAB_LENGTH_FRAC) and _inside(t.cab_height_frac, env.CAB_HEIGHT_FRAC)
    assert (t.load_heights_frac is not None) == (t.kind == "flatbed")
    assert t.body_paint in env.PAINTS and t.cab_paint in env.PAINTS
    assert all(0 <= v <= 1 for v in (*t.body_rgb, *t.cab_rgb))
    assert p.texture_class in env.TEXTURE_CLASSES and _inside(p.panel.texture_strength, env.TEXTURE_STRENGTH[p.texture_class])
    if p.texture_class == "plain":
        assert p.panel.texture_strength <= 0.02  # the "plain paint": contrast <= 2 %
    assert _inside(p.texel_over_footprint, env.TEXEL_OVER_FOOTPRINT)
    for d in p.panel.decals:
        assert 0 <= d[0] < d[1] <= 1 and 0 <= d[2] < d[3] <= 0.9 + 1e-12
    assert _inside(f.radius_over_length, env.RADIUS_OVER_LENGTH)
    assert f.radius_m >= env.MIN_RADIUS_M[t.scale] - 1e-12 and f.radius_m >= f.radius_over_length * t.length_m - 1e-12
    assert _inside(f.elevation_drawn_deg, env.ELEVATION_DEG)
    assert f.elevation_drawn_deg - 1e-9 <= f.elevation_deg <= 60.0  # raised only over a second vehicle in the way
    # The elevation is the camera's, seen from the truck's centre at half height.
    assert math.degrees(math.atan2(f.altitude_m - 0.5 * t.height_m, f.radius_m)) == pytest.approx(f.elevation_deg)
    assert _inside(f.arc_deg, env.ARC_DEG) and _inside(f.frames_drawn, env.FRAMES)
    assert f.frames == (f.frames_drawn if s.max_frames is None else min(f.frames_drawn, s.max_frames))
    assert math.hypot(*f.centre_offset_m) <= env.CENTRE_OFFSET_OVER_LENGTH * t.length_m + 1e-12
    assert _inside(f.jitter_deg, env.JITTER_DEG) and _inside(f.shake_deg, env.SHAKE_DEG)
    assert c.lens_family in ("zed", "zed2") and c.codec in env.CODECS
    # The two families' k1 stay apart: about -0.17 (ZED) and -0.04 (ZED2), spread +-10 %.
    k1 = {"zed": (-0.19, -0.15), "zed2": (-0.046, -0.036)}[c.lens_family]
    assert _inside(c.left_hd[4], k1) and _inside(c.right_hd[4], k1)
    assert _inside(c.noise_sigma_dn, env.NOISE_SIGMA_DN) and _inside(c.blur_sigma_px, env.BLUR_SIGMA_PX)
    assert _inside(c.exposure_jitter, env.EXPOSURE_JITTER) and _inside(c.right_gain, env.RIGHT_GAIN)
    assert _inside(sc.sun_elevation_deg, env.SUN_ELEVATION_DEG) and sc.ground_class in env.GROUND_CLASSES
    assert _inside(sc.n_distractors, env.DISTRACTORS)
    if sc.second is not None:
        r = sc.second.height_m / t.height_m
        assert sc.second.relation in env.SECOND_RELATIONS and _inside(r, env.SECOND_HEIGHT_RATIO[sc.second.relation])
        assert _inside(sc.second.gap_m / t.width_m, env.SECOND_GAP_OVER_WIDTH)


def test_every_draw_lies_inside_the_envelope_and_covers_it():
    specs = [env.draw_spec(seed, i) for seed in range(6) for i in range(50)]
    for s in specs:
        _check_spec(s)
    # Every level of every categorical factor occurs, and the shares follow the design (300 draws: +-4 sigma bounds).
    n = len(specs)
    for attr, levels in ((lambda s: s.truck.scale, env.SCALES), (lambda s: s.truck.kind, env.KINDS),
                         (lambda s: s.panel.texture_class, env.TEXTURE_CLASSES), (lambda s: s.camera.lens_family, ("zed", "zed2")),
                         (lambda s: s.camera.codec, env.CODECS), (lambda s: s.truck.body_paint, env.PAINTS)):
        counts = {lv: sum(attr(s) == lv for s in specs) for lv in levels}
        p = 1 / len(levels)
        assert all(abs(c - n * p) <= 4 * math.sqrt(n * p * (1 - p)) for c in counts.values()), counts
    second = sum(s.scene.second is not None for s in specs)
    assert abs(second - n / 3) <= 4 * math.sqrt(n * 2 / 9)
    assert {s.scene.second.relation for s in specs if s.scene.second} == set(env.SECOND_RELATIONS)


def test_orbits_fly_over_a_second_vehicle_never_through_it():
    raised = 0
    for i in range(300):
        s = env.draw_spec(9, i)
        sv, t, f = s.scene.second, s.truck, s.flight
        if sv is None:
            continue
        raised += f.elevation_deg > f.elevation_drawn_deg
        yaw = math.radians(t.yaw_deg)
        a = np.linspace(0, 2 * np.pi, 720)
        x = f.centre_offset_m[0] + f.radius_m * np.cos(a)
        y = f.centre_offset_m[1] + f.radius_m * np.sin(a)
        tx, ty = np.cos(yaw) * x + np.sin(yaw) * y, -np.sin(yaw) * x + np.cos(yaw) * y  # truck frame
        sx, sy = env.second_vehicle_xy(t, sv)
        over = (np.abs(tx - sx) <= sv.length_m / 2) & (np.abs(ty - sy) <= sv.width_m / 2)
        if over.any():
            assert f.altitude_m >= sv.height_m + 0.3 * t.height_m - 1e-9, s.name
    assert raised > 0  # the case occurs in the envelope


def test_a_draw_depends_only_on_seed_and_index():
    a = env.draw_spec(7, 3)
    assert env.draw_spec(7, 3) == a
    assert env.draw_spec(7, 4) != a and env.draw_spec(8, 3) != a
    assert env.sample_scene_spec(np.random.default_rng([7, 3])) == replace(a, seed=-1, index=-1)
    capped = env.draw_spec(7, 3, max_frames=40)
    assert capped.max_frames == 40 and capped.flight.frames == min(40, a.flight.frames_drawn)
    assert capped.truck == a.truck and capped.camera == a.camera  # the cap changes nothing else
    forced = env.draw_spec(7, 3, scale="model" if a.truck.scale == "full" else "full")
    assert forced.camera == a.camera and forced.truck.kind == a.truck.kind and forced.truck.scale != a.truck.scale


def test_spec_round_trips_through_json():
    for i in range(20):
        s = env.draw_spec(11, i, max_frames=50)
        assert env.spec_from_dict(json.loads(json.dumps(env.spec_to_dict(s)))) == s
    with pytest.raises(ConfigError, match="unknown keys"):
        env.spec_from_dict({**env.spec_to_dict(s), "bogus": 1})


def _first_draw(pred, seed=5):
    for i in range(400):
        s = env.draw_spec(seed, i)
        if pred(s):
            return s
    raise AssertionError("no draw matches")


@pytest.mark.parametrize("kind", env.KINDS)
def test_every_kind_builds_a_renderable_scene_with_exact_truth(kind):
    from stereo_recon.synthetic.render import StereoRenderer

    s = _first_draw(lambda s: s.truck.kind == kind and s.scene.second is not None)
    s = replace(s, resolution="VGA", max_frames=2, flight=replace(s.flight, frames=2))
    d = env.build_draw(s)
    t = d.truth
    assert (t["length_m"], t["width_m"], t["height_m"]) == (s.truck.length_m, s.truck.width_m, s.truck.height_m)
    lo, hi = truck_mesh(d.preset.truck).bounds()
    assert np.allclose(hi - lo, [s.truck.length_m, s.truck.width_m, s.truck.height_m])
    assert t["random_spec"]["truck"]["kind"] == kind and t["second_vehicle"] is not None
    assert len(d.poses) == 2 and d.rig.image_size == (672, 376)
    with StereoRenderer(d.scene, d.rig, d.render_config, noise_seed=d.noise_seed) as r:
        pair = r.render(d.poses[0], rng=0)
        _, prim, _ = r.first_hits(d.poses[0])
    # The truck is in view: a share of the pixels of both eyes sees its cargo body.
    mats, ids = d.scene.material_table()
    names = np.array([m.name for m in mats] + ["sky"])[np.append(ids, len(mats))[np.minimum(prim, len(ids))]]
    n = pair.left.shape[0] * pair.left.shape[1]
    assert (names[:n] == "truck.body").mean() > 0.005 or kind == "flatbed"
    assert np.char.startswith(names[:n], "truck.").mean() > 0.01 and np.char.startswith(names[n:], "truck.").mean() > 0.01
    assert pair.left.std() > 5 and pair.right.std() > 5


def test_full_scale_truth_carries_the_verdict_expectation():
    s = _first_draw(lambda s: s.truck.scale == "full")
    t = env.build_draw(replace(s, resolution="VGA", flight=replace(s.flight, frames=2))).truth
    exp = t["over_limit_expectation"]
    assert exp["regulation"] == "cn-2016-62"
    over = s.truck.width_m > 2.55 or s.truck.height_m > 4.0 or s.truck.length_m > 18.1
    assert exp["verdict"] == ("over-limit" if over else "within-limits")
    m = _first_draw(lambda s: s.truck.scale == "model")
    assert env.build_draw(replace(m, resolution="VGA", flight=replace(m.flight, frames=2))).truth["over_limit_expectation"]["verdict"] == "not-applicable"


def test_synth_random_cli_writes_reuses_and_refuses(tmp_path, capsys):
    from stereo_recon.app.cli import main

    out = tmp_path / "draws"
    assert main(["synth", "--random", "2", "--seed", "3", "--max-frames", "2", "--resolution", "VGA", "--out", str(out)]) == 0
    for i in range(2):
        d = out / f"draw_{i:03d}"
        names = {p.name for p in d.iterdir()}
        assert {"truth.json", "poses_gt.txt", "rig.yaml", "SN28000001.conf", "synth_run.json"} <= names
        assert any(n.startswith("video.") for n in names)
        truth = json.loads((d / "truth.json").read_text())
        assert truth["frames"] == 2 and truth["random_spec"]["index"] == i and truth["random_spec"]["max_frames"] == 2
    before = (out / "draw_000" / "video.avi").stat().st_mtime_ns if (out / "draw_000" / "video.avi").exists() else None
    assert main(["synth", "--random", "2", "--seed", "3", "--max-frames", "2", "--resolution", "VGA", "--out", str(out)]) == 0
    if before is not None:
        assert (out / "draw_000" / "video.avi").stat().st_mtime_ns == before  # reused, not rendered again
    assert main(["synth", "--random", "1", "--seed", "4", "--max-frames", "2", "--resolution", "VGA", "--out", str(out)]) == 2
    assert "holds another draw" in capsys.readouterr().err
    assert main(["synth", "--random", "1", "--noise", "3", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


def test_synth_random_depth_adds_the_rendered_depth_beside_the_same_video(tmp_path, capsys):
    """``--depth`` is no part of a draw's spec: the video is byte for byte the draw's, with the left eye's rendered
    z-depth beside it (what ``benchmarks/bench_depth_bias.py`` compares a run's depth with); a folder holding the
    draw without depth maps is refused for ``--depth``, not silently reused."""
    import hashlib

    from stereo_recon.app.cli import main

    args = ["synth", "--random", "1", "--seed", "3", "--max-frames", "2", "--resolution", "VGA"]
    assert main(args + ["--out", str(tmp_path / "plain")]) == 0
    assert main(args + ["--depth", "--out", str(tmp_path / "depth")]) == 0
    plain, deep = tmp_path / "plain" / "draw_000", tmp_path / "depth" / "draw_000"
    video = next(p.name for p in plain.iterdir() if p.name.startswith("video."))
    assert hashlib.sha256((plain / video).read_bytes()).digest() == hashlib.sha256((deep / video).read_bytes()).digest()
    maps = sorted((deep / "depth").glob("*.npy"))
    assert len(maps) == 2 and not (plain / "depth").exists()
    truth = json.loads((deep / "truth.json").read_text())
    z = np.load(maps[0])
    # The truck is in view: some pixels lie nearer than its centre's distance from the first camera plus its length.
    cam = np.loadtxt(deep / "poses_gt.txt")[0, 1:4]
    assert z.shape == (376, 672) and np.isfinite(z).mean() > 0.5
    assert np.nanmin(z) < np.linalg.norm(cam) + truth["length_m"]
    assert main(args + ["--depth", "--out", str(tmp_path / "plain")]) == 2
    assert "without its depth maps" in capsys.readouterr().err
