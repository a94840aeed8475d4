"""Ray-cast stereo rendering of a synthetic scene through a (distorted) stereo rig with Open3D.

Per frame, the viewing rays of both eyes (cached per rig, see :func:`camera.pixel_rays`) are
rotated into the world and cast in ONE ``RaycastingScene.cast_rays`` call; hits are shaded with
Lambert + ambient (shadows from a second, occlusion-only cast toward the sun), rays that miss get
the sky colour, then exposure, optional blur and sensor noise are applied.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from stereo_recon.synthetic.camera import pixel_rays
from stereo_recon.synthetic.scene import Scene
from stereo_recon.synthetic.texture import shade_albedo

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RenderConfig:
    """Image formation settings.

    noise_sigma_dn: std of additive Gaussian sensor noise, in 8-bit grey levels.
    shadows: cast shadow rays toward the sun (about +25% render time).
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


def _to_bgr(m):
    from dataclasses import replace

    pr = dict(m.params)
    for k in ("paint_rgb", "band_rgb", "black_rgb"):
        if k in pr:
            pr[k] = tuple(pr[k])[::-1]
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
        rs = o3d.t.geometry.RaycastingScene()
        verts = o3d.core.Tensor(np.ascontiguousarray(scene.mesh.vertices, np.float32))
        tris = o3d.core.Tensor(np.ascontiguousarray(scene.mesh.triangles, np.uint32))
        rs.add_triangles(verts, tris)
        self.raycaster = rs

    def _shade_chunk(self, sl: slice, eye: int, t_hit, prim, nrm, d, origin) -> tuple:
        """Hit points, normals facing the viewer, Lambert term and textured albedo for rays ``sl`` of one eye."""
        t = t_hit[sl]
        hit = np.isfinite(t)
        t = np.where(hit, t, np.float32(0.0))
        dd = d[sl]
        p = dd * t[:, None]
        p += origin
        mat = self._tri_material_ext[np.minimum(prim[sl], self._n_tri)]  # misses -> -1
        n = nrm[sl]
        dn = np.einsum("ij,ij->i", n, dd)
        n = n * np.where(dn > 0, np.float32(-1.0), np.float32(1.0))[:, None]  # face the viewer (winding not trusted)
        # Pixel footprint on the surface: z-depth / focal / cos(incidence); |d| is rotation invariant.
        dlen = self._dirs_len[sl]
        cos_inc = np.abs(dn) / dlen
        footprint = t / np.float32(self._focal[eye]) / np.maximum(cos_inc, np.float32(0.15))
        albedo = shade_albedo(p, n, mat, self._materials_bgr, footprint, ref_m=origin)
        lam = n @ self._sun
        np.maximum(lam, 0.0, out=lam)
        return hit, p, n, lam, albedo

    def _finish_chunk(self, sl: slice, eye: int, hit, lam, albedo, occ, d, gain: float, noise_off: int, out: np.ndarray) -> None:
        """Light, sky, noise and 8-bit conversion of rays ``sl`` (one eye) into ``out`` (flat uint8 view)."""
        cfg = self.config
        g = np.float32(gain * (cfg.right_gain if eye == 1 else 1.0))
        if occ is not None:
            lam[occ[sl]] = 0.0
        light = lam * np.float32(self.scene.sun) * g
        light += np.float32(self.scene.ambient) * g
        img = albedo
        img *= light[:, None]
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
        The two eyes are shaded in parallel threads (numpy releases the GIL on large arrays).
        """
        o3d = self._o3d
        cfg = self.config
        rng = np.random.default_rng(rng)
        T_wc = np.asarray(T_wc, np.float64)
        Rwc = T_wc[:3, :3]
        n = self.n_px
        w, h = self.size
        origins = (T_wc[:3, 3].astype(np.float32), (T_wc[:3, 3] + Rwc @ self._right_centre_cam).astype(np.float32))
        if getattr(self, "_rays", None) is None:
            # Reused buffers: fresh 44 MB arrays per frame cost page faults.
            self._rays = np.empty((2 * n, 6), np.float32)
            self._d = np.empty((2 * n, 3), np.float32)
        rays, d = self._rays, self._d
        eyes = (slice(0, n), slice(n, 2 * n))
        pool = self._pool()
        Rt = Rwc.T.astype(np.float32)

        def make_rays(e):
            np.matmul(self._dirs_cam[eyes[e]], Rt, out=d[eyes[e]])  # world directions (z-depth scaled)
            rays[eyes[e], 3:] = d[eyes[e]]
            rays[eyes[e], :3] = origins[e]

        list(pool.map(make_rays, (0, 1)))
        ans = self.raycaster.cast_rays(o3d.core.Tensor.from_numpy(rays))
        t_hit = ans["t_hit"].numpy()
        prim = ans["primitive_ids"].numpy()
        nrm = ans["primitive_normals"].numpy()
        shaded = list(pool.map(lambda e: self._shade_chunk(eyes[e], e, t_hit, prim, nrm, d, origins[e]), (0, 1)))
        occ = None
        if cfg.shadows:
            # Shadow rays for every pixel, reusing the ray buffer (cheaper than gathering the lit ones).
            eps = np.float32(2e-3 * self.scene.scale_m)

            def fill(e):
                _, p, nn, _, _ = shaded[e]
                rays[eyes[e], :3] = p + nn * eps
                rays[eyes[e], 3:] = self._sun

            list(pool.map(fill, (0, 1)))
            occ = self.raycaster.test_occlusions(o3d.core.Tensor.from_numpy(rays)).numpy().view(bool)
        gain = 255.0 * cfg.exposure * (1.0 if exposure is None else float(exposure))
        noise_off = int(rng.integers(0, len(self._noise) - 2 * n * 3)) if self._noise is not None else 0
        out = np.empty((2 * n, 3), np.uint8)
        list(pool.map(lambda e: self._finish_chunk(eyes[e], e, shaded[e][0], shaded[e][3], shaded[e][4], occ, d, gain, noise_off, out), (0, 1)))
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
