"""Solid procedural surface texture evaluated at every ray hit point (vectorised numpy + cv2.remap).

A surface's colour is ``albedo * (1 + strength * noise(world point))`` (plus painted patterns), where
``noise`` is band-limited multi-scale noise: two periodic 1/f^beta tiles (a fine 'grain' and coarse
'stains') looked up by bilinear interpolation at the hit point's world coordinates, projected on
the plane of the surface's dominant normal axis (tri-planar mapping). The texture is therefore
fixed to the world: both eyes and every frame see the same surface pattern, as stereo needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

_TILE = 1024  # texels per tile side (periodic)
_ROW = 2048  # remap row length used to batch the 1-D point lists
_TILE_SCALE = 4096.0  # noise tiles are int16 = round(4096 * value)
# The stain tile is read at (0.8 u - 0.6 v, 0.6 u + 0.8 v) / 16 grain texels: a shift of 80 grain tiles
# along u or v moves it by (4, 3) or (-3, 4) whole stain tiles, the shortest shift that leaves both unchanged.
_JOINT_TILES = 80


@dataclass(frozen=True)
class Material:
    """Appearance of one surface type.

    albedo_rgb: diffuse reflectance per channel, 0..1.
    texture_strength: relative standard deviation of the multiplicative noise (0.02 = weakly
        textured paint, 0.3 = gravel).
    texel_m: size of one noise texel in metres; the finest pattern has a wavelength of ~4 texels
        (choose ~1 pixel footprint at the working distance so it neither aliases nor vanishes).
    stain_mix: weight of the coarse stain tile relative to the fine grain (0..1).
    pattern: "noise" | "bays" (ground with painted parking lines) | "band" (a painted horizontal
        stripe) | "panel" (a truck's cargo panels: seams, rails, dirt, decals in the truck's frame) |
        "checker" (a calibration chessboard in its own plane frame).
    params: pattern parameters (see ``_apply_pattern``); values are floats or 3-vectors.
    """

    name: str
    albedo_rgb: tuple[float, float, float]
    texture_strength: float = 0.1
    texel_m: float = 0.004
    stain_mix: float = 0.5
    pattern: str = "noise"
    params: dict = field(default_factory=dict, compare=False)


@lru_cache(maxsize=4)
def noise_tile(beta: float, seed: int, size: int = _TILE) -> np.ndarray:
    """Periodic, band-limited 1/f^beta noise tile (size x size int16 holding 4096 x a zero-mean, unit-std field).

    Built in the Fourier domain, so it wraps seamlessly; frequencies above 1/4 cycle per texel are
    removed so a bilinear lookup at ~1 texel per pixel does not alias.
    """
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    fr = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2)
    fr[0, 0] = 1.0
    amp = fr ** (-beta) * np.exp(-((fr / 0.22) ** 4))  # smooth low-pass near 1/4 cycle per texel
    amp[0, 0] = 0.0
    phase = rng.uniform(0, 2 * np.pi, (size, size))
    spec = amp * np.exp(1j * phase)
    img = np.real(np.fft.ifft2(spec))
    img = (img - img.mean()) / img.std()
    # Stored as int16 (1/4096 std per step); the renderer samples the float32 copy (_noise_tile_f32).
    return np.clip(np.round(img * _TILE_SCALE), -32767, 32767).astype(np.int16)


def lookup_rows(img: np.ndarray, u: np.ndarray, v: np.ndarray, border: int = cv2.BORDER_WRAP, border_value: float = 0.0) -> np.ndarray:
    """Bilinear ``cv2.remap`` lookup of the 2-D array ``img`` at the points (u, v) (1-D float32 arrays, texel units).

    The point lists are folded into rows of ``_ROW`` so one remap call serves any number of points.
    Returns (M,) values of ``img``'s dtype (rounded for integer images).
    """
    n = len(u)
    if n == 0:
        return np.zeros(0, img.dtype)
    row = _ROW
    rows = -(-n // row)
    pad = rows * row - n
    if pad:  # np.pad's per-call overhead shows on the many small per-material subsets
        uu = np.zeros(rows * row, np.float32)
        vv = np.zeros(rows * row, np.float32)
        uu[:n], vv[:n] = u, v
        u, v = uu, vv
    out = cv2.remap(img, u.astype(np.float32, copy=False).reshape(rows, row), v.astype(np.float32, copy=False).reshape(rows, row),
                    cv2.INTER_LINEAR, borderMode=border, borderValue=border_value)
    return out.reshape(-1)[:n]


@lru_cache(maxsize=4)
def _noise_tile_f32(beta: float, seed: int) -> np.ndarray:
    """:func:`noise_tile` as float32 unit-std values: cv2.remap's bilinear path is ~2x faster on float32 than on int16."""
    t = noise_tile(beta, seed).astype(np.float32) * np.float32(1.0 / _TILE_SCALE)
    t.setflags(write=False)
    return t


