"""Ray-cast stereo rendering of a synthetic scene through a (distorted) stereo rig with Open3D.

Per frame, the viewing rays of both eyes (cached per rig, see :func:`camera.pixel_rays`) are
rotated into the world; hits are shaded with Lambert + ambient, rays that miss get the sky colour,
then exposure, optional blur and sensor noise are applied.

First hits: when the scene's ``ground`` is a rectangle in z = 0 (every truck scene), only the rays
inside the image of some object's convex hull (drawn per eye and frame, dilated by 2 px) go through
Open3D's ``RaycastingScene.cast_rays`` (about 10-15 % of the pixels in an orbit); all others hit
the ground plane or the sky, which is computed analytically. ``StereoRenderer.first_hits(...,
full_cast=True)`` casts every ray instead, the reference the tests compare against.

Shadows: the scene is static and the sun fixed, so the shadows on the ground plane (most of the
image) come from a ground shadow map computed once per scene (occlusion rays from a grid of
ground points toward the sun, only where some triangle's shadow can fall) and looked up
bilinearly; only the sunlit hits on other surfaces (truck, distractors) cast per-pixel shadow rays.

Speed notes (2-core machine): no BLAS call on image-sized arrays in the per-frame path (OpenBLAS'
spinning worker threads fought the shading threads and Open3D's: one (921600, 3) @ (3, 3) product
took 0.15 s instead of 3 ms, doubling the frame time); ray rotation with ``cv2.transform`` into a
reused direction buffer, Open3D's (N, 6) ray arrays built only for the rays actually cast; float32
noise tiles (cv2.remap's bilinear path is ~2x faster than on int16); per-channel loops instead of
(N, 3) x (N, 1) broadcasts (numpy's inner loop of length 3 is several times slower).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from stereo_recon.synthetic.camera import pixel_rays
from stereo_recon.synthetic.scene import Scene
from stereo_recon.synthetic.texture import lookup_rows, shade_albedo

log = logging.getLogger(__name__)

_SHADOW_BLOCK = 32  # shadow-map cells per block side; only blocks some triangle's shadow can reach are cast
_SHADOW_MAX_CELLS = 8_000_000  # cap of the cast cells (the cell grows beyond): bounds the one-off setup time
_SHADOW_MAX_MAP = 64_000_000  # cap of the whole map (uint8 cells, bytes)
_SHADOW_BATCH = 2_000_000  # occlusion rays per test_occlusions call (bounds the temporary memory)


@dataclass(frozen=True)
class RenderConfig:
    """Image formation settings.

    noise_sigma_dn: std of additive Gaussian sensor noise, in 8-bit grey levels.
    shadows: sun shadows (a ground shadow map once per scene + shadow rays for the other sunlit hits).
    blur_sigma_px: Gaussian blur (defocus / motion) applied to both eyes; 0 = sharp.
    exposure: global gain (1 = nominal); per-frame changes come from ``render(exposure=...)``.
    right_gain: right-eye sensor gain relative to the left (real pairs differ by a few %).
    """

    noise_sigma_dn: float = 1.5
    shadows: bool = True
    blur_sigma_px: float = 0.0
    exposure: float = 1.0
    right_gain: float = 0.97


@dataclass
class RenderedPair:
    """One rendered stereo frame: BGR uint8 images (H, W, 3) per eye, left z-depth (H, W) float32 m (inf = sky)."""

    left: np.ndarray
    right: np.ndarray
    depth_left_m: np.ndarray


@dataclass
class GroundShadowMap:
    """Sunlit fraction of the ground plane z = 0 on a regular grid (world x, y).

    lit: (ny, nx) uint8, 255 = sunlit, 0 = shadowed; cell (i, j) is the ground point
    (x0_m + j * cell_m, y0_m + i * cell_m). Outside the grid the ground is sunlit.
    """

    lit: np.ndarray
    x0_m: float
    y0_m: float
    cell_m: float
    cast_cells: int

    def lookup(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear sunlit fraction (M,) float32 in [0, 1] at ground points (x, y) (metres, world)."""
        inv = np.float32(1.0 / self.cell_m)
        ny, nx = self.lit.shape
        u = (x - np.float32(self.x0_m)) * inv
        v = (y - np.float32(self.y0_m)) * inv
        # The outermost rows and columns are sunlit (the grid extends past every shadow), so clamping
        # points outside onto them is exact, and keeps cv2.remap on its fast in-image path.
        np.clip(u, 0.0, nx - 1.0, out=u)
        np.clip(v, 0.0, ny - 1.0, out=v)
        out = lookup_rows(self.lit, u, v, border=cv2.BORDER_REPLICATE)
        return out * np.float32(1.0 / 255.0)


