"""One unit of batch work (:class:`Job`) and how it runs on any executor: the local pool (``batch``) or Ray (``batch_ray``)."""

from __future__ import annotations

import logging
import os
import socket
import time
import traceback
from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any, Callable, Mapping

from stereo_recon.core.errors import StereoReconError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Job:
    """One unit of batch work: ``func(*args)`` must be a module-level (picklable) function returning a dict.

    ``inputs`` and ``outputs`` name the files/folders among ``args`` (also inside dataclass args)
    that the job reads and writes: they are made absolute on the driver, and on Ray the inputs
    are shipped to a node that lacks them and the outputs come back to the driver.
    """

    name: str
    func: Callable[..., dict]
    args: tuple
    inputs: tuple[str, ...] = ()        # files or folders the job reads
    outputs: tuple[str, ...] = ()       # folders the job writes
    reuse_outputs: bool = False         # existing output folders are inputs too (``--resume``)
    info: dict = field(default_factory=dict, hash=False)  # copied into the job's result (e.g. its video), also on failure


def substitute_paths(obj: Any, mapping: Mapping[str, str]) -> Any:
    """``obj`` with every str/Path value equal to a key of ``mapping`` replaced by its value.

    Walks tuples, lists, dicts and dataclass fields; a Path stays a Path.
    """
    if isinstance(obj, Path):
        return Path(mapping[str(obj)]) if str(obj) in mapping else obj
    if isinstance(obj, str):
        return mapping.get(obj, obj)
    if isinstance(obj, (tuple, list)):
        return type(obj)(substitute_paths(v, mapping) for v in obj)
    if isinstance(obj, dict):
        return {k: substitute_paths(v, mapping) for k, v in obj.items()}
    if is_dataclass(obj) and not isinstance(obj, type):
        changed = {f.name: substitute_paths(getattr(obj, f.name), mapping) for f in fields(obj) if f.init}
        return replace(obj, **changed)
    return obj


def resolve_job(job: Job) -> Job:
    """The job with its inputs and outputs as absolute paths of this (the driver's) machine."""
    mapping = {str(p): os.path.abspath(p) for p in (*job.inputs, *job.outputs)}
    return replace(job, args=substitute_paths(job.args, mapping), inputs=tuple(mapping[str(p)] for p in job.inputs),
                   outputs=tuple(mapping[str(p)] for p in job.outputs))


def one_line(err: BaseException) -> str:
    """``'Type: message'`` on one line (whitespace collapsed)."""
    text = " ".join(str(err).split())
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def call_job(job: Job) -> dict:
    """Run one job; its result dict with name, host, ok, error (one line) and time_s; never raises for the job's failure."""
    t0 = time.perf_counter()
    base = {"name": job.name, **job.info, "host": socket.gethostname()}
    try:
        out = job.func(*job.args)
        return {**base, "ok": True, "error": None, "time_s": time.perf_counter() - t0, **out}
    except StereoReconError as err:
        return {**base, "ok": False, "error": " ".join(str(err).split()), "time_s": time.perf_counter() - t0}
    except Exception as err:  # a crash in one recording must not stop the fleet
        log.debug("job %s crashed:\n%s", job.name, traceback.format_exc())
        return {**base, "ok": False, "error": one_line(err), "time_s": time.perf_counter() - t0}
