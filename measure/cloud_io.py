"""Read point clouds (PLY, PCD, XYZ, PTS) through Open3D, with one-line errors for bad files."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from stereo_recon.core.errors import InputError

SUPPORTED_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")


def read_cloud(path: str | os.PathLike, min_points: int = 100) -> np.ndarray:
    """Points of a cloud file as an (N, 3) float64 array (metres, the file's frame).

    Raises InputError naming the file for: missing, not a file, unsupported suffix, unreadable
    or empty, non-finite coordinates (NaN/inf), fewer than ``min_points`` points.
    """
    return read_cloud_colors(path, min_points)[0]


def read_cloud_colors(path: str | os.PathLike, min_points: int = 100) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (N, 3) float64 and their colours (N, 3) float64 RGB in [0, 1], or None when the file has none.

    As ``read_cloud`` (same checks and errors); ``.pts`` files and text files without colours give None.
    """
    colors = None
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    if not p.is_file():
        raise InputError(f"{p}: not a file")
    suffix = p.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise InputError(f"{p}: unsupported point-cloud format '{suffix}' (use one of {', '.join(SUPPORTED_SUFFIXES)})")
    if not os.access(p, os.R_OK):
        raise InputError(f"{p}: file is not readable")
    if p.stat().st_size == 0:
        raise InputError(f"{p}: file is empty")
    if suffix == ".ply":
        check_ply_complete(p)   # Open3D reads the missing points of a cut file as (0, 0, 0)
    if suffix == ".pts":
        pts = _read_pts(p)
    else:
        import open3d as o3d

        try:
            pc = o3d.io.read_point_cloud(str(p), format="auto", remove_nan_points=False, remove_infinite_points=False)
        except Exception as err:  # Open3D raises RuntimeError on corrupt files
            raise InputError(f"{p}: cannot read point cloud ({' '.join(str(err).split())})") from None
        pts = np.asarray(pc.points, dtype=np.float64)
        if pc.has_colors() and len(pc.colors) == len(pts):
            colors = np.asarray(pc.colors, dtype=np.float64)
        if len(pts) == 0 and suffix in (".xyz", ".xyzn", ".xyzrgb"):
            pts = _read_text_xyz(p)   # Open3D skips files with NaN tokens silently
    if len(pts) == 0:
        raise InputError(f"{p}: file has 0 points (empty or unreadable cloud)")
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise InputError(f"{p}: {int(bad.sum())} of {len(pts)} points have NaN or infinite coordinates")
    if len(pts) < min_points:
        raise InputError(f"{p}: only {len(pts)} points, at least {min_points} are needed to measure a truck")
    return pts, colors


_PLY_TYPE_BYTES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
                   "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _ply_header(p: Path) -> tuple[str, int, list[tuple[str, int, list[list[str]]]]]:
    """(format, header length in bytes, [(element, count, [property tokens])]) of a PLY file."""
    with open(p, "rb") as f:
        head = f.read(1 << 16)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise InputError(f"{p}: not a PLY file (no 'ply' ... 'end_header' header)")
    nl = head.find(b"\n", end)
    header_len = (nl + 1) if nl >= 0 else len(head)
    fmt, elements = "", []
    for line in head[:end].decode("ascii", "replace").splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format" and len(tok) > 1:
            fmt = tok[1]
        elif tok[0] == "element" and len(tok) == 3:
            try:
                elements.append((tok[1], int(tok[2]), []))
            except ValueError:
                raise InputError(f"{p}: PLY header line {line.strip()!r} has no element count") from None
        elif tok[0] == "property" and elements:
            elements[-1][2].append(tok[1:])
    return fmt, header_len, elements


def check_ply_complete(p: Path) -> None:
    """InputError when a PLY file holds fewer vertices than its header announces (a cut or truncated file).

    Binary files: the bytes of the elements up to and including the vertices against the file size;
    ASCII files: the number of data lines. Elements with list properties before the vertices are not sized.
    """
    fmt, header_len, elements = _ply_header(p)
    size = p.stat().st_size - header_len
    need = 0
    for name, count, props in elements:
        if any(t[0] == "list" for t in props):
            return   # variable-size rows: cannot be sized without reading them
        row = sum(_PLY_TYPE_BYTES.get(t[0], 0) for t in props)
        if fmt == "ascii":
            with open(p, "rb") as f:
                f.seek(header_len)
                lines = sum(1 for line in f if line.strip())
            if name == "vertex" and lines < need + count:
                raise InputError(f"{p}: PLY header announces {count} points but the file holds only "
                                 f"{max(lines - need, 0)} point lines (truncated file)")
            need += count
            if name == "vertex":
                return
            continue
        need += row * count
        if name == "vertex":
            if size < need:
                have = max(0, (size - (need - row * count)) // max(row, 1))
                raise InputError(f"{p}: PLY header announces {count} points but the file holds only {have} "
                                 f"({size} of {need} bytes; truncated file)")
            return


def _read_text_xyz(p: Path) -> np.ndarray:
    try:
        data = np.loadtxt(p, ndmin=2, usecols=(0, 1, 2), comments="#")
    except (ValueError, IndexError, OSError):
        return np.zeros((0, 3))
    return data


def _read_pts(p: Path) -> np.ndarray:
    """Leica/CloudCompare PTS: optional first line with the point count, then 'x y z [...]' lines."""
    try:
        with open(p) as f:
            first = f.readline().split()
            skip = 1 if len(first) == 1 else 0
        data = np.loadtxt(p, ndmin=2, usecols=(0, 1, 2), skiprows=skip, comments="#")
    except (ValueError, IndexError, UnicodeDecodeError, OSError) as err:
        raise InputError(f"{p}: cannot read PTS file ({' '.join(str(err).split())[:120]})") from None
    return data.astype(np.float64)