def ground_shadow_map(raycaster, vertices: np.ndarray, sun_dir: np.ndarray, cell_m: float, eps_m: float) -> GroundShadowMap:
    """Shadow map of the ground plane z = 0 under a directional sun, from occlusion rays cast once.

    raycaster: Open3D RaycastingScene holding the whole scene; vertices: (T, 3, 3) world corners of
    every triangle that is NOT the ground (metres); sun_dir: unit vector toward the sun (z > 0);
    cell_m: grid spacing (about one pixel footprint or finer); eps_m: ray start height above the
    ground (as the per-pixel shadow rays' offset). A triangle's shadow lies inside the bounding box
    of its corners and their projections along the sun onto z = 0, so only the grid blocks those
    boxes touch are cast; everything else is sunlit for sure.
    """
    import open3d as o3d

    sun = np.asarray(sun_dir, np.float64)
    tri = np.asarray(vertices, np.float64).reshape(-1, 3, 3)
    if len(tri) == 0:
        return GroundShadowMap(np.full((1, 1), 255, np.uint8), 0.0, 0.0, float(cell_m), 0)
    proj = tri[..., :2] - np.maximum(tri[..., 2:3], 0.0) * (sun[:2] / sun[2])
    allxy = np.concatenate([tri[..., :2], proj], axis=1)  # (T, 6, 2)
    tlo, thi = allxy.min(axis=1), allxy.max(axis=1)
    cell = float(cell_m)
    B = _SHADOW_BLOCK
    for _ in range(20):
        lo = tlo.min(axis=0) - 2 * cell
        bs = B * cell
        b0 = np.floor((tlo - lo) / bs).astype(np.int64)
        b1 = np.floor((thi - lo + 2 * cell) / bs).astype(np.int64)
        nbx, nby = int(b1[:, 0].max()) + 1, int(b1[:, 1].max()) + 1
        mark = np.zeros((nby, nbx), bool)
        for (bx0, by0), (bx1, by1) in zip(b0, b1):  # a few hundred triangles
            mark[by0:by1 + 1, bx0:bx1 + 1] = True
        n_cast = int(mark.sum()) * B * B
        # Bounded cast work, map memory and cv2.remap's source size (< 32767 per side).
        grow = max(n_cast / _SHADOW_MAX_CELLS, nbx * nby * B * B / _SHADOW_MAX_MAP, (max(nbx, nby) * B / 32000.0) ** 2)
        if grow <= 1.0:
            break
        cell *= 1.25 * np.sqrt(grow)
    lit = np.full((nby * B, nbx * B), 255, np.uint8)  # first / last rows and columns lie >= 1 cell outside every shadow box
    by, bx = np.nonzero(mark)
    jj, ii = np.meshgrid(np.arange(B), np.arange(B))
    # Cell indices of every marked block, block by block.
    ci = (by[:, None, None] * B + ii[None]).reshape(-1)
    cj = (bx[:, None, None] * B + jj[None]).reshape(-1)
    sun32 = sun.astype(np.float32)
    for a in range(0, len(ci), _SHADOW_BATCH):
        i, j = ci[a:a + _SHADOW_BATCH], cj[a:a + _SHADOW_BATCH]
        rays = np.empty((len(i), 6), np.float32)
        rays[:, 0] = lo[0] + j * cell
        rays[:, 1] = lo[1] + i * cell
        rays[:, 2] = eps_m
        rays[:, 3:] = sun32
        occ = raycaster.test_occlusions(o3d.core.Tensor.from_numpy(rays)).numpy().view(bool)
        lit[i[occ], j[occ]] = 0
    log.debug("ground shadow map: %dx%d cells of %.4f m, %d cast", lit.shape[1], lit.shape[0], cell, len(ci))
    return GroundShadowMap(lit, float(lo[0]), float(lo[1]), cell, int(len(ci)))