def _wrap(a: np.ndarray, period: float) -> np.ndarray:
    """``a`` folded into [0, period) (float32; cheaper than np.mod)."""
    p = np.float32(period)
    out = a * np.float32(1.0 / period)
    np.floor(out, out=out)
    out *= -p
    out += a
    return out


def _lookup(tile: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear, wrapping lookup of the float32 ``tile`` at texel coordinates (u, v) (1-D float32 arrays); returns (M,) float32 values.

    The coordinates are folded into the tile first: cv2.remap takes a per-pixel border path for every
    point outside the source image, ~4x slower than its vector path (and its fixed-point maps overflow
    beyond ~32k texels).
    """
    if len(u) == 0:
        return np.zeros(0, np.float32)
    s = float(tile.shape[0])
    return lookup_rows(tile, _wrap(u, s), _wrap(v, s))


def planar_coords(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tri-planar 2-D coordinates (metres): the two world axes spanning the plane of the dominant normal axis.

    points, normals: (M, 3) world frame. Returns (u, v), each (M,) float32.
    """
    a = np.abs(normals)
    along_z = (a[:, 2] >= a[:, 0]) & (a[:, 2] >= a[:, 1])
    along_x = ~along_z & (a[:, 0] >= a[:, 1])
    u = np.where(along_z | ~along_x, points[:, 0], points[:, 1])
    v = np.where(along_z, points[:, 1], points[:, 2])
    # Offset the x-facing and y-facing planes so adjacent faces do not share one pattern.
    u = u + np.where(along_x, 17.3, 0.0) + np.where(~along_z & ~along_x, 41.9, 0.0)
    return u.astype(np.float32), v.astype(np.float32)


def _smooth_square(x: np.ndarray, period: float, width: np.ndarray) -> np.ndarray:
    """Anti-aliased square wave in [-1, 1]: +1 on the first half period, -1 on the second.

    width: (M,) transition width in the same units (about one pixel footprint).
    """
    ph = np.mod(x, period) / period  # 0..1
    d = np.minimum(ph, 1.0 - ph) * period  # distance to the edge at phase 0
    d2 = np.abs(ph - 0.5) * period  # distance to the edge at phase 1/2
    dist = np.minimum(d, d2)
    sign = np.where(ph < 0.5, 1.0, -1.0)
    return sign * np.clip(dist / np.maximum(width, 1e-9), 0.0, 1.0)


def _texture_factor(mat: Material, mid: int, p: np.ndarray, n: np.ndarray | None, ref: np.ndarray) -> np.ndarray:
    """Multiplicative noise factor (M,) float32 of one material at world points ``p`` (``n`` None: horizontal plane)."""
    if mat.texture_strength <= 0:
        return np.ones(len(p), np.float32)
    if n is None:
        u, v = p[:, 0], p[:, 1]
    else:
        u, v = planar_coords(p, n)
    # Whole periods near the reference point keep coordinates small without changing the texture. The
    # period must be one of *both* tiles: the grain repeats every _TILE texels, but the rotated stain
    # lookup (below) only every _JOINT_TILES x _TILE texels along either axis. Shifting by the grain's
    # period alone changed the stains wherever two eyes or two frames rounded the reference differently
    # (an eye 0.5 period from the origin), so the same panel looked different in them.
    grain_m = _TILE * mat.texel_m  # the grain tile's period: only the per-material offset folds into it
    joint_m = _JOINT_TILES * _TILE * mat.texel_m  # the period of both tiles together
    off_u = np.float32(np.mod(97.1 * mid, grain_m) - np.round(ref[0] / joint_m) * joint_m)
    off_v = np.float32(np.mod(48.6 * mid, grain_m) - np.round(ref[1] / joint_m) * joint_m)
    inv = np.float32(1.0 / mat.texel_m)
    tu = (u + off_u) * inv
    tv = (v + off_v) * inv
    g = _lookup(_noise_tile_f32(0.6, 11), tu, tv)
    if mat.stain_mix > 0:
        # Stains at 16x the grain scale, rotated so the two tile periods never line up.
        su = (np.float32(0.8 / 16) * tu - np.float32(0.6 / 16) * tv)
        sv = (np.float32(0.6 / 16) * tu + np.float32(0.8 / 16) * tv)
        g = np.float32(1 - mat.stain_mix) * g + np.float32(mat.stain_mix) * _lookup(_noise_tile_f32(1.6, 23), su, sv)
    tex = np.float32(mat.texture_strength) * g
    tex += np.float32(1.0)
    return np.clip(tex, 0.05, 3.0, out=tex)


def shade_albedo(points: np.ndarray, normals: np.ndarray, material_ids: np.ndarray, materials: list[Material], footprint_m: np.ndarray,
                 ref_m: np.ndarray | None = None) -> np.ndarray:
    """Textured albedo (M, 3) float32 at hit points, channels in the order of ``Material.albedo_rgb``.

    points: (M, 3) world hit points, metres; normals: (M, 3) unit-ish normals (world);
    material_ids: (M,) indices into ``materials`` (-1 = no surface: left as zeros); footprint_m: (M,)
    approximate pixel footprint on the surface (metres), used to anti-alias painted edges;
    ref_m: a world point near the camera (keeps texture coordinates small; the result does not depend on it).
    The most frequent material (the ground) is evaluated on the whole arrays (as a horizontal
    plane when it is ``ground``), the rest on gathered subsets.
    """
    ref = np.zeros(3) if ref_m is None else np.asarray(ref_m, float)
    m = len(points)
    counts = np.bincount(material_ids + 1, minlength=len(materials) + 1)[1:]  # -1 (no surface) drops out
    dom = int(np.argmax(counts)) if len(materials) else 0
    if m == 0 or counts.sum() == 0:
        return np.zeros((m, 3), np.float32)
    out = np.empty((m, 3), np.float32)  # every row is written by the dominant material below
    dmat = materials[dom]
    tex = _texture_factor(dmat, dom, points, None if dmat.name == "ground" else normals, ref)
    for k, a in enumerate(np.asarray(dmat.albedo_rgb, np.float32)):  # per channel: a (M, 1) x (1, 3) broadcast is ~4x slower
        np.multiply(tex, a, out=out[:, k])
    if dmat.pattern != "noise":
        # Patterns of the dominant material on the whole arrays (no gather); others overwrite below.
        out = _apply_pattern(dmat, out, points, footprint_m, tex)
    rest = np.nonzero((material_ids != dom) & (material_ids >= 0))[0]
    if len(rest) == 0:
        return out
    rid = material_ids[rest]
    rp = points[rest]
    rn = normals[rest]
    rf = footprint_m[rest]
    for mid in np.nonzero(counts)[0]:
        if mid == dom:
            continue
        mat = materials[mid]
        loc = np.nonzero(rid == mid)[0]
        p = rp[loc]
        t = _texture_factor(mat, int(mid), p, rn[loc], ref)
        rgb = np.asarray(mat.albedo_rgb, np.float32)[None, :] * t[:, None]
        if mat.pattern != "noise":
            rgb = _apply_pattern(mat, rgb, p, rf[loc], t)
        out[rest[loc]] = rgb
    return out


def _apply_pattern(mat: Material, rgb: np.ndarray, p: np.ndarray, fp: np.ndarray, tex: np.ndarray) -> np.ndarray:
    """Painted patterns on top of the noise texture (see :class:`Material`)."""
    pr = mat.params
    if mat.pattern == "bays":
        # Parking-bay lines: transverse lines every spacing_m along x between y_lo..y_hi, plus two
        # long lines at y_lo and y_hi, all line_width_m wide, limited to |x| <= x_extent_m.
        w = pr["line_width_m"]
        s = pr["spacing_m"]
        x0 = pr.get("x0_m", 0.0)
        x, y = p[:, 0], p[:, 1]
        # Only points inside the painted area's bounding box can be paint (cheap test, then a subset).
        cand = np.abs(x - np.float32(x0)) <= np.float32(pr["x_extent_m"])
        cand &= (y >= np.float32(pr["y_lo_m"] - w)) & (y <= np.float32(pr["y_hi_m"] + w))
        idx = np.nonzero(cand)[0]
        x, y = x[idx], y[idx]
        dx = np.abs(np.mod(x - x0 + s / 2, s) - s / 2)
        trans = (dx < w / 2) & (y >= pr["y_lo_m"]) & (y <= pr["y_hi_m"])
        long_ = (np.minimum(np.abs(y - pr["y_lo_m"]), np.abs(y - pr["y_hi_m"])) < w / 2)
        paint = idx[trans | long_]
        if len(paint):
            col = np.asarray(pr.get("paint_rgb", (0.85, 0.83, 0.75)), np.float32)
            rgb[paint] = col[None, :] * (1.0 + 0.3 * (tex[paint, None] - 1.0))
        return rgb
    if mat.pattern == "band":
        z = p[:, 2]
        m = (z >= pr["z_lo_m"]) & (z <= pr["z_hi_m"])
        if m.any():
            rgb[m] = np.asarray(pr["band_rgb"], np.float32)[None, :] * tex[m, None]
        return rgb
    if mat.pattern == "panel":
        return _panel_pattern(pr, rgb, p, tex)
    if mat.pattern == "checker":
        o = np.asarray(pr["origin"], float)
        ua = np.asarray(pr["u_axis"], float)
        va = np.asarray(pr["v_axis"], float)
        q = p - o
        u = q @ ua  # metres from the first inner corner's square origin along the board's columns
        v = q @ va
        sq = pr["square_m"]
        nc, nr = pr["squares_x"], pr["squares_y"]
        su = _smooth_square(u, 2 * sq, fp)
        sv = _smooth_square(v, 2 * sq, fp)
        val = 0.5 - 0.5 * su * sv  # 1 = white, 0 = black; the corner squares are black
        inside = (u >= 0) & (u <= nc * sq) & (v >= 0) & (v <= nr * sq)
        val = np.where(inside, val, 1.0)
        black = np.asarray(pr.get("black_rgb", (0.04, 0.04, 0.04)), np.float32)
        white = np.asarray(mat.albedo_rgb, np.float32)
        col = black[None, :] + (white - black)[None, :] * val[:, None].astype(np.float32)
        return col * np.clip(tex, 0.5, 1.5)[:, None]
    return rgb


def _panel_pattern(pr: dict, rgb: np.ndarray, p: np.ndarray, tex: np.ndarray) -> np.ndarray:
    """A truck's cargo panels: decals painted over the paint, then seams, rails and dirt darken it.

    pr: origin / x_axis (the truck frame's origin and x axis in the world; the truck stands upright),
    seams_x_m, seam_width_m, seam_shade, rails_z_m, rail_shade, dirt, dirt_top_m, z_floor_m, decals
    ((x0, x1, z0, z1, colour) in the truck frame, metres). p: (M, 3) world points; tex: (M,) noise factor.
    """
    o = np.asarray(pr["origin"], np.float32)
    ax = np.asarray(pr["x_axis"], np.float32)
    x = (p[:, 0] - o[0]) * ax[0] + (p[:, 1] - o[1]) * ax[1]  # truck-frame x (the truck is only yawed)
    z = p[:, 2]
    for x0, x1, z0, z1, col in pr.get("decals", ()):
        m = (x >= x0) & (x <= x1) & (z >= z0) & (z <= z1)
        if m.any():
            rgb[m] = np.asarray(col, np.float32)[None, :] * tex[m, None]
    shade = np.ones(len(p), np.float32)
    seams = np.asarray(pr.get("seams_x_m", ()), np.float32)
    if len(seams) > 1:
        s0, step = float(seams[0]), float(seams[1] - seams[0])  # evenly spaced
        dx = np.abs(np.mod(x - s0 + step / 2, step) - step / 2)
        on = (dx < pr["seam_width_m"] / 2) & (x > s0 - step / 2) & (x < float(seams[-1]) + step / 2)
        shade[on] *= np.float32(pr["seam_shade"])
    elif len(seams) == 1:
        shade[np.abs(x - seams[0]) < pr["seam_width_m"] / 2] *= np.float32(pr["seam_shade"])
    for zl, zh in pr.get("rails_z_m", ()):
        shade[(z >= zl) & (z <= zh)] *= np.float32(pr["rail_shade"])
    if pr.get("dirt", 0.0) > 0:
        top, floor = pr["dirt_top_m"], pr["z_floor_m"]
        shade *= np.float32(1.0) - np.float32(pr["dirt"]) * np.clip((top - z) / max(top - floor, 1e-9), 0.0, 1.0).astype(np.float32)
    rgb *= shade[:, None]
    return rgb
