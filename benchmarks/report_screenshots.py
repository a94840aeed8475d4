"""Look at report.html as a person would: headless Chromium screenshots at desktop and phone width, and the printed PDF.

Usage:
    python benchmarks/report_screenshots.py OUT_DIR [--out SHOTS_DIR]

OUT_DIR is a run or measure output folder with report.html (e.g. out/run after ``stereo-recon run``).
Writes SHOTS_DIR (default OUT_DIR/screenshots): report-1280.png, report-420.png, report.pdf and
report-page-N.png (one PNG per printed page, via poppler's pdftoppm), and prints the page count.
Needs ``chromium`` (or ``chromium-browser``/``google-chrome``) and ``pdftoppm`` on the PATH
(Debian: ``apt-get install -y chromium fonts-noto-cjk poppler-utils``; the CJK font renders the
Chinese regulation title).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome")


def find_browser() -> str | None:
    """The first headless-capable Chromium on the PATH, or None."""
    return next((b for b in BROWSERS if shutil.which(b)), None)


def _chromium(browser: str, *args: str, timeout_s: float = 120.0) -> None:
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", *args]
    subprocess.run(cmd, check=True, capture_output=True, timeout=timeout_s)


def shoot(report: Path, shots: Path, browser: str) -> dict:
    """Screenshots at 1280 and 420 px wide, the printed PDF and its pages as PNG; returns their paths and page count."""
    shots.mkdir(parents=True, exist_ok=True)
    url = report.resolve().as_uri()
    out = {}
    for width, height in ((1280, 2400), (420, 2600)):
        png = shots / f"report-{width}.png"
        _chromium(browser, f"--window-size={width},{height}", f"--screenshot={png}", url)
        out[f"screen_{width}"] = png
    pdf = shots / "report.pdf"
    _chromium(browser, "--no-pdf-header-footer", f"--print-to-pdf={pdf}", url)
    out["pdf"] = pdf
    if shutil.which("pdftoppm"):
        for old in shots.glob("report-page-*.png"):
            old.unlink()
        subprocess.run(["pdftoppm", "-png", "-r", "80", str(pdf), str(shots / "report-page")], check=True, timeout=120)
        out["pages"] = sorted(shots.glob("report-page-*.png"))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out_dir", type=Path, help="folder with report.html")
    ap.add_argument("--out", type=Path, default=None, help="where the screenshots go (default: OUT_DIR/screenshots)")
    args = ap.parse_args(argv)
    report = args.out_dir / "report.html"
    if not report.is_file():
        print(f"{report}: no report (run `stereo-recon run --out {args.out_dir}` first)", file=sys.stderr)
        return 2
    browser = find_browser()
    if browser is None:
        print("no chromium on the PATH (apt-get install -y chromium fonts-noto-cjk poppler-utils)", file=sys.stderr)
        return 2
    res = shoot(report, args.out or args.out_dir / "screenshots", browser)
    for k, v in res.items():
        print(f"{k}: {', '.join(map(str, v)) if isinstance(v, list) else v}")
    if "pages" in res:
        print(f"printed pages: {len(res['pages'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