_Z_NEAR_M = 1e-4  # object parts closer to the camera plane than this are not seen (no ray reaches them in practice)


def _clip_convex(poly: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """Clip a convex polygon (K, 2) to the rectangle [x0, x1] x [y0, y1] (Sutherland-Hodgman); returns (K', 2)."""
    for axis, lim, keep_ge in ((0, x0, True), (0, x1, False), (1, y0, True), (1, y1, False)):
        if len(poly) == 0:
            break
        c = poly[:, axis] - lim
        inside = c >= 0 if keep_ge else c <= 0
        out = []
        for i in range(len(poly)):
            j = (i + 1) % len(poly)
            if inside[i]:
                out.append(poly[i])
            if inside[i] != inside[j]:
                t = c[i] / (c[i] - c[j])
                out.append(poly[i] + t * (poly[j] - poly[i]))
        poly = np.array(out).reshape(-1, 2)
    return poly


def _to_bgr(m):
    from dataclasses import replace

    pr = dict(m.params)
    for k in ("paint_rgb", "band_rgb", "black_rgb"):
        if k in pr:
            pr[k] = tuple(pr[k])[::-1]
    if "decals" in pr:
        pr["decals"] = tuple((*d[:4], tuple(d[4])[::-1]) for d in pr["decals"])
    return replace(m, albedo_rgb=tuple(m.albedo_rgb)[::-1], params=pr)


class StereoRenderer:
    """Renders a fixed scene through a rig from any left-camera pose (one ``render`` call at a time).

    scene: :class:`Scene` (world frame, z up). rig: anything with K1 D1 K2 D2 R T image_size
    (``calib.rig.StereoRig``); rays follow the distortion exactly (X_right = R X_left + T).
    """

    def __init__(self, scene: Scene, rig, config: RenderConfig = RenderConfig(), noise_seed: int = 0):
        import open3d as o3d

        self._o3d = o3d
        self.rig = rig
        self.config = config
        self.set_scene(scene)
        w, h = rig.image_size
        self.size = (int(w), int(h))
        self.n_px = int(w) * int(h)
        dl = pixel_rays(rig.K1, rig.D1, rig.image_size)
        dr = pixel_rays(rig.K2, rig.D2, rig.image_size)
        R = np.asarray(rig.R, np.float64)
        T = np.asarray(rig.T, np.float64).reshape(3)
        # Right-eye rays expressed in the LEFT camera frame: d_left = R^T d_right (row form: d @ R).
        self._dirs_cam = np.ascontiguousarray(np.vstack([dl, (dr.astype(np.float64) @ R).astype(np.float32)]))
        self._dirs_len = np.sqrt(np.einsum("ij,ij->i", self._dirs_cam, self._dirs_cam))
        self._right_centre_cam = -R.T @ T  # right eye's centre in the left camera frame
        self._focal = (float(rig.K1[0, 0]), float(rig.K2[0, 0]))
        self._rig_R, self._rig_T = R, T
        # Per eye: a virtual pinhole image over the undistorted ray coordinates (x/z, y/z) and the
        # nearest-neighbour map from it back to the real pixels (object hulls are drawn there).
        self._virt = []
        for dd, f in ((dl, self._focal[0]), (dr, self._focal[1])):
            vx, vy = dd[:, 0] * np.float32(f), dd[:, 1] * np.float32(f)
            off = np.array([8.0 - np.floor(vx.min()), 8.0 - np.floor(vy.min())])
            shape = (int(np.ceil(vy.max() + off[1])) + 9, int(np.ceil(vx.max() + off[0])) + 9)
            m1, m2 = cv2.convertMaps((vx + np.float32(off[0])).reshape(h, w), (vy + np.float32(off[1])).reshape(h, w), cv2.CV_16SC2)
            self._virt.append((f, off, shape, m1, m2))
        # Sensor noise: a pre-drawn buffer read at a random offset per frame (drawing 5.5 M normals
        # per frame would cost more than the ray cast).
        nrng = np.random.default_rng(noise_seed)
        if config.noise_sigma_dn > 0:
            self._noise = nrng.standard_normal(2 * 2 * self.n_px * 3, dtype=np.float32)
            self._noise *= np.float32(config.noise_sigma_dn)
            self._noise += np.float32(0.5)  # rounding offset for the uint8 conversion
        else:
            self._noise = None

    def set_scene(self, scene: Scene) -> None:
        """Swap the scene (e.g. a moved calibration board) keeping the rig's rays and buffers."""
        o3d = self._o3d
        self.scene = scene
        self.materials, self.tri_material = scene.material_table()
        self._n_tri = len(self.tri_material)
        self._tri_material_ext = np.append(self.tri_material, np.int32(-1)).astype(np.int32)  # index n_tri = miss
        self._sun = np.asarray(scene.sun_dir, np.float32)
        # Images are produced in OpenCV's BGR order: reverse every colour once here.
        self._materials_bgr = [_to_bgr(m) for m in self.materials]
        self._needs_footprint = any(m.pattern == "checker" for m in self.materials)
        rs = o3d.t.geometry.RaycastingScene()
        verts = o3d.core.Tensor(np.ascontiguousarray(scene.mesh.vertices, np.float32))
        tris = o3d.core.Tensor(np.ascontiguousarray(scene.mesh.triangles, np.uint32))
        rs.add_triangles(verts, tris)
        self.raycaster = rs
        self._shadow_eps = np.float32(2e-3 * scene.scale_m)
        self._ground_id = -1
        self.shadow_map = None
        self._fast = None
        self._setup_ground_path()
        if self.config.shadows and self._fast is not None:
            self._build_shadow_map()

    def _setup_ground_path(self) -> None:
        """Analytic ground: when the ``ground`` material is one axis-aligned rectangle in z = 0, rays outside
        the projected convex hulls of the other objects are intersected with it analytically (no BVH cast)."""
        names = [m.name for m in self.materials]
        if "ground" not in names:
            return
        gid = names.index("ground")
        verts = np.asarray(self.scene.mesh.vertices, np.float64)
        tris = np.asarray(self.scene.mesh.triangles)
        is_ground = self.tri_material == gid
        gv = verts[tris[is_ground]].reshape(-1, 3)
        if not np.all(np.abs(gv[:, 2]) < 1e-9):
            return  # a 'ground' that is not the plane z = 0 (e.g. the fronto-parallel check plane)
        lo, hi = gv[:, :2].min(axis=0), gv[:, :2].max(axis=0)
        # The ground triangles must tile their bounding rectangle exactly (the analytic test is the rectangle).
        g = tris[is_ground]
        e1, e2 = verts[g[:, 1]] - verts[g[:, 0]], verts[g[:, 2]] - verts[g[:, 0]]
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
        if abs(area - np.prod(hi - lo)) > 1e-6 * np.prod(hi - lo):
            return
        # Objects = triangles grouped by material prefix ("truck.", "dis3.", ...): their vertices.
        groups: dict[str, list[int]] = {}
        for ti in np.nonzero(~is_ground)[0]:
            groups.setdefault(self.materials[self.tri_material[ti]].name.split(".")[0], []).append(int(ti))
        objects = [verts[np.unique(tris[idx])] for idx in groups.values()]
        self._fast = {"gid": gid, "tri": int(np.nonzero(is_ground)[0][0]), "lo": lo.astype(np.float32), "hi": hi.astype(np.float32),
                      "objects": objects, "is_ground": is_ground}

    def _build_shadow_map(self) -> None:
        """Ground shadow map (the scene has a ``ground`` rectangle in z = 0) when the sun is up."""
        if self._sun[2] < 0.05:
            return
        gid = self._fast["gid"]
        tri_v = np.asarray(self.scene.mesh.vertices, np.float64)[np.asarray(self.scene.mesh.triangles)]  # (M, 3, 3)
        is_ground = self._fast["is_ground"]
        cell = self.materials[gid].texel_m  # the ground's noise texel: ~0.75 px footprint at the working range
        self.shadow_map = ground_shadow_map(self.raycaster, tri_v[~is_ground], self._sun, cell, float(self._shadow_eps))
        self._ground_id = gid

    def _object_mask(self, eye: int, T_wc: np.ndarray) -> np.ndarray | None:
        """(H*W,) uint8, 1 where a ray of ``eye`` may hit a non-ground object: inside the image of an object's
        convex hull (clipped at the camera plane when the object straddles it), dilated by 2 px."""
        f, off, shape, m1, m2 = self._virt[eye]
        Rcw, o = T_wc[:3, :3].T, T_wc[:3, 3]
        mask = np.zeros(shape, np.uint8)
        drawn = False
        h, w = shape
        for V in self._fast["objects"]:
            X = (V - o) @ Rcw.T  # a few hundred vertices: cheap
            if eye == 1:
                X = X @ self._rig_R.T + self._rig_T
            z = X[:, 2]
            if np.all(z <= _Z_NEAR_M):
                continue  # behind the camera: no ray (all have z > 0) reaches it
            if z.min() < _Z_NEAR_M:
                # Straddles the camera plane: hull(V) clipped to z >= z_near is the hull of the front
                # vertices and of every front-back segment's crossing of the plane.
                fr, bk = X[z >= _Z_NEAR_M], X[z < _Z_NEAR_M]
                a = (_Z_NEAR_M - bk[None, :, 2]) / (fr[:, None, 2] - bk[None, :, 2])
                cross = bk[None] + a[..., None] * (fr[:, None] - bk[None])
                X = np.vstack([fr, cross.reshape(-1, 3)])
            uv = X[:, :2] / X[:, 2:3] * f + off
            hull = cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2).astype(np.float64)
            hull = _clip_convex(hull, -4.0, -4.0, w + 4.0, h + 4.0)
            if len(hull) < 3:
                continue
            cv2.fillConvexPoly(mask, np.round(hull * 16).astype(np.int32), 1, cv2.LINE_8, 4)
            drawn = True
        if not drawn:
            return np.zeros(self.n_px, np.uint8)
        mask = cv2.dilate(mask, np.ones((5, 5), np.uint8))  # 2 px margin for the nearest-neighbour lookup
        return cv2.remap(mask, m1, m2, cv2.INTER_NEAREST).reshape(-1)

    def _make_rays(self, T_wc: np.ndarray) -> tuple[np.ndarray, tuple]:
        """World directions of every pixel ray of both eyes (left first) for the left-camera pose ``T_wc``, in a
        reused (2n, 3) float32 buffer (z-depth scaled); returns (directions, (left origin, right origin) float32)."""
        n = self.n_px
        Rwc = T_wc[:3, :3]
        origins = (T_wc[:3, 3], T_wc[:3, 3] + Rwc @ self._right_centre_cam)
        if getattr(self, "_d", None) is None:
            # Reused buffer (fresh image-sized arrays per frame cost page faults).
            self._d = np.empty((2 * n, 3), np.float32)
        d = self._d
        eyes = (slice(0, n), slice(n, 2 * n))
        list(self._pool().map(lambda e: cv2.transform(self._dirs_cam[eyes[e]].reshape(n, 1, 3), Rwc, dst=d[eyes[e]].reshape(n, 1, 3)), (0, 1)))
        return d, tuple(o.astype(np.float32) for o in origins)

    def rays(self, T_wc: np.ndarray) -> np.ndarray:
        """(2HW, 6) float32 Open3D rays [origin, direction] of every pixel of both eyes (left eye's rows first)
        for the left-camera pose ``T_wc``; a ray reaches z-depth t (metres) at origin + t * direction."""
        d, origins32 = self._make_rays(np.asarray(T_wc, np.float64))
        return self._ray_array(d, origins32, None)

    def _ray_array(self, d: np.ndarray, origins32, idx: np.ndarray | None) -> np.ndarray:
        """Open3D ray array of all rays (idx None) or of the rays ``idx`` (sorted indices into both eyes)."""
        n = self.n_px
        if idx is None:
            idx_e = (slice(0, n), slice(n, 2 * n))
            k = 2 * n
            split = n
        else:
            split = int(np.searchsorted(idx, n))
            idx_e = (idx[:split], idx[split:])
            k = len(idx)
        out = np.empty((k, 6), np.float32)
        for e, (a, b) in enumerate(((0, split), (split, k))):
            out[a:b, :3] = origins32[e]
            out[a:b, 3:] = d[idx_e[e]]
        return out

    def first_hits(self, T_wc: np.ndarray, full_cast: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hit of every pixel ray of both eyes (left eye's rows first) for the left-camera pose ``T_wc``.

        Returns copies of (t (2HW,) float32 z-depth in metres, inf = miss; triangle index (2HW,) uint32,
        2^32 - 1 = miss; triangle normals (2HW, 3) float32, world). full_cast=True casts every ray through
        Open3D's BVH instead of intersecting the rays outside the objects' image hulls with the ground
        analytically (the reference the fast path must reproduce).
        """
        T_wc = np.asarray(T_wc, np.float64)
        d, origins32 = self._make_rays(T_wc)
        t, prim, nrm = self._cast(T_wc, origins32, d, self._pool(), full_cast=full_cast)
        return t.copy(), prim.copy(), nrm.copy()

    def _cast(self, T_wc: np.ndarray, origins32, d: np.ndarray, pool, full_cast: bool = False):
        """First hits of all rays: (t_hit (2n,), primitive ids (2n,) uint32 (miss = 2^32-1), normals (2n, 3))."""
        o3d = self._o3d
        n = self.n_px
        eyes = (slice(0, n), slice(n, 2 * n))
        fast = self._fast
        masks = None
        if fast is not None and not full_cast and min(o[2] for o in origins32) > 0:
            masks = list(pool.map(lambda e: self._object_mask(e, T_wc), (0, 1)))
            if any(m is None for m in masks):
                masks = None
        if masks is None:
            ans = self.raycaster.cast_rays(o3d.core.Tensor.from_numpy(self._ray_array(d, origins32, None)), nthreads=0)
            return ans["t_hit"].numpy(), ans["primitive_ids"].numpy(), ans["primitive_normals"].numpy()
        if getattr(self, "_t_buf", None) is None:
            self._t_buf = np.empty(2 * n, np.float32)
            self._prim_buf = np.empty(2 * n, np.uint32)
            self._nrm_buf = np.zeros((2 * n, 3), np.float32)
            self._nrm_buf[:, 2] = 1.0
            self._nrm_dirty = np.zeros(0, np.int64)
        t_full, prim_full, nrm_full = self._t_buf, self._prim_buf, self._nrm_buf
        nrm_full[self._nrm_dirty] = (0.0, 0.0, 1.0)
        lo, hi = fast["lo"], fast["hi"]
        gtri = np.uint32(fast["tri"])
        miss = np.uint32(0xFFFFFFFF)

        def ground(e):
            sl, o = eyes[e], origins32[e]
            dz = d[sl, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.float32(-o[2]) / dz
            ok = dz < 0
            x = d[sl, 0] * t
            x += o[0]
            ok &= (x >= lo[0]) & (x <= hi[0])
            y = d[sl, 1] * t
            y += o[1]
            ok &= (y >= lo[1]) & (y <= hi[1])
            t_full[sl] = np.where(ok, t, np.float32(np.inf))
            prim_full[sl] = np.where(ok, gtri, miss)

        list(pool.map(ground, (0, 1)))
        idx = np.nonzero(np.concatenate(masks))[0]
        if len(idx):
            ans = self.raycaster.cast_rays(o3d.core.Tensor.from_numpy(self._ray_array(d, origins32, idx)), nthreads=0)
            t_full[idx] = ans["t_hit"].numpy()
            prim_full[idx] = ans["primitive_ids"].numpy()
            nrm_full[idx] = ans["primitive_normals"].numpy()
        self._nrm_dirty = idx
        return t_full, prim_full, nrm_full

    def _shade_chunk(self, sl: slice, eye: int, t_hit, prim, nrm, d, origin) -> tuple:
        """Hit mask, hit points, normals facing the viewer, (ground-shadowed) Lambert term, textured albedo and
        the indices that still need a shadow ray, for rays ``sl`` of one eye."""
        t = t_hit[sl]
        hit = np.isfinite(t)
        t = np.where(hit, t, np.float32(0.0))
        dd = d[sl]
        # Hit points column by column into a (3, n) buffer, used as its (n, 3) transpose: 3x faster than the
        # broadcast dd * t[:, None], and the x / y columns come out contiguous.
        pT = np.empty((3, len(t)), np.float32)
        for k in range(3):
            np.multiply(dd[:, k], t, out=pT[k])
            pT[k] += origin[k]
        p = pT.T
        mat = self._tri_material_ext[np.minimum(prim[sl], self._n_tri)]  # misses -> -1
        n = nrm[sl]
        dn = np.einsum("ij,ij->i", n, dd)
        n = n * np.where(dn > 0, np.float32(-1.0), np.float32(1.0))[:, None]  # face the viewer (winding not trusted)
        # Pixel footprint on the surface: z-depth / focal / cos(incidence); |d| is rotation invariant.
        if self._needs_footprint:  # only anti-aliased patterns (the chessboard) use it
            cos_inc = np.abs(dn) / self._dirs_len[sl]
            footprint = t / np.float32(self._focal[eye]) / np.maximum(cos_inc, np.float32(0.15))
        else:
            footprint = np.broadcast_to(np.float32(0.0), t.shape)
        albedo = shade_albedo(p, n, mat, self._materials_bgr, footprint, ref_m=origin)
        s = self._sun
        lam = n[:, 0] * s[0]  # elementwise, not n @ sun: no BLAS in the per-frame path (see module notes)
        lam += n[:, 1] * s[1]
        lam += n[:, 2] * s[2]
        np.maximum(lam, 0.0, out=lam)
        need = None
        if self.config.shadows:
            if self.shadow_map is not None:
                ground = mat == self._ground_id
                lit = self.shadow_map.lookup(p[:, 0], p[:, 1])
                lam *= np.where(ground, lit, np.float32(1.0))
                need = np.nonzero(hit & ~ground & (lam > 0))[0]
            else:
                need = np.nonzero(hit & (lam > 0))[0]
        return hit, p, n, lam, albedo, need

    def _finish_chunk(self, sl: slice, eye: int, hit, lam, albedo, d, gain: float, noise_off: int, out: np.ndarray) -> None:
        """Light, sky, noise and 8-bit conversion of rays ``sl`` (one eye) into ``out`` (flat uint8 view)."""
        cfg = self.config
        g = np.float32(gain * (cfg.right_gain if eye == 1 else 1.0))
        light = lam * np.float32(self.scene.sun * g)
        light += np.float32(self.scene.ambient * g)
        img = albedo
        for k in range(3):  # per channel: the (M, 3) x (M, 1) broadcast is several times slower
            img[:, k] *= light
        miss = np.nonzero(~hit)[0]
        if len(miss):
            dm = d[sl][miss]
            el = np.clip(dm[:, 2] / self._dirs_len[sl][miss], 0.0, 1.0)[:, None]
            hz, zen = (np.asarray(c[::-1], np.float32) * g for c in self.scene.sky_rgb)
            img[miss] = hz[None, :] * (1 - el) + zen[None, :] * el
        if cfg.blur_sigma_px > 0:
            w, h = self.size
            img = cv2.GaussianBlur(img.reshape(h, w, 3), (0, 0), cfg.blur_sigma_px).reshape(-1, 3)
        if self._noise is not None:
            a = noise_off + sl.start * 3
            img += self._noise[a: a + img.size].reshape(-1, 3)
        else:
            img += np.float32(0.5)
        np.clip(img, 0, 255, out=img)
        out[sl] = img  # float -> uint8 (truncation after the +0.5 rounding offset)

    def render(self, T_wc: np.ndarray, rng=None, exposure: float | None = None) -> RenderedPair:
        """Render both eyes with the LEFT camera at world-from-camera pose ``T_wc`` (4x4, OpenCV axes).

        rng: seed/Generator for the sensor noise of this frame; exposure: extra gain for this frame.
        The two eyes are shaded in parallel threads (numpy and OpenCV release the GIL on large arrays).
        """
        o3d = self._o3d
        cfg = self.config
        rng = np.random.default_rng(rng)
        T_wc = np.asarray(T_wc, np.float64)
        n = self.n_px
        w, h = self.size
        eyes = (slice(0, n), slice(n, 2 * n))
        pool = self._pool()
        d, origins32 = self._make_rays(T_wc)
        t_hit, prim, nrm = self._cast(T_wc, origins32, d, pool)
        shaded = list(pool.map(lambda e: self._shade_chunk(eyes[e], e, t_hit, prim, nrm, d, origins32[e]), (0, 1)))
        if cfg.shadows:
            # Shadow rays only for the sunlit hits the ground shadow map does not cover, both eyes in one call.
            need = [s[5] for s in shaded]
            k = sum(len(i) for i in need)
            if k:
                srays = np.empty((k, 6), np.float32)
                a = 0
                for (_, p, nn, _, _, idx) in shaded:
                    srays[a:a + len(idx), :3] = p[idx] + nn[idx] * self._shadow_eps
                    a += len(idx)
                srays[:, 3:] = self._sun
                occ = self.raycaster.test_occlusions(o3d.core.Tensor.from_numpy(srays), nthreads=0).numpy().view(bool)
                a = 0
                for (_, _, _, lam, _, idx) in shaded:
                    lam[idx[occ[a:a + len(idx)]]] = 0.0
                    a += len(idx)
        gain = 255.0 * cfg.exposure * (1.0 if exposure is None else float(exposure))
        noise_off = int(rng.integers(0, len(self._noise) - 2 * n * 3)) if self._noise is not None else 0
        out = np.empty((2 * n, 3), np.uint8)
        list(pool.map(lambda e: self._finish_chunk(eyes[e], e, shaded[e][0], shaded[e][3], shaded[e][4], d, gain, noise_off, out), (0, 1)))
        img = out.reshape(2, h, w, 3)
        depth = t_hit[:n].reshape(h, w).astype(np.float32, copy=True)
        return RenderedPair(img[0], img[1], depth)

    def close(self) -> None:
        """Stop the shading threads (the renderer can still be used; they restart on demand)."""
        ex = getattr(self, "_executor", None)
        if ex is not None:
            ex.shutdown(wait=True)
            self._executor = None

    def __enter__(self) -> "StereoRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _pool(self):
        if getattr(self, "_executor", None) is None:
            from concurrent.futures import ThreadPoolExecutor

            self._executor = ThreadPoolExecutor(max_workers=2, thread_name_prefix="synth-shade")
        return self._executor
