"""Self-contained HTML report (measure/report_html.py)."""

from __future__ import annotations

import base64
import re
from html.parser import HTMLParser

import cv2
import numpy as np
import pytest

from measure.limits import load_regulation, over_limit_verdict
from measure.report_html import render_report_html

SHA = "0123456789abcdef" * 4


class _Tags(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.text.append(data)


def _parse(html_text):
    p = _Tags()
    p.feed(html_text)
    return p.tags, " ".join(p.text)


def _png(path, colour, size=(40, 60)):
    img = np.zeros((*size, 3), np.uint8)
    img[:] = colour
    cv2.imwrite(str(path), img)
    return path


def _measurement(dims, unc, **verdict_kw):
    reg = load_regulation(verdict_kw.pop("regulation", "cn-2016-62"))
    return {
        "length_m": dims["length"], "width_m": dims["width"], "height_m": dims["height"],
        "uncertainty_m": unc,
        "verdict": over_limit_verdict(dims, unc, reg, **verdict_kw),
        "rules": {"length": "rear peak to front extreme", "width": "distance between the two side peaks",
                  "height": "99.5th percentile of heights above the ground plane"},
        "parameters": {"eps_m": 0.08, "ground_thickness_m": 0.07},
        "versions": {"numpy": "2.x", "open3d": "0.20.0"},
        "input": {"path": "/data/truck cloud.ply", "sha256": SHA},
    }


def test_report_has_dimensions_verdict_rules_and_inlined_images(tmp_path):
    m = _measurement({"length": 16.2, "width": 2.61, "height": 3.95}, {"length": 0.05, "width": 0.01, "height": 0.04})
    imgs = {"top_view": _png(tmp_path / "top.png", (0, 0, 255)), "side_view": _png(tmp_path / "side.png", (0, 255, 0)),
            "width_density": _png(tmp_path / "w.png", (255, 0, 0))}
    out = render_report_html(m, imgs, tmp_path / "out" / "report.html", run_info={"video": "clip.avi", "versions": {"python": "3.11"}})
    assert out == tmp_path / "out" / "report.html"
    assert [p.name for p in out.parent.iterdir()] == ["report.html"]   # no temp file left behind
    text = out.read_text(encoding="utf-8")
    tags, visible = _parse(text)
    # dimensions with uncertainty, limits, per-dimension verdicts, overall banner
    for s in ("16.200", "2.610", "3.950", "0.050", "0.010", "0.040", "18.1", "2.55"):
        assert s in visible, s
    assert "OVER THE LIMIT" in visible
    verdict_cells = [a.get("class", "") for t, a in tags if t == "td" and "verdict" in a.get("class", "")]
    assert verdict_cells == ["verdict v-within", "verdict v-over", "verdict v-undecided"]
    assert "rear peak to front extreme" in visible and "distance between the two side peaks" in visible
    assert "Order 2016 No. 62" in visible and SHA in visible and "eps_m" in visible and "open3d" in visible
    # images are embedded byte for byte, in the documented order
    srcs = [a["src"] for t, a in tags if t == "img"]
    assert len(srcs) == 3 and all(s.startswith("data:image/png;base64,") for s in srcs)
    decoded = [base64.b64decode(s.split(",", 1)[1]) for s in srcs]
    assert decoded == [imgs[k].read_bytes() for k in ("top_view", "side_view", "width_density")]
    # printable, self-contained
    assert "@media print" in text
    assert not any(t in ("link", "iframe", "object", "embed") for t, _ in tags)
    for t, a in tags:
        for attr in ("src", "href"):
            assert not re.match(r"\s*(https?:)?//", a.get(attr) or "", re.I), (t, a)
    assert not re.search(r"url\(|@import", text)


def test_all_text_is_escaped(tmp_path):
    m = _measurement({"length": 12.0, "width": 2.5, "height": 3.8}, {"length": 0.02, "width": 0.01, "height": 0.01})
    m["rules"]["height"] = "<script>alert('rule')</script>"
    m["warnings"] = ["<img src=http://evil.example/x.png>"]
    m["parameters"]["<b>key</b>"] = "a&b"
    text = render_report_html(m, {}, tmp_path / "r.html").read_text(encoding="utf-8")
    assert "<script>alert" not in text and "&lt;script&gt;alert(&#x27;rule&#x27;)" in text
    assert "<img src=http" not in text
    assert "<b>key</b>" not in text and "&lt;b&gt;key&lt;/b&gt;" in text and "a&amp;b" in text
    tags, _ = _parse(text)
    assert not any(t == "script" for t, _ in tags)   # no script at all: the appendix stays collapsed in print
    assert "WITHIN THE LIMITS" in text


def test_model_scale_report_without_and_with_scale(tmp_path):
    dims, unc = {"length": 1.0, "width": 0.15, "height": 0.26}, {"length": 0.004, "width": 0.002, "height": 0.002}
    text = render_report_html(_measurement(dims, unc), {}, tmp_path / "a.html").read_text(encoding="utf-8")
    _, visible = _parse(text)
    assert "NO LEGAL VERDICT" in visible and "scale model" in visible
    assert "1.0000" in visible and "0.2600" in visible   # model sizes at 0.1 mm precision
    text = render_report_html(_measurement(dims, unc, scale=16.0), {}, tmp_path / "b.html").read_text(encoding="utf-8")
    _, visible = _parse(text)
    assert "OVER THE LIMIT" in visible and "16.000" in visible and "4.160" in visible and "16.0" in visible


def test_missing_or_non_image_plot_is_left_out_with_a_note(tmp_path):
    m = _measurement({"length": 12.0, "width": 2.5, "height": 3.8}, {"length": 0.02, "width": 0.01, "height": 0.01})
    bogus = tmp_path / "bogus.png"
    bogus.write_text("not a png")
    text = render_report_html(m, {"top_view": tmp_path / "absent.png", "extra_plot": bogus}, tmp_path / "r.html").read_text()
    tags, visible = _parse(text)
    assert not any(t == "img" for t, _ in tags)
    assert "top_view" in visible and "extra_plot" in visible and "left out" in visible


def test_partial_measurement_does_not_crash(tmp_path):
    text = render_report_html({"length_m": 12.0, "width_m": None, "height_m": float("nan")}, {}, tmp_path / "r.html").read_text()
    _, visible = _parse(text)
    assert "12.000" in visible and "NO VERDICT" in visible


@pytest.mark.parametrize("name", ["us-federal", "eu-96-53"])
def test_no_limit_dimensions_are_shown_as_such(tmp_path, name):
    m = _measurement({"length": 16.0, "width": 2.5, "height": 4.3}, {"length": 0.02, "width": 0.005, "height": 0.02}, regulation=name)
    _, visible = _parse(render_report_html(m, {}, tmp_path / "r.html").read_text())
    assert "no limit" in visible


def test_render_from_dir_picks_up_measurement_plots_and_run_json(tmp_path):
    import json

    from measure.report_html import render_report_from_dir
    from stereo_recon.core.errors import InputError

    with pytest.raises(InputError, match="measurement.json"):
        render_report_from_dir(tmp_path)
    m = _measurement({"length": 12.0, "width": 2.7, "height": 3.8}, {"length": 0.02, "width": 0.01, "height": 0.01})
    (tmp_path / "measurement.json").write_text(json.dumps(m))
    (tmp_path / "run.json").write_text(json.dumps({"command": "reconstruct", "inputs": {"video": {"path": "v.avi", "sha256": "f" * 64}}}))
    _png(tmp_path / "side_view.png", (0, 255, 0))
    _png(tmp_path / "top_view.png", (0, 0, 255))
    out = render_report_from_dir(tmp_path)
    assert out == tmp_path / "report.html"
    tags, visible = _parse(out.read_text())
    srcs = [a["src"] for t, a in tags if t == "img"]
    assert [base64.b64decode(s.split(",", 1)[1]) for s in srcs] == [(tmp_path / n).read_bytes() for n in ("top_view.png", "side_view.png")]
    assert "OVER THE LIMIT" in visible and "f" * 64 in visible and SHA in visible


def test_report_for_an_officer_first_page_evidence_and_signed_margins(tmp_path):
    # length 0.2 m over the 18.1 m limit, tight uncertainty: an unambiguous 'over by 0.200 m'
    m = _measurement({"length": 18.3, "width": 2.40, "height": 3.9}, {"length": 0.02, "width": 0.01, "height": 0.01})
    m["case"] = {"case_id": "2026-0117", "site": "G4 收费站 12", "operator": "Li Wei"}
    m["recording"] = {"video": {"path": "/flights/truck7.mp4", "sha256": "a" * 64},
                      "calib": {"path": "/calib/SN28000001.conf", "sha256": "b" * 64},
                      "recorded": "2026-11-20 09:41:07", "source": "container metadata (creation date)",
                      "keyframe": {"frame": 120, "time_s": 8.0}}
    m["data_quality"] = {"ok": False, "checks": [{"name": "ground_visible", "status": "pass", "detail": "62 % ground"},
                                                 {"name": "coverage", "status": "fail", "detail": "one side never seen"}]}
    imgs = {"keyframe": _png(tmp_path / "kf.png", (10, 200, 10)), "top_view": _png(tmp_path / "top.png", (0, 0, 255))}
    text = render_report_html(m, imgs, tmp_path / "r.html").read_text(encoding="utf-8")
    tags, visible = _parse(text)
    visible = " ".join(visible.replace("\xa0", " ").split())
    for s in ("2026-0117", "G4 收费站 12", "Li Wei", "truck7.mp4", "a" * 64, "SN28000001.conf", "b" * 64,
              "2026-11-20 09:41:07", "frame 120", "over by 0.200 m", "0.150 m under", "coverage", "one side never seen"):
        assert s in visible, s
    assert "FAILED" in visible  # the data-quality verdict
    # the keyframe comes with the recording, before the plots, which start a new printed page
    srcs = [a["src"] for t, a in tags if t == "img"]
    assert base64.b64decode(srcs[0].split(",", 1)[1]) == imgs["keyframe"].read_bytes()
    assert text.index("Recording") < text.index("class='newpage'>Plots") < text.index("Appendix")
    # appendix collapsed (no 'open'), CJK-capable font stack, a layout for phone widths
    assert [a for t, a in tags if t == "details"] and not any("open" in a for t, a in tags if t == "details")
    assert '"Noto Sans CJK SC"' in text and "Microsoft YaHei" in text and "@media (max-width: 700px)" in text
    assert all("data-label" in a for t, a in tags if t == "td" and "verdict" in a.get("class", ""))


def test_data_quality_absent_reads_not_assessed(tmp_path):
    m = _measurement({"length": 12.0, "width": 2.5, "height": 3.8}, {"length": 0.02, "width": 0.01, "height": 0.01})
    _, visible = _parse(render_report_html(m, {}, tmp_path / "r.html").read_text())
    assert "not assessed" in visible


@pytest.mark.slow
def test_printed_report_finding_on_page_one(tmp_path):
    """Headless Chromium prints the report: the finding is on page 1, the whole report on a few pages."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from report_screenshots import find_browser, shoot

    browser = find_browser()
    if browser is None or not shutil.which("pdftotext"):
        pytest.skip("needs chromium and poppler-utils (apt-get install -y chromium fonts-noto-cjk poppler-utils)")
    m = _measurement({"length": 18.3, "width": 2.40, "height": 3.9}, {"length": 0.02, "width": 0.01, "height": 0.01})
    m["parameters"] = {f"p{i}": list(range(40)) for i in range(60)}  # a long appendix must stay collapsed
    imgs = {k: _png(tmp_path / f"{k}.png", (0, 0, 200), size=(500, 900)) for k in ("top_view", "side_view", "width_density")}
    report = render_report_html(m, imgs, tmp_path / "report.html")
    res = shoot(report, tmp_path / "shots", browser)
    page1 = subprocess.run(["pdftotext", "-f", "1", "-l", "1", str(res["pdf"]), "-"], capture_output=True, text=True).stdout
    page1 = " ".join(page1.replace("\xa0", " ").split())
    assert "OVER THE LIMIT" in page1 and "over by 0.200" in page1
    assert len(res["pages"]) <= 3
    assert res["screen_420"].stat().st_size > 0 and res["screen_1280"].stat().st_size > 0
