"""Many recordings at once: a local process pool by default, or a Ray cluster (``batch_ray``).

One failed job is recorded with its error and does not stop the others; results are reported
as they finish. The same machinery runs ``bench``. ``summary.csv`` (one typed row per recording)
is written here too.
"""

from __future__ import annotations

import concurrent.futures as cf
import csv
import json
import logging
import math
import multiprocessing as mp
import os
from pathlib import Path
from typing import Callable, Sequence

from stereo_recon.app.jobs import Job, call_job, resolve_job
from stereo_recon.core.errors import ConfigError
from stereo_recon.core.paths import RunPaths
from stereo_recon.core.atomic import write_atomic

log = logging.getLogger(__name__)


def run_jobs(jobs: Sequence[Job], workers: int | None = 1, executor: str = "local",
             progress: Callable[[dict], None] | None = None, ray_options=None) -> list[dict]:
    """Run jobs; ``progress`` sees each result as it finishes; returns the results in the order given.

    Parameters
    ----------
    workers : processes (local; None = 1, 1 runs in this process) or, on Ray, the most jobs
        submitted at once (None: all; a local Ray instance then gets this many job slots).
    executor : ``'local'`` (process pool) or ``'ray'`` (the ``ray`` extra; see ``batch_ray``).
    ray_options : :class:`stereo_recon.app.batch_ray.RayOptions` (address, resources per job, input shipping).
    """
    if executor not in {"local", "ray"}:
        raise ConfigError(f"--executor: unknown executor '{executor}' (use local or ray)")
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers: must be >= 1, got {workers}")
    jobs = [resolve_job(j) for j in jobs]
    if executor == "ray":
        from stereo_recon.app.batch_ray import RayOptions, run_jobs_ray

        return run_jobs_ray(jobs, ray_options or RayOptions(), workers=workers, progress=progress)
    results: dict[int, dict] = {}
    workers = workers or 1
    if workers <= 1 or len(jobs) <= 1:
        for i, job in enumerate(jobs):
            results[i] = call_job(job)
            if progress:
                progress(results[i])
    else:
        # 'spawn' keeps workers free of the parent's threads (Open3D/OpenCV pools).
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
            futs = {pool.submit(call_job, job): i for i, job in enumerate(jobs)}
            for fut in cf.as_completed(futs):
                i = futs[fut]
                results[i] = fut.result()
                if progress:
                    progress(results[i])
    return [results[i] for i in range(len(jobs))]


# summary.csv: one row per recording, keyed by the video's absolute path. Lengths in metres to the
# millimetre, booleans as true/false, empty cells for what a failed job could not give.
SUMMARY_COLUMNS = ("video", "name", "ok", "length_m", "width_m", "height_m", "u_length_m", "u_width_m", "u_height_m",
                   "regulation", "vehicle_class", "verdict", "data_quality_ok", "warnings", "video_sha256", "time_s",
                   "host", "out_dir", "error")


def _mm(value) -> str:
    """Metres rounded to the millimetre ('' for missing / non-finite)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return ""
    return f"{v:.3f}" if math.isfinite(v) else ""


def _bool(value) -> str:
    return "" if value is None else ("true" if value else "false")


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _video_sha256(result: dict, out_dir: Path | None) -> str:
    """The video's sha256 as the run recorded it (run.json), else hashed here if the file is readable."""
    from stereo_recon.core.manifest import sha256_file

    if out_dir is not None:
        recorded = _read_json(RunPaths(out_dir).run_json).get("inputs", {}).get("video", {})
        if isinstance(recorded, dict) and recorded.get("sha256"):
            return recorded["sha256"]
    video = result.get("video")
    try:
        return sha256_file(video) if video and Path(video).is_file() else ""
    except OSError:
        return ""


def summary_row(result: dict) -> dict:
    """One typed row of summary.csv from a job result (and its measurement.json when present)."""
    out_dir = Path(result["out_dir"]) if result.get("out_dir") else None
    m = _read_json(RunPaths(out_dir).measurement) if out_dir is not None and result.get("ok") else {}
    unc = result.get("uncertainty_m") or {}
    verdict = result.get("verdict") if isinstance(result.get("verdict"), dict) else {}
    reg = verdict.get("regulation")
    dq = m.get("data_quality") if isinstance(m.get("data_quality"), dict) else {}
    warnings = m.get("warnings") or []
    return {
        "video": result.get("video") or "",
        "name": result.get("name") or "",
        "ok": _bool(bool(result.get("ok"))),
        "length_m": _mm(result.get("length_m")),
        "width_m": _mm(result.get("width_m")),
        "height_m": _mm(result.get("height_m")),
        "u_length_m": _mm(unc.get("length")),
        "u_width_m": _mm(unc.get("width")),
        "u_height_m": _mm(unc.get("height")),
        "regulation": (reg.get("name") if isinstance(reg, dict) else reg) or "",
        "vehicle_class": verdict.get("vehicle_class") or "",
        "verdict": verdict.get("overall") or "",
        "data_quality_ok": _bool(dq.get("ok")),
        "warnings": "; ".join(" ".join(str(w).split()) for w in warnings) if isinstance(warnings, list) else str(warnings),
        "video_sha256": _video_sha256(result, out_dir),
        "time_s": f"{float(result.get('time_s') or 0.0):.1f}",
        "host": result.get("host") or "",
        "out_dir": str(out_dir) if out_dir is not None else "",
        "error": result.get("error") or "",
    }


def write_summary_csv(path: str | os.PathLike, results: Sequence[dict], merge: bool = False) -> Path:
    """Write summary.csv atomically, one row per job.

    merge : keep the rows of an existing summary.csv, replacing those of the same video (``--resume``);
        rows of videos not run now stay, in their order, and new videos are appended.
    """
    path = Path(path)
    rows: dict[str, dict] = {}
    if merge and path.is_file():
        with path.open(newline="") as f:
            for old in csv.DictReader(f):
                key = old.get("video") or old.get("name") or ""
                rows[key] = {c: old.get(c) or "" for c in SUMMARY_COLUMNS}
    for r in results:
        row = summary_row(r)
        rows[row["video"] or row["name"]] = row

    def write(tmp: str) -> None:
        with open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS)
            w.writeheader()
            w.writerows(rows.values())

    write_atomic(path, write)
    return path
