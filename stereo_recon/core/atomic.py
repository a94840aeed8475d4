"""The one atomic writer and the one folder transaction of the project.

Files: :func:`write_atomic` (and its text, bytes and JSON forms) write a temporary sibling and rename it,
so a reader sees the old file or the complete new one. Folders: :func:`staged_output_dir` yields a
temporary sibling folder that replaces the output folder in one step on success and vanishes on failure.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterator

from stereo_recon.core.errors import InputError
from stereo_recon.core.manifest import to_jsonable


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def set_default_mode(path: str | os.PathLike) -> None:
    """Give a file made by ``mkstemp`` (mode 0600) the permissions a plain ``open`` would."""
    os.chmod(path, 0o666 & ~_umask())


def write_atomic(path: str | os.PathLike, write: Callable[[str], None], suffix: str = "") -> Path:
    """Make ``path`` through ``write(tmp)`` on a temporary file in the same folder, then one atomic rename.

    path: the file to make (its folder is created). write: fills the temporary file, given its path.
    suffix: the temporary file's suffix, for writers that choose the format by it (cv2.FileStorage).
    A reader sees the old file or the complete new one; on any failure the temporary file is removed.
    The file gets the permissions a plain ``open`` would give (mkstemp makes 0600).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        set_default_mode(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write bytes to ``path`` atomically (:func:`write_atomic`)."""
    return write_atomic(path, lambda tmp: Path(tmp).write_bytes(data))


def write_text_atomic(path: str | os.PathLike, text: str, encoding: str | None = "utf-8") -> Path:
    """Write text to ``path`` atomically (:func:`write_atomic`); encoding None: the locale's, as ``open`` does."""
    return write_atomic(path, lambda tmp: Path(tmp).write_text(text, encoding=encoding))


def write_json_atomic(path: str | os.PathLike, data: Any) -> Path:
    """Write ``data`` (made JSON-ready by ``to_jsonable``) as indented JSON with a final newline, atomically."""
    return write_text_atomic(path, json.dumps(to_jsonable(data), indent=2, sort_keys=False) + "\n", encoding=None)


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


class FileTransaction:
    """Files written under temporary names, moved to their final paths together when all are written."""

    def __init__(self, tmp_dir: Path) -> None:
        self.tmp_dir = tmp_dir
        self._moves: list[tuple[Path, Path]] = []

    def temp(self, name: str) -> Path:
        """A temporary path for a file named ``name`` (inside the transaction's hidden folder)."""
        return self.tmp_dir / name

    def add(self, tmp: str | os.PathLike, final: str | os.PathLike) -> Path:
        """Move ``tmp`` to ``final`` at the commit (in the order added; ``final``'s folder is made then)."""
        self._moves.append((Path(tmp), Path(final)))
        return Path(final)

    def _commit(self) -> None:
        for tmp, final in self._moves:
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp, final)


@contextlib.contextmanager
def staged_files(folder: str | os.PathLike, prefix: str = "staged") -> Iterator[FileTransaction]:
    """Yield a :class:`FileTransaction` whose temporary folder is a hidden child of ``folder``.

    On success every added file is moved into place; on any exception nothing is moved and the folders
    this call created for ``folder`` are removed again when empty. The temporary folder always goes.
    """
    folder = Path(folder)
    made_dirs = [d for d in [folder, *folder.parents] if not d.exists()]  # removed again on failure
    folder.mkdir(parents=True, exist_ok=True)
    tx = FileTransaction(Path(tempfile.mkdtemp(prefix=f".{prefix}.", dir=folder)))
    done = False
    try:
        yield tx
        tx._commit()
        done = True
    finally:
        shutil.rmtree(tx.tmp_dir, ignore_errors=True)
        for d in made_dirs if not done else ():
            if d.is_dir() and not any(d.iterdir()):
                d.rmdir()
