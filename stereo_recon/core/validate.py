"""Checks of arguments and output paths made before any work, each failing with one line (exit 2)."""

from __future__ import annotations

import errno
import math
import os
import re
import shutil
import tempfile
from pathlib import Path

from stereo_recon.core.errors import ConfigError, InputError
from stereo_recon.core.paths import LOG, OUTPUT_MARKERS



def check_number(option: str, value, *, minimum: float = 0.0, strict: bool = True, integer: bool = False,
                 allow_none: bool = True):
    """``value`` unless it is not a finite number above ``minimum`` (``>=`` when not ``strict``): ConfigError.

    option: the option's name as the user typed it (``--eps``), used in the message.
    """
    if value is None and allow_none:
        return None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if ok:
        ok = value > minimum if strict else value >= minimum
    if not ok:
        kind = "an integer" if integer else "a finite number"
        rel = ">" if strict else ">="
        raise ConfigError(f"{option} {value}: must be {kind} {rel} {minimum:g}")
    return value


def _nearest_existing(p: Path) -> Path:
    while not os.path.lexists(p) and p != p.parent:
        p = p.parent
    return p


# Below this much free space a failed write without an errno is put down to a full disk.
_LOW_DISK_BYTES = 64 * 2**20
# numpy's short write ("921600 requested and 413664 written") carries no errno; on a disk it means no space.
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written")


def disk_full_message(err: BaseException, folder) -> str | None:
    """One line saying that the disk of ``folder`` ran out of space, when ``err`` is a write that failed for that.

    err: the exception caught; folder: where the command was writing (its nearest existing ancestor is the
    one measured). None for anything else: not an OSError, another errno, or no errno on a disk with room.
    """
    if not isinstance(err, OSError):
        return None
    try:
        free = shutil.disk_usage(_nearest_existing(Path(folder))).free
    except OSError:
        free = None
    full = err.errno in (errno.ENOSPC, errno.EDQUOT) or (
        err.errno is None and (_SHORT_WRITE.search(str(err)) is not None
                               or (free is not None and free < _LOW_DISK_BYTES)))
    if not full:
        return None
    now = "" if free is None else f" ({free / 2**20:.0f} MB free now)"
    return f"{folder}: its disk ran out of space{now}; free some space or write the output elsewhere (--out)"


def _probe_write(folder: Path, what: str) -> None:
    """Create and remove a hidden folder in ``folder``; InputError (one line) when that fails."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".stereo-recon-probe-", dir=folder))
    except OSError as err:
        raise InputError(f"{what}: cannot write in {folder} ({err.strerror or err})") from None


def check_output_dir(path, option: str = "--out", foreign_ok: bool = False) -> Path:
    """The output folder ``path`` (resolved) if it can be written as a whole; else one-line InputError.

    Refused: an existing non-folder; a path under a regular file; a parent that cannot be written
    (read-only, ``/proc``); an existing folder with other content and none of this program's outputs
    (unless ``foreign_ok``), since a run replaces the folder as a whole. Nothing is created.
    """
    raw = Path(path).expanduser()
    what = f"{option} {path}"
    if str(path).strip() == "":
        raise InputError(f"{option}: empty path")
    final = Path(os.path.realpath(raw))
    if final == final.parent:
        raise InputError(f"{what}: the file-system root cannot be an output folder")
    if final.exists() and not final.is_dir():
        raise InputError(f"{what}: exists and is not a folder")
    anc = _nearest_existing(final.parent)
    if not anc.is_dir():
        raise InputError(f"{what}: {anc} is a file, not a folder")
    _probe_write(anc, what)
    if final.is_dir():
        try:
            # log.txt is the command's own log, opened in the folder before the checks run
            entries = [e.name for e in os.scandir(final) if e.name != LOG]
        except OSError as err:
            raise InputError(f"{what}: cannot read the folder ({err.strerror or err})") from None
        if entries and not foreign_ok and not any(m in entries for m in OUTPUT_MARKERS):
            raise InputError(f"{what}: the folder holds other files ({', '.join(sorted(entries)[:3])}"
                             f"{', ...' if len(entries) > 3 else ''}) and no stereo-recon output; give a new or "
                             "empty folder")
        _probe_write(final, what)
    return final


def check_output_file(path, option: str = "--out") -> Path:
    """An output file path that can be written; else one-line InputError (nothing is created)."""
    raw = Path(path).expanduser()
    what = f"{option} {path}"
    if str(path).strip() == "":
        raise InputError(f"{option}: empty path")
    if raw.is_dir():
        raise InputError(f"{what}: is a folder, expected a file")
    anc = _nearest_existing(raw.absolute().parent)
    if not anc.is_dir():
        raise InputError(f"{what}: {anc} is a file, not a folder")
    _probe_write(anc, what)
    return raw
