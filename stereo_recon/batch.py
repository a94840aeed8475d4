"""Many recordings at once: a local process pool by default, or a Ray cluster.

One failed job is recorded with its error and does not stop the others. The same
machinery runs ``bench``.
"""

from __future__ import annotations

import concurrent.futures as cf
import csv
import logging
import multiprocessing as mp
import os
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from stereo_recon.errors import ConfigError, StereoReconError
from stereo_recon.manifest import set_default_mode

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Job:
    """One unit of batch work: ``func(*args)`` must be a module-level (picklable) function returning a dict."""

    name: str
    func: Callable[..., dict]
    args: tuple


def _call(job: Job) -> dict:
    t0 = time.perf_counter()
    try:
        out = job.func(*job.args)
        return {"name": job.name, "ok": True, "error": None, "time_s": time.perf_counter() - t0, **out}
    except StereoReconError as err:
        return {"name": job.name, "ok": False, "error": " ".join(str(err).split()), "time_s": time.perf_counter() - t0}
    except Exception as err:  # a crash in one recording must not stop the fleet
        log.debug("job %s crashed:\n%s", job.name, traceback.format_exc())
        return {"name": job.name, "ok": False, "error": f"{type(err).__name__}: {err}", "time_s": time.perf_counter() - t0}


def run_jobs(jobs: Sequence[Job], workers: int = 1, executor: str = "local", progress: Callable[[dict], None] | None = None) -> list[dict]:
    """Run jobs and return their result dicts in the order given.

    Parameters
    ----------
    workers : processes (local) or concurrent tasks (ray); 1 runs in this process.
    executor : ``'local'`` (process pool) or ``'ray'`` (needs the ``ray`` extra; uses an existing
        cluster if ``RAY_ADDRESS`` is set, else starts a local instance).
    """
    if executor not in {"local", "ray"}:
        raise ConfigError(f"--executor: unknown executor '{executor}' (use local or ray)")
    results: dict[int, dict] = {}
    if executor == "ray":
        try:
            import ray
        except ImportError as err:
            raise ConfigError("--executor ray: Ray is not installed (pip install 'stereo-recon[ray]')") from err
        started = not ray.is_initialized()
        if started:
            ray.init(address=os.environ.get("RAY_ADDRESS"), num_cpus=max(1, workers), include_dashboard=False, log_to_driver=False)
        try:
            remote = ray.remote(_call)
            refs = [remote.remote(j) for j in jobs]
            for i, ref in enumerate(refs):
                results[i] = ray.get(ref)
                if progress:
                    progress(results[i])
        finally:
            if started:
                ray.shutdown()
    elif workers <= 1 or len(jobs) <= 1:
        for i, job in enumerate(jobs):
            results[i] = _call(job)
            if progress:
                progress(results[i])
    else:
        # 'spawn' keeps workers free of the parent's threads (Open3D/OpenCV pools).
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
            futs = {pool.submit(_call, job): i for i, job in enumerate(jobs)}
            for fut in cf.as_completed(futs):
                i = futs[fut]
                results[i] = fut.result()
                if progress:
                    progress(results[i])
    return [results[i] for i in range(len(jobs))]


SUMMARY_COLUMNS = ("name", "ok", "length_m", "width_m", "height_m", "u_length_m", "u_width_m", "u_height_m", "verdict", "time_s", "out_dir", "error")


def summary_row(result: dict) -> dict:
    """Flatten one job result into a row of the summary CSV."""
    unc = result.get("uncertainty_m") or {}
    verdict = result.get("verdict") or {}
    return {
        "name": result.get("name"),
        "ok": result.get("ok"),
        "length_m": result.get("length_m"),
        "width_m": result.get("width_m"),
        "height_m": result.get("height_m"),
        "u_length_m": unc.get("length"),
        "u_width_m": unc.get("width"),
        "u_height_m": unc.get("height"),
        "verdict": verdict.get("overall") if isinstance(verdict, dict) else verdict,
        "time_s": round(float(result.get("time_s") or 0.0), 3),
        "out_dir": result.get("out_dir"),
        "error": result.get("error"),
    }


def write_summary_csv(path: str | os.PathLike, results: Sequence[dict]) -> Path:
    """Write the batch summary CSV (one row per job) atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS)
        w.writeheader()
        for r in results:
            w.writerow(summary_row(r))
    set_default_mode(tmp)
    os.replace(tmp, path)
    return path
