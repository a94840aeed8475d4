"""A self-contained, printable HTML report of one truck measurement, for an enforcement officer.

One file, no external resources: CSS is inline, PNG plots are embedded as base64 data URIs,
every text from the measurement is HTML-escaped. The file is written atomically.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import math
import os
import time
from pathlib import Path
from typing import Any, Mapping

from stereo_recon.core.errors import InputError
from stereo_recon.core.atomic import write_text_atomic
from stereo_recon.core.manifest import to_jsonable
from stereo_recon.core.paths import RunPaths

log = logging.getLogger(__name__)

DIMENSIONS = ("length", "width", "height")
# The full measurement record is embedded for reference; beyond this it is cut (it stays in measurement.json).
_MAX_RECORD_CHARS = 200_000

# verdict -> (css class, banner text, table text)
_VERDICT_STYLE = {
    "over": ("v-over", "OVER THE LIMIT", "over"),
    "within": ("v-within", "WITHIN THE LIMITS", "within"),
    "undecided": ("v-undecided", "UNDECIDED: a limit lies inside the measurement uncertainty", "undecided"),
    "not-applicable": ("v-na", "NO LEGAL VERDICT", "n/a"),
    "no-limit": ("v-na", "NO LIMIT SET", "no limit"),
    "not-measured": ("v-undecided", "NOT MEASURED", "not measured"),
}

# image keys shown first, in this order, with their captions; other keys follow alphabetically
_IMAGE_ORDER = {
    "top_view": "Top view: points on the ground plane and the fitted rectangle",
    "side_view": "Side view: points above the fitted ground and the height",
    "width_density": "Density along the width axis (the paper's Fig. 5): width = distance between the two side peaks",
    "length_density": "Density along the length axis (the paper's Fig. 6): length = rear peak to front extreme",
}

_CSS = """
:root { --over:#b71c1c; --within:#1b5e20; --undecided:#e65100; --na:#455a64; --line:#cfd8dc; }
* { box-sizing: border-box; }
/* CJK-capable stack: the Chinese regulation title must not print as empty boxes. */
body { font-family: system-ui, -apple-system, "Segoe UI", "Noto Sans", "Noto Sans CJK SC", "Noto Sans SC",
       "Source Han Sans SC", "Microsoft YaHei", "PingFang SC", "WenQuanYi Micro Hei", Helvetica, Arial, sans-serif;
       color:#212121; margin:0 auto; max-width:1100px; padding:24px; line-height:1.4; }
h1 { font-size:1.6em; margin:0 0 4px 0; } h2 { font-size:1.2em; margin:22px 0 8px 0; border-bottom:2px solid var(--line); }
.meta { color:#546e7a; font-size:0.92em; } .mono { font-family: ui-monospace, Consolas, "DejaVu Sans Mono", monospace; word-break: break-all; }
.case { display:flex; flex-wrap:wrap; gap:4px 24px; margin:8px 0; }
.banner { margin:14px 0; padding:14px 18px; border-radius:6px; color:#fff; font-size:1.5em; font-weight:700; }
.banner .reason { display:block; font-size:0.6em; font-weight:400; margin-top:4px; }
.banner.v-over { background:var(--over); } .banner.v-within { background:var(--within); }
.banner.v-undecided { background:var(--undecided); } .banner.v-na { background:var(--na); }
table { border-collapse:collapse; width:100%; }
th, td { border:1px solid var(--line); padding:6px 10px; text-align:left; vertical-align:top; }
th { background:#eceff1; }
table.dims td.num { font-size:1.2em; font-weight:600; }  /* "value m ± u m" may wrap at the ±, never inside a number */
table.dims td.small { overflow-wrap:anywhere; }  /* rule names are long single words: wrap, stay inside the page */
td.verdict { font-weight:700; text-transform:uppercase; white-space:nowrap; }
td.v-over { color:#fff; background:var(--over); } td.v-within { color:#fff; background:var(--within); }
td.v-undecided { color:#fff; background:var(--undecided); } td.v-na { color:#fff; background:var(--na); }
td.over { color:var(--over); font-weight:700; }
.small { font-size:0.88em; color:#455a64; }
.warn { border-left:5px solid var(--undecided); background:#fff3e0; padding:8px 12px; margin:10px 0; }
.dq-pass { color:var(--within); font-weight:700; } .dq-warn { color:var(--undecided); font-weight:700; }
.dq-fail { color:var(--over); font-weight:700; }
.evidence { display:flex; flex-wrap:wrap; gap:16px; align-items:flex-start; }
.evidence table { flex:1 1 340px; } .evidence figure { flex:1 1 340px; margin:0; }
.plots { display:flex; flex-wrap:wrap; gap:12px; } .plots figure { flex:1 1 420px; }
figure { margin:12px 0; page-break-inside:avoid; break-inside:avoid; }
figure img { max-width:100%; height:auto; border:1px solid var(--line); }
figcaption { font-size:0.9em; color:#455a64; }
details { margin:10px 0; border:1px solid var(--line); border-radius:4px; padding:6px 10px; }
summary { cursor:pointer; font-weight:600; }
pre { white-space:pre-wrap; word-break:break-all; font-size:0.82em; background:#fafafa; padding:8px; }
footer { margin-top:30px; font-size:0.8em; color:#78909c; }
/* Phone width: one card per dimension, every cell labelled; nothing off-screen. */
@media (max-width: 700px) {
  body { padding:10px; }
  table.dims tr.head { display:none; }
  table.dims, table.dims tbody, table.dims tr, table.dims td { display:block; width:100%; }
  table.dims tr { margin-bottom:10px; border:1px solid var(--line); }
  table.dims td { border:none; border-bottom:1px solid #eceff1; white-space:normal; }
  table.dims td[data-label]::before { content:attr(data-label) ": "; font-weight:400; font-size:0.75rem;
                                       color:#546e7a; text-transform:none; }
}
@media print {
  @page { size:A4; margin:12mm; }
  body { max-width:none; padding:0; font-size:9.5pt; }
  .banner, td.verdict, th, td.over { -webkit-print-color-adjust:exact; print-color-adjust:exact; }
  h2 { page-break-after:avoid; break-after:avoid; margin-top:12px; }
  table.dims, .banner, .evidence { page-break-inside:avoid; break-inside:avoid; }
  .evidence figure img { max-height:62mm; width:auto; }
  .newpage { page-break-before:always; break-before:page; }
  .plots figure { flex:1 1 45%; } .plots figure img { max-height:60mm; width:auto; }
  table.dims td.num { font-size:1.05em; white-space:nowrap; }
  details { border:none; padding:0; margin:4px 0; } footer { margin-top:10px; break-before:avoid; page-break-before:avoid; }
}
"""


def _e(value: Any) -> str:
    """HTML-escaped text of any value."""
    return html.escape("" if value is None else str(value), quote=True)


def _num(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _fmt_m(v: Any, decimals: int = 3) -> str:
    f = _num(v)
    return "&ndash;" if f is None else f"{f:.{decimals}f}&nbsp;m"


def _decimals(*values: Any) -> int:
    """3 decimals (mm) for road vehicles, 4 for scale models."""
    vs = [abs(f) for f in map(_num, values) if f is not None]
    return 4 if vs and max(vs) < 4.0 else 3


def _image_data_uri(path: Path) -> str | None:
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        log.warning("report: cannot read image %s (%s); left out", path, err)
        return None
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        mime = "image/png"
    elif data.startswith(b"\xff\xd8\xff"):
        mime = "image/jpeg"
    else:
        log.warning("report: %s is not a PNG or JPEG image; left out", path)
        return None
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def _find_sha256(measurement: Mapping, run_info: Mapping) -> list[tuple[str, str, str]]:
    """(label, path, sha256) of the inputs, from the places the measure/run stages record them."""
    found: list[tuple[str, str, str]] = []
    for src in (measurement, run_info):
        for key in ("input", "cloud"):
            item = src.get(key)
            if isinstance(item, Mapping) and item.get("sha256"):
                found.append((key, str(item.get("path", "")), str(item["sha256"])))
        if src.get("input_sha256"):
            path = src.get("input_path") or src.get("input")
            found.append(("input", "" if isinstance(path, Mapping) or path is None else str(path), str(src["input_sha256"])))
        inputs = src.get("inputs")
        if isinstance(inputs, Mapping):
            for name, item in inputs.items():
                if isinstance(item, Mapping) and item.get("sha256"):
                    found.append((str(name), str(item.get("path", "")), str(item["sha256"])))
    seen, out = set(), []
    for row in found:
        if row[2] not in seen:
            seen.add(row[2])
            out.append(row)
    return out


def _rule_text(rule: Any) -> str:
    if rule is None:
        return ""
    if isinstance(rule, Mapping):
        return "; ".join(f"{k}: {v}" for k, v in rule.items())
    return str(rule)


def _kv_table(d: Mapping) -> str:
    rows = []
    for k, v in d.items():
        if isinstance(v, (Mapping, list, tuple)):
            val = f"<pre>{_e(json.dumps(to_jsonable(v), indent=2, ensure_ascii=False))}</pre>"
        else:
            val = _e(v)
        rows.append(f"<tr><th>{_e(k)}</th><td class='mono'>{val}</td></tr>")
    return "<table>" + "".join(rows) + "</table>" if rows else "<p class='small'>none recorded</p>"


def _fmt_limit(lim: float) -> str:
    return f"{lim:.4f}".rstrip("0").rstrip(".") + "&nbsp;m"


def _limit_text(value: float | None, limit: float | None, dec: int) -> tuple[str, str]:
    """('over by 0.200 m' | '0.150 m under', css class) of an assessed value against its limit."""
    if value is None or limit is None:
        return "&ndash;", ""
    excess = value - limit
    if excess > 0:
        return f"over by {excess:.{dec}f}&nbsp;m", "over"
    return f"{-excess:.{dec}f}&nbsp;m under", ""


def _dimension_rows(measurement: Mapping, verdict: Mapping) -> tuple[str, bool]:
    vdims = verdict.get("dimensions") or {}
    unc = measurement.get("uncertainty_m") or {}
    rules = measurement.get("rules") or {}
    scale = _num(verdict.get("scale"))
    k = _num(verdict.get("k_sigma"))
    # one precision per column set: mm for road vehicles, 0.1 mm for scale models
    dec_measured = _decimals(measurement.get("length_m"))
    dec_assessed = _decimals((vdims.get("length") or {}).get("value_m"))
    rows = []
    for d in DIMENSIONS:
        v = measurement.get(f"{d}_m")
        u = unc.get(d) if isinstance(unc, Mapping) else None
        vd = vdims.get(d) or {}
        status = vd.get("verdict") or ("not-applicable" if verdict.get("overall") == "not-applicable" else "")
        css, _, label = _VERDICT_STYLE.get(status, ("v-na", "", status))
        measured = _fmt_m(v, dec_measured) + (f" &plusmn; {_fmt_m(u, dec_measured)}" if _num(u) is not None else "")
        cells = [f"<td><b>{_e(d.capitalize())}</b></td>", f"<td class='num' data-label='Measured'>{measured}</td>"]
        assessed_v, assessed_u = _num(vd.get("value_m")), _num(vd.get("uncertainty_m"))
        if scale is not None:
            sv = _fmt_m(assessed_v, dec_assessed)
            if assessed_u is not None:
                sv += f" &plusmn; {_fmt_m(assessed_u, dec_assessed)}"
            cells.append(f"<td class='num' data-label='Real size'>{sv}</td>")
        if assessed_v is not None and assessed_u is not None and k is not None:
            interval = f"{assessed_v - k * assessed_u:.{dec_assessed}f} &ndash; {assessed_v + k * assessed_u:.{dec_assessed}f}&nbsp;m"
        else:
            interval = "&ndash;"
        lim = _num(vd.get("limit_m"))
        cells.append(f"<td data-label='Interval'>{interval}</td>")
        cells.append(f"<td data-label='Limit'>{_fmt_limit(lim) if lim is not None else 'no limit'}</td>")
        # Signed as a person reads it: 'over by 0.200 m' (value above the limit), '0.150 m under'.
        text, over = _limit_text(assessed_v if status != "not-applicable" else None, lim, dec_assessed)
        cells.append(f"<td class='{over}' data-label='Against the limit'>{text}</td>")
        cells.append(f"<td class='verdict {css}' data-label='Verdict'>{_e(label) if label else '&ndash;'}</td>")
        rule = _rule_text(rules.get(d) if isinstance(rules, Mapping) else None)
        cells.append(f"<td class='small' data-label='How it was measured'>{_e(rule) if rule else '&ndash;'}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return "".join(rows), scale is not None


def _case_block(measurement: Mapping, created: str, source_name: str) -> str:
    """Case id, site, operator (as given on the command line), report time and input name."""
    case = measurement.get("case") if isinstance(measurement.get("case"), Mapping) else {}
    items = [("Case", case.get("case_id")), ("Site", case.get("site")), ("Operator", case.get("operator")),
             ("Report created", created), ("Input", Path(str(source_name)).name if source_name else None)]
    return "<div class='case meta'>" + "".join(f"<span><b>{_e(a)}:</b> {_e(b)}</span>" for a, b in items if b) + "</div>"


def _data_quality_block(measurement: Mapping) -> str:
    """The data-quality checks (measurement.json 'data_quality'); 'not assessed' for records without them."""
    dq = measurement.get("data_quality")
    if not isinstance(dq, Mapping):
        return "<p class='small'><b>Data quality:</b> not assessed (this measurement record carries no data-quality checks).</p>"
    checks = [c for c in (dq.get("checks") or []) if isinstance(c, Mapping)]
    head = "passed" if dq.get("ok") else "FAILED: the verdict cannot rest on this recording"
    rows = "".join(f"<tr><td>{_e(c.get('name'))}</td><td class='dq-{_e(c.get('status'))}'>{_e(c.get('status'))}</td>"
                   f"<td>{_e(c.get('detail'))}</td></tr>" for c in checks)
    table = f"<table><tr><th>Check</th><th>Status</th><th>Detail</th></tr>{rows}</table>" if rows else ""
    return f"<p><b>Data quality:</b> <span class='{'dq-pass' if dq.get('ok') else 'dq-fail'}'>{_e(head)}</span></p>{table}"


def _recording_block(measurement: Mapping, run_info: Mapping, image_paths: Mapping) -> str:
    """Source video and calibration with sha256, the recording's date/time, and the keyframe with the box."""
    rec = measurement.get("recording") if isinstance(measurement.get("recording"), Mapping) else {}
    inputs = run_info.get("inputs") if isinstance(run_info.get("inputs"), Mapping) else {}
    rows = []
    for key, label in (("video", "Source video"), ("calib", "Calibration")):
        item = rec.get(key) or inputs.get(key)
        if isinstance(item, Mapping) and item.get("path"):
            rows.append((label, f"{_e(item['path'])}<br><span class='small'>SHA-256 {_e(item.get('sha256') or 'not recorded')}</span>"))
        elif isinstance(run_info.get(key), str):
            rows.append((label, _e(run_info[key])))
    if rec.get("recorded"):
        rows.append(("Recorded", f"{_e(rec['recorded'])} <span class='small'>({_e(rec.get('source'))})</span>"))
    elif rec:
        rows.append(("Recorded", f"not in the video's container; file last modified {_e(rec.get('file_modified_utc'))}"))
    cloud = measurement.get("input") if isinstance(measurement.get("input"), Mapping) else {}
    if cloud.get("sha256"):
        rows.append(("Point cloud", f"{_e(cloud.get('path'))}<br><span class='small'>SHA-256 {_e(cloud['sha256'])}</span>"))
    if not rows:
        return ""
    table = "<table class='kv'>" + "".join(f"<tr><th>{_e(a)}</th><td class='mono'>{b}</td></tr>" for a, b in rows) + "</table>"
    fig = ""
    if "keyframe" in image_paths:
        uri = _image_data_uri(Path(image_paths["keyframe"]))
        kf = rec.get("keyframe") if isinstance(rec.get("keyframe"), Mapping) else {}
        when = f" (frame {kf['frame']}, {float(kf['time_s']):.2f} s into the video)" if kf.get("frame") is not None else ""
        if uri:
            fig = (f"<figure><img src='{uri}' alt='video frame with the measured box'><figcaption>The measured box "
                   f"projected into the video{_e(when)}: roof edges amber, the rest red.</figcaption></figure>")
    return f"<h2>Recording</h2><div class='evidence'>{table}{fig}</div>"


def render_report_html(
    measurement: Mapping[str, Any],
    image_paths: Mapping[str, str | os.PathLike],
    out_path: str | os.PathLike,
    run_info: Mapping[str, Any] | None = None,
) -> Path:
    """Write one self-contained HTML report of a truck measurement and return its path.

    Page 1 (printed): case fields, verdict, dimensions, data quality, the recording (video and calibration with
    sha256, date/time, keyframe with the box); then the plots; then regulation, provenance and a collapsed appendix
    (parameters, versions, run, the raw record).

    measurement: the measure stage's result (the content of measurement.json): ``length_m``,
        ``width_m``, ``height_m``, ``uncertainty_m`` {length, width, height}, ``verdict`` (from
        :func:`measure.limits.over_limit_verdict`), optionally ``rules``, ``parameters``, ``versions``,
        ``input`` {path, sha256}, ``recording``, ``case``, ``data_quality``, ``warnings`` and anything else.
    image_paths: plot name -> PNG/JPEG file (``keyframe`` goes with the recording, the rest under Plots);
        embedded as base64 (unreadable files are left out with a note).
    out_path: HTML file to write (atomically).
    run_info: optional job information (run.json: inputs with sha256, versions, ...).
    """
    run_info = dict(run_info or {})
    verdict = measurement.get("verdict") or {}
    if not isinstance(verdict, Mapping):
        verdict = {"overall": str(verdict)}
    overall = str(verdict.get("overall") or "")
    css, banner_text, _ = _VERDICT_STYLE.get(overall, ("v-na", overall.upper() or "NO VERDICT", overall))
    reg = verdict.get("regulation") or {}
    created = run_info.get("created_utc") or measurement.get("created_utc") or time.strftime("%Y-%m-%d %H:%M:%SZ", time.gmtime())
    sha_rows = _find_sha256(measurement, run_info)
    rec_video = (measurement.get("recording") or {}).get("video") if isinstance(measurement.get("recording"), Mapping) else None
    source_name = ((rec_video or {}).get("path") if isinstance(rec_video, Mapping) else None) or run_info.get("video") \
        or measurement.get("input_path") or (sha_rows[0][1] if sha_rows else "")

    parts: list[str] = []
    add = parts.append
    title = "Truck dimension measurement"
    add("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>")
    add("<meta name='viewport' content='width=device-width, initial-scale=1'>")
    add(f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>")
    add(f"<h1>{_e(title)}</h1>")
    add(_case_block(measurement, created, str(source_name)))
    add(f"<div class='banner {css}'>{_e(banner_text)}<span class='reason'>{_e(verdict.get('reason') or '')}</span></div>")
    if reg:
        add(f"<p class='small'><b>Regulation:</b> {_e(reg.get('name', ''))}: {_e(reg.get('title', ''))}</p>")
    add(_dimensions_block(measurement, verdict))
    add(_data_quality_block(measurement))
    add(_recording_block(measurement, run_info, image_paths))
    add(_plots_block(image_paths))
    add(_regulation_block(verdict, reg))
    add(_provenance_block(measurement, run_info, sha_rows))
    add("<footer>stereo-recon: truck outer dimensions from drone stereo video. "
        "The verdict compares the measurement interval with the regulation's limits; a legal decision "
        "remains with the officer.</footer></body></html>")
    return write_text_atomic(Path(out_path), "\n".join(parts))


def _dimensions_block(measurement: Mapping, verdict: Mapping) -> str:
    rows, scaled = _dimension_rows(measurement, verdict)
    k = _num(verdict.get("k_sigma"))
    head = ["Dimension", "Measured (&plusmn; 1&sigma;)"]
    if scaled:
        head.append(f"Real size (scale &times;{_e(verdict.get('scale'))})")
    head += [f"Interval (&plusmn; {_e(f'{k:g}') if k is not None else 'k'}&sigma;)", "Limit", "Against the limit",
             "Verdict", "How it was measured"]
    out = ["<table class='dims'><tr class='head'>" + "".join(f"<th>{h}</th>" for h in head) + f"</tr>{rows}</table>",
           "<p class='small'>Over: the whole interval lies above the limit. Within: the whole interval is at or "
           "below the limit. Undecided: the limit lies inside the interval.</p>"]
    u_parts = measurement.get("uncertainty_parts")
    if isinstance(u_parts, Mapping) and isinstance(u_parts.get("reconstruction_rel_sigma"), Mapping):
        rel = u_parts["reconstruction_rel_sigma"]
        shares = ", ".join(f"{_e(d)} {100 * float(rel.get(d, 0.0)):.2f}&nbsp;%" for d in DIMENSIONS)
        depth = u_parts.get("reconstruction_depth_m")
        depth_txt = ""
        if isinstance(depth, Mapping):
            depth_txt = (" and the depth geometry's share (how finely the stereo baseline resolves depth at this range: "
                         + ", ".join(f"{_e(d)} {1000 * float(depth.get(d, 0.0)):.0f}&nbsp;mm" for d in DIMENSIONS) + ")")
        out.append("<p class='small'>&sigma; combines the measurement's own uncertainty (bootstrap, point spacing, noise) "
                   f"with the reconstruction's validated relative error ({shares} of each dimension){depth_txt}.</p>")
    warnings = measurement.get("warnings") or []
    for w in [warnings] if isinstance(warnings, str) else warnings:
        out.append(f"<div class='warn'>{_e(w)}</div>")
    return "".join(out)


def _plots_block(image_paths: Mapping) -> str:
    keys = [k for k in _IMAGE_ORDER if k in image_paths] + sorted(k for k in image_paths if k not in _IMAGE_ORDER and k != "keyframe")
    if not keys:
        return ""
    out = ["<h2 class='newpage'>Plots</h2><div class='plots'>"]
    for key in keys:
        uri = _image_data_uri(Path(image_paths[key]))
        caption = _IMAGE_ORDER.get(key, key.replace("_", " "))
        if uri is None:
            out.append(f"<div class='warn'>Plot '{_e(key)}' could not be read and is left out.</div>")
            continue
        out.append(f"<figure><img src='{uri}' alt='{_e(caption)}'><figcaption>{_e(caption)}</figcaption></figure>")
    return "".join(out) + "</div>"


def _regulation_block(verdict: Mapping, reg: Mapping) -> str:
    if not reg:
        return "<h2>Regulation applied</h2><p class='small'>No regulation was applied.</p>"
    rows = {
        "Regulation": f"{reg.get('name', '')}: {reg.get('title', '')}",
        "Source": reg.get("source", ""),
        "Vehicle class": f"{verdict.get('vehicle_class', '')}"
        + (f" ({verdict.get('class_description')})" if verdict.get("class_description") else "")
        + (" (the table's default class)" if verdict.get("class_is_default") else ""),
    }
    if verdict.get("class_citation"):
        rows["Citation"] = verdict["class_citation"]
    if reg.get("notes"):
        rows["Notes"] = reg["notes"]
    rows["Coverage factor k"] = verdict.get("k_sigma", "")
    rows["Model-to-real scale"] = "none (measured size taken as real size)" if verdict.get("scale") is None else verdict.get("scale")
    return ("<h2>Regulation applied</h2><table class='kv'>"
            + "".join(f"<tr><th>{_e(a)}</th><td>{_e(b)}</td></tr>" for a, b in rows.items()) + "</table>")


def _provenance_block(measurement: Mapping, run_info: Mapping, sha_rows: list) -> str:
    # The recording's files and checksums are on page 1; every input the stages recorded is listed here.
    out = ["<h2>Appendix</h2><p class='small'>Collapsed here and in print; open a section on screen, or read measurement.json.</p>"]
    if sha_rows:
        out.append("<details><summary>Provenance: every input with its SHA-256</summary><table><tr><th>Input</th><th>File</th>"
                   "<th>SHA-256</th></tr>"
                   + "".join(f"<tr><td>{_e(a)}</td><td class='mono'>{_e(b)}</td><td class='mono'>{_e(c)}</td></tr>" for a, b, c in sha_rows)
                   + "</table></details>")
    else:
        out.append("<p class='small'>No input checksum recorded.</p>")
    params = measurement.get("parameters") or measurement.get("config")
    if params:
        out.append(f"<details><summary>Parameters used</summary>{_kv_table(params) if isinstance(params, Mapping) else '<pre>' + _e(params) + '</pre>'}</details>")
    versions = measurement.get("versions") or run_info.get("versions")
    if versions:
        out.append(f"<details><summary>Software versions</summary>{_kv_table(versions) if isinstance(versions, Mapping) else '<pre>' + _e(versions) + '</pre>'}</details>")
    if run_info:
        out.append(f"<details><summary>Run</summary>{_kv_table({k: v for k, v in run_info.items() if k != 'versions'})}</details>")
    record = json.dumps(to_jsonable(measurement), indent=2, ensure_ascii=False)
    if len(record) > _MAX_RECORD_CHARS:
        record = record[:_MAX_RECORD_CHARS] + f"\n... ({len(record) - _MAX_RECORD_CHARS:,} more characters in measurement.json)"
    out.append(f"<details><summary>Full measurement record (measurement.json)</summary><pre>{_e(record)}</pre></details>")
    return "".join(out)


def render_report_from_dir(run_dir: str | os.PathLike, out_path: str | os.PathLike | None = None,
                           run_info: Mapping[str, Any] | None = None) -> Path:
    """Render ``report.html`` from an output folder: its measurement.json, every PNG in it, and run info.

    run_dir: folder holding ``measurement.json`` and the plots (``<name>.png``; the name is the
        plot's key, e.g. ``top_view.png``).
    out_path: HTML file to write; default ``run_dir/report.html``.
    run_info: job information; default: ``run.json`` (reconstruction manifest) of the folder, if any.
    Raises InputError when measurement.json is missing or unreadable.
    """
    run_dir = Path(run_dir)
    mpath = RunPaths(run_dir).measurement
    try:
        measurement = json.loads(mpath.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{mpath}: no measurement to report (run the measure stage first)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"{mpath}: cannot read measurement ({err})") from err
    if not isinstance(measurement, dict):
        raise InputError(f"{mpath}: not a measurement record (expected a JSON object)")
    if run_info is None:
        run_info = {}
        rpath = RunPaths(run_dir).run_json
        if rpath.is_file():
            try:
                loaded = json.loads(rpath.read_text(encoding="utf-8"))
                run_info = loaded if isinstance(loaded, dict) else {}
            except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
                log.warning("report: ignoring unreadable %s (%s)", rpath, err)
    images = {p.stem: p for p in sorted(run_dir.glob("*.png"))}
    return render_report_html(measurement, images, out_path if out_path is not None else RunPaths(run_dir).report, run_info)
