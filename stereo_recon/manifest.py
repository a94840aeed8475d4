"""Run manifests and safe output: input hashes, library versions, timings, atomic writes."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import platform
import shutil
import sys
import tempfile
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


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def set_default_mode(path: str | os.PathLike) -> None:
    """Give a file made by ``mkstemp`` (mode 0600) the permissions a plain ``open`` would."""
    os.chmod(path, 0o666 & ~_umask())


def write_json_atomic(path: str | os.PathLike, data: Any) -> Path:
    """Write JSON to ``path`` via a temporary file in the same folder and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(to_jsonable(data), f, indent=2, sort_keys=False)
            f.write("\n")
        set_default_mode(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


# Temporary and superseded folders of an output folder NAME are hidden siblings named
# ``.NAME.tmp-<pid>-<random>`` / ``.NAME.old-<pid>-<random>`` (a nested stage's temporary folder adds
# leading dots): the pid says whether the process that owns one is still running.
_TEMP_RE = r"^\.+{name}\.(tmp|old)-(\d+)-"


def _pid_alive(pid: int) -> bool:
    """Whether a process with this id exists on this machine (a PermissionError means it does, owned by
    someone else; any other doubt counts as alive, so a folder is never taken from a running process)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def remove_stale_temps(final_dir: str | os.PathLike) -> list[Path]:
    """Remove the temporary folders that killed runs left beside ``final_dir``; returns what was removed.

    Only folders whose owning process is gone are touched. A superseded folder (``.old-``) whose
    run died between the two renames of a commit is put back as ``final_dir`` when that is missing.
    """
    import re

    final = Path(final_dir)
    parent = final.parent
    if not parent.is_dir():
        return []
    pattern = re.compile(_TEMP_RE.format(name=re.escape(final.name)))
    removed = []
    for item in sorted(parent.iterdir()):
        m = pattern.match(item.name)
        if not m or _pid_alive(int(m.group(2))):
            continue
        if m.group(1) == "old" and not final.exists() and item.name.startswith(f".{final.name}.old-"):
            os.replace(item, final)   # the commit died after moving the old folder away: restore it
            continue
        shutil.rmtree(item, ignore_errors=True)
        with contextlib.suppress(FileNotFoundError):
            item.unlink()
        removed.append(item)
    return removed


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst, follow_symlinks=False)
    except OSError:
        shutil.copy2(src, dst, follow_symlinks=False)


def _carry_over(old: Path, new: Path, keep) -> None:
    """Hard-link (or copy) the entries of ``old`` that ``new`` lacks and ``keep(name)`` accepts into ``new``."""
    for item in old.iterdir():
        dest = new / item.name
        if dest.exists() or dest.is_symlink() or not keep(item.name):
            continue
        if item.is_dir() and not item.is_symlink():
            shutil.copytree(item, dest, symlinks=True, copy_function=_link_or_copy)
        else:
            _link_or_copy(str(item), str(dest))


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two paths (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    AT_FDCWD, RENAME_EXCHANGE = -100, 2
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return fn(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE) == 0


def commit_output_dir(tmp: Path, final: Path, keep=lambda name: True) -> None:
    """Make ``tmp`` the folder ``final`` in one step: the old folder's entries that ``tmp`` lacks and
    ``keep(name)`` accepts are linked in first, then the two are swapped and the old one removed.

    A reader sees either the old folder or the complete new one, never a mix.
    """
    if final.is_dir():
        _carry_over(final, tmp, keep)
        if _exchange(tmp, final):
            shutil.rmtree(tmp, ignore_errors=True)   # tmp now holds the old folder
            return
        old = Path(tempfile.mkdtemp(prefix=f".{final.name}.old-{os.getpid()}-", dir=final.parent))
        os.rmdir(old)
        os.replace(final, old)          # a crash between these two renames is undone by remove_stale_temps
        os.replace(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, final)


@contextlib.contextmanager
def staged_output_dir(final_dir: str | os.PathLike, overwrite: bool = True, keep=None) -> Iterator[Path]:
    """Yield a temporary sibling folder; on success it replaces ``final_dir`` in one step.

    On any exception the temporary folder is removed and ``final_dir`` is left exactly as it was,
    so a failed run never leaves half-written output; on success ``final_dir`` changes at once
    (``commit_output_dir``). Entries of the old ``final_dir`` that the run did not produce are kept
    (finished stages of earlier runs survive) when ``keep(name)`` (default: always) says so; with
    ``overwrite=False`` the old entries also win over the new ones. Temporary folders of killed
    runs into the same place are removed first (``remove_stale_temps``). An output folder that
    cannot be made or written is one InputError line.
    """
    from stereo_recon.errors import InputError

    final = Path(os.path.realpath(final_dir))
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(final)
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.tmp-{os.getpid()}-", dir=final.parent))
        # mkdtemp makes 0700; the output folder gets the old folder's mode, or what mkdir would give.
        if final.is_dir():
            shutil.copymode(final, tmp)
        else:
            os.chmod(tmp, 0o777 & ~_umask())
    except OSError as err:
        raise InputError(f"{final_dir}: cannot create the output folder ({err.strerror or err})") from None
    try:
        yield tmp
        keep_fn = keep or (lambda name: True)
        if not overwrite and final.is_dir():   # the old entries win: drop the new copies before the commit
            for item in final.iterdir():
                dest = tmp / item.name
                if not (dest.exists() and keep_fn(item.name)):
                    continue
                if dest.is_dir() and not dest.is_symlink():
                    shutil.rmtree(dest)
                else:
                    dest.unlink()
        try:
            commit_output_dir(tmp, final, keep_fn)
        except OSError as err:
            raise InputError(f"{final_dir}: cannot write the output folder ({err.strerror or err})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


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
