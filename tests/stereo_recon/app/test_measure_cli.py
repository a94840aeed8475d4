"""``stereo-recon measure``: a good run writes the report; bad input is one line, non-zero, no folder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stereo_recon.core.cloud_io import write_cloud
from measure.synthetic_cloud import MODEL_TRUCK, SceneSpec, TruckShape, make_truck_scene
from measure.schema import read_measurement  # every measurement.json a test writes is checked against its schema
from stereo_recon.app.cli import main


@pytest.fixture(scope="module")
def truck_ply(tmp_path_factory):
    pts, truth = make_truck_scene(MODEL_TRUCK, SceneSpec(spacing_m=0.01, noise_m=0.002, tilt_deg=6.0, camera_frame=True), rng=21)
    path = tmp_path_factory.mktemp("clouds") / "truck.ply"
    write_cloud(path, pts)
    return path, truth


def _fails(capsys, argv, out_dir, pattern):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc != 0
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    assert pattern in err, err
    assert not out_dir.exists()
    return err


def test_measure_writes_json_plots_and_report(truck_ply, tmp_path, capsys):
    path, truth = truck_ply
    out = tmp_path / "out"
    assert main(["measure", str(path), "--out", str(out), "--scale", "6"]) == 0
    text = capsys.readouterr().out
    assert "length" in text and "verdict" in text
    m = read_measurement(out)
    for d in ("length", "width", "height"):
        assert abs(m[f"{d}_m"] - truth[f"{d}_m"]) / truth[f"{d}_m"] < 0.01
        assert m["uncertainty_m"][d] > 0
    assert m["verdict"]["overall"] in ("within", "over", "undecided")
    assert len(m["input"]["sha256"]) == 64
    assert m["parameters"]["resolved"]["eps_m"] > 0 and "numpy" in m["versions"]
    assert m["parameters"]["resolved"]["lattice_m"] is None        # a synthetic cloud, not a fused one
    assert set(m["bandwidths_m"]) == {"length", "width", "height"}
    for png in ("width_density.png", "length_density.png", "top_view.png", "side_view.png"):
        assert (out / png).stat().st_size > 1000
    assert (out / "report.html").exists()
    assert not list(tmp_path.glob(".out.tmp-*"))


def test_model_truck_without_scale_gets_no_legal_verdict(truck_ply, tmp_path, capsys):
    path, _ = truck_ply
    out = tmp_path / "o2"
    assert main(["measure", str(path), "--out", str(out), "--no-plots", "--eps", "0.03", "--bootstrap", "5"]) == 0
    m = read_measurement(out)
    assert m["verdict"]["overall"] == "not-applicable"
    assert m["parameters"]["resolved"]["eps_m"] == 0.03


def test_missing_file(tmp_path, capsys):
    _fails(capsys, ["measure", str(tmp_path / "nope.ply"), "--out", str(tmp_path / "o")], tmp_path / "o", "no such file")


def test_empty_file(tmp_path, capsys):
    (tmp_path / "e.ply").write_bytes(b"")
    _fails(capsys, ["measure", str(tmp_path / "e.ply"), "--out", str(tmp_path / "o")], tmp_path / "o", "empty")


def test_garbage_ply(tmp_path, capsys):
    (tmp_path / "g.ply").write_bytes(b"this is not a ply file\n" * 10)
    _fails(capsys, ["measure", str(tmp_path / "g.ply"), "--out", str(tmp_path / "o")], tmp_path / "o", "g.ply")


def test_nan_points(tmp_path, capsys):
    pts = np.random.default_rng(0).random((500, 3))
    pts[7, 1] = np.nan
    np.savetxt(tmp_path / "n.xyz", pts)
    _fails(capsys, ["measure", str(tmp_path / "n.xyz"), "--out", str(tmp_path / "o")], tmp_path / "o", "NaN or infinite")


def test_too_few_points(tmp_path, capsys):
    np.savetxt(tmp_path / "few.xyz", np.random.default_rng(0).random((20, 3)))
    _fails(capsys, ["measure", str(tmp_path / "few.xyz"), "--out", str(tmp_path / "o")], tmp_path / "o", "only 20 points")


def test_no_ground_plane(tmp_path, capsys):
    write_cloud(tmp_path / "blob.ply", np.random.default_rng(1).normal(0, 1, (20000, 3)))
    _fails(capsys, ["measure", str(tmp_path / "blob.ply"), "--out", str(tmp_path / "o")], tmp_path / "o", "no ground plane")


def test_no_truck_like_cluster(tmp_path, capsys):
    rng = np.random.default_rng(0)
    ground = np.c_[rng.random((20000, 2)) * 4, rng.normal(0, 0.001, 20000)]
    post = np.c_[rng.random((3000, 2)) * 0.05 + 2, rng.random(3000) * 0.5]
    write_cloud(tmp_path / "post.ply", np.concatenate([ground, post]))
    err = _fails(capsys, ["measure", str(tmp_path / "post.ply"), "--out", str(tmp_path / "o")], tmp_path / "o", "no truck-like cluster")
    assert "rejected" in err


def test_two_equally_plausible_trucks(tmp_path, capsys):
    a, ta = make_truck_scene(TruckShape(2.1, 0.38, 0.38), SceneSpec(spacing_m=0.012, ground_margin=0.3), rng=15)
    side = np.cross(ta["up"], ta["heading"])
    write_cloud(tmp_path / "two.pcd", np.concatenate([a, a[ta["labels"] == 1] + side * 1.2]))
    _fails(capsys, ["measure", str(tmp_path / "two.pcd"), "--out", str(tmp_path / "o")], tmp_path / "o", "two equally plausible trucks")


def test_config_unknown_key_and_bad_vector(truck_ply, tmp_path, capsys):
    path, _ = truck_ply
    (tmp_path / "c.toml").write_text("epsilon = 3\n")
    _fails(capsys, ["measure", str(path), "--out", str(tmp_path / "o"), "--config", str(tmp_path / "c.toml")], tmp_path / "o", "unknown key")
    with pytest.raises(SystemExit):
        main(["measure", str(path), "--out", str(tmp_path / "o"), "--up", "0,1"])
    assert not (tmp_path / "o").exists()


def test_hints_and_config_file(truck_ply, tmp_path, capsys):
    path, truth = truck_ply
    (tmp_path / "m.yaml").write_text("measure:\n  eps_res: 3.5\n  bootstrap: 4\n")
    up = ",".join(f"{v:.4f}" for v in truth["up"] + 0.05)
    centre = ",".join(f"{v:.4f}" for v in truth["truck_centre"])
    out = tmp_path / "o"
    assert main(["measure", str(path), "--out", str(out), "--no-plots", "--config", str(tmp_path / "m.yaml"), "--up", up, "--centre", centre]) == 0
    m = read_measurement(out)
    assert m["ground_plane"]["initial_normal_source"] == "up_hint"
    assert np.degrees(np.arccos(np.dot(m["ground_plane"]["normal"], truth["up"]))) < 0.1
    assert m["clusters"]["selection_rule"] == "nearest_to_centre_hint"
    assert m["parameters"]["eps_res"] == 3.5 and m["parameters"]["bootstrap"] == 4
    assert abs(m["length_m"] - truth["length_m"]) / truth["length_m"] < 0.01


def test_reconstruction_error_widens_the_verdict_interval(tmp_path):
    """A truck 5 cm under the width limit: measured alone it is within; with the reconstruction's own
    1.44 % (2 sigma = 7 cm at 2.5 m) the limit falls inside the interval and the verdict is undecided."""
    from measure.pipeline import combined_uncertainty, measure_cloud_file
    from measure.synthetic_cloud import TruckShape

    pts, truth = make_truck_scene(TruckShape(length_m=12.0, width_m=2.50, height_m=3.6),
                                  SceneSpec(spacing_m=0.04, noise_m=0.01), rng=5)
    path = tmp_path / "truck.ply"
    write_cloud(path, pts)
    alone = measure_cloud_file(path, tmp_path / "a", plots=False, html=False)
    read_measurement(tmp_path / "a")
    assert abs(alone["width_m"] - 2.50) < 0.02
    assert alone["verdict"]["dimensions"]["width"]["verdict"] == "within" and "uncertainty_parts" not in alone
    rel = {"length": 0.0032, "width": 0.0144, "height": 0.0051}
    both = measure_cloud_file(path, tmp_path / "b", plots=False, html=True, reconstruction_rel_sigma=rel)
    read_measurement(tmp_path / "b")
    assert both["verdict"]["dimensions"]["width"]["verdict"] == "undecided"
    u, parts = both["uncertainty_m"], both["uncertainty_parts"]
    for d in ("length", "width", "height"):
        assert u[d] == pytest.approx(np.hypot(parts["measurement_m"][d], rel[d] * both[f"{d}_m"]))
        assert parts["measurement_m"][d] == pytest.approx(alone["uncertainty_m"][d])
    assert "validated relative error" in (tmp_path / "b" / "report.html").read_text()
    with pytest.raises(Exception, match="reconstruction_rel_sigma"):
        combined_uncertainty({"length": 1, "width": 1, "height": 1}, {"length": 0, "width": 0, "height": 0}, {"width": -0.1})


def test_run_parses_the_reconstruction_sigma_option():
    from stereo_recon.core.errors import ConfigError
    from stereo_recon.app.pipeline_cli import _parse_sigma_pct

    assert _parse_sigma_pct("0.3,1.5,0.5") == pytest.approx({"length": 0.003, "width": 0.015, "height": 0.005})
    for bad in ("1,2", "a,b,c", "1,-1,1", "1,nan,1"):
        with pytest.raises(ConfigError, match="reconstruction-sigma-pct"):
            _parse_sigma_pct(bad)


def test_case_fields_and_real_size_with_scale(truck_ply, tmp_path, capsys):
    path, _ = truck_ply
    out = tmp_path / "case"
    assert main(["measure", str(path), "--out", str(out), "--scale", "8", "--case-id", "2026-0117", "--site", "G4 收费站",
                 "--operator", "Li Wei"]) == 0
    m = read_measurement(out)
    assert m["case"] == {"site": "G4 收费站", "operator": "Li Wei", "case_id": "2026-0117"}
    text = capsys.readouterr().out
    real = m["verdict"]["dimensions"]["length"]["value_m"]
    assert abs(real - 8 * m["length_m"]) < 1e-9 and f"{real:.3f} m" in text  # the size the verdict is about
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "2026-0117" in html and "G4 收费站" in html
