"""Run manifests: input hashes, library versions, timings, JSON-ready values (atomic writes: :mod:`stereo_recon.core.atomic`)."""

from __future__ import annotations

import contextlib
import hashlib
import os
import platform
import sys
import time
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np


def sha256_file(path: str | os.PathLike, chunk_bytes: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(chunk_bytes):
            h.update(chunk)
    return h.hexdigest()


def library_versions() -> dict[str, str]:
    """Versions of Python and the numeric/vision libraries that are importable (imports nothing new if absent)."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    from importlib import metadata

    for dist in ("stereo-recon", "numpy", "scipy", "opencv-contrib-python-headless", "open3d", "pycolmap", "matplotlib", "kornia", "torch"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def to_jsonable(obj: Any) -> Any:
    """Convert dataclasses, numpy scalars/arrays and paths into JSON-serialisable values."""
    if is_dataclass(obj) and not isinstance(obj, type):
        return to_jsonable(asdict(obj))
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


class Stopwatch:
    """Collects named wall-clock timings (seconds) for a run manifest."""

    def __init__(self) -> None:
        self.timings_s: dict[str, float] = {}

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.timings_s[name] = self.timings_s.get(name, 0.0) + time.perf_counter() - t0


def run_manifest(command: str, inputs: dict[str, str | os.PathLike], parameters: Any, timings_s: dict[str, float], seed: int | None = None, extra: dict | None = None) -> dict:
    """Build a manifest dict: command line, inputs with sha256, parameters, versions, timings, seed."""
    ins = {}
    for name, p in inputs.items():
        p = Path(p)
        ins[name] = {"path": str(p), "sha256": sha256_file(p) if p.is_file() else None}
    man = {
        "command": command,
        "argv": sys.argv,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "inputs": ins,
        "parameters": to_jsonable(parameters),
        "seed": seed,
        "versions": library_versions(),
        "timings_s": timings_s,
    }
    if extra:
        man.update(to_jsonable(extra))
    return man
