"""Depth bias per surface: the rig's and the wide pairs' (motion stereo) depth against rendered depth.

Why: a width or height error of the fused cloud comes from the poses, the depth maps, the fusion or
the measurement. Fusing rendered depth with the true poses through the same ``TSDFFusion`` and
measuring it gives the truth within 0.3 % (issue 12, fifth round), so what is left is the depth. This
script says, per surface class, how far each depth map puts the surface along the viewing ray,
relative to the rendered depth (positive: too far, i.e. side walls inside the truck, roofs low).

Usage (a draw, a run that kept its work folder)::

    stereo-recon synth --random 40 --seed 2027 --depth --out D          # or any synth with --depth
    stereo-recon reconstruct D/draw_000/video.* --calib D/draw_000/SN*.conf --out R --keep-work
    python benchmarks/bench_depth_bias.py D/draw_000:R [D/draw_001:R1 ...]

A random draw rendered without ``--depth`` (e.g. a ``bench --random`` draw) works too: the fused views'
depth is rendered again from its ``random_spec`` (the same scene and poses).

Surface classes, from the rendered point: ``roof`` (within 1 % of H of the truck's top), ``sides``
(20-80 % of H: side walls, ends, cab), ``ground<1L`` (the ground within one truck length of its centre),
``walls`` (within 0.2 % of W of the side planes, 20-80 % of H: a box's or a trailer's side walls) and
``deck edge`` (that band on a flatbed: its deck's edge face, the only part of it that reaches the
side planes). Issue 12, twenty-sixth round: the wide pairs put the deck edge 0.3-0.8 % of the
depth too far while the walls beside it are within 0.1 % (the flatbeds' widths 2-4 % short); the rendered
depth fused through the same TSDF (full or half resolution) places that edge within 0.5 % of W.
Per class: median relative depth error over the views (each view's median), and its MAD (%).
``--by-hole-distance`` also splits the wide pairs' ``sides`` by each pixel's distance to the nearest
invalid pixel of its depth map (issue 12, seventh round: the far bias sits next to the holes).

``--refuse`` fuses the run's views again through the same ``TSDFFusion`` settings four ways, {the run's depth,
the rendered depth resampled into the same frames and pixels} x {the run's poses, the true ones}, and prints
each cloud's side walls (a tanker's flanks about its widest line) and roof against the truth, in mm and in
voxels (``bench_error_budget.face_offsets_mm``; the run's poses' cloud moved onto the truth by the similarity of
its cameras). Which of depth, poses and fusion puts the walls where they are: issue 12, fifty-second round.
"""

from __future__ import annotations

import argparse
import glob
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

CLASSES = ("roof", "sides", "ground<1L", "walls", "deck edge")
HOLE_BANDS_PX = ((0, 3), (3, 6), (6, 10), (10, None))  # distance to the nearest invalid pixel, px


def _classes(P: np.ndarray, truth: dict) -> dict:
    """Masks of the surface classes for world points P (N, 3) on the rendered surfaces."""
    H, L = truth["height_m"], truth["length_m"]
    ctr = np.asarray(truth["truck_corners_world_m"], float)[:, :2].mean(axis=0)
    z = P[:, 2]
    near = np.linalg.norm(P[:, :2] - ctr, axis=1) < L
    out = {"roof": np.abs(z - H) < 0.01 * H, "sides": (z > 0.2 * H) & (z < 0.8 * H),
           "ground<1L": (np.abs(z) < 1e-4) & near}
    tk = truth.get("truck") or {}
    if "T_world_truck" in tk:
        T = np.asarray(tk["T_world_truck"], float)
        y = (P - T[:3, 3]) @ T[:3, 1]                      # across the truck, m (truck frame, y left)
        x = (P - T[:3, 3]) @ T[:3, 0]
        W = float(truth["width_m"])
        plane = (np.abs(np.abs(y) - 0.5 * W) < 0.002 * W) & (np.abs(x) < 0.5 * L) & (z > 1e-4)
        if tk.get("body") == "flatbed":
            out["deck edge"] = plane & (z < 0.5 * H)   # the deck (its load stands inside the side planes)
        else:
            out["walls"] = plane & (z > 0.2 * H) & (z < 0.8 * H)
    return out


def _errors(X_raw: np.ndarray, idx: int, depth_of, rig, T_wc_gt: np.ndarray, truth: dict,
            hole_px: np.ndarray | None = None) -> dict:
    """Per class (median relative error, MAD) of points X_raw (N, 3, raw left camera frame, m) of view idx;
    with hole_px (N,: each point's pixel distance to the nearest invalid pixel) also ``sides`` by band."""
    import cv2

    uv, _ = cv2.projectPoints(X_raw.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), rig.K1, rig.D1)
    uv = uv.reshape(-1, 2)
    g = depth_of(idx)
    ui, vi = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    ins = (ui >= 0) & (ui < g.shape[1]) & (vi >= 0) & (vi < g.shape[0])
    z_gt = np.full(len(ui), np.nan)
    z_gt[ins] = g[vi[ins], ui[ins]]
    # Same ray: the ratio of z in the raw frame is the ratio of distances along the ray.
    rel = X_raw[:, 2] / z_gt - 1.0
    with np.errstate(invalid="ignore"):   # points outside the rendered view (NaN) belong to no class
        P = (X_raw * (z_gt / X_raw[:, 2])[:, None]) @ T_wc_gt[:3, :3].T + T_wc_gt[:3, 3]
    out = {}
    classes = _classes(P, truth)
    if hole_px is not None:
        for lo, hi in HOLE_BANDS_PX:
            band = (hole_px >= lo) & (hole_px < (np.inf if hi is None else hi))
            classes[f"sides {lo}-{hi or ''}px"] = classes["sides"] & band
    for name, m in classes.items():
        m = m & np.isfinite(rel)
        if m.sum() > 100:
            r = rel[m]
            out[name] = (float(np.median(r)), float(1.4826 * np.median(np.abs(r - np.median(r)))))
    return out


def _pixels(z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Points (N, 3) of a z-depth map in its camera frame, m (valid pixels only)."""
    h, w = z.shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    ok = np.isfinite(z) & (z > 0)
    return np.stack([u[ok], v[ok], np.ones(ok.sum())], 1) @ np.linalg.inv(K).T * z[ok][:, None]


def _hole_distance(z: np.ndarray) -> np.ndarray:
    """Distance (px) of each valid pixel of a depth map to its nearest invalid pixel, in ``_pixels`` order."""
    import cv2

    ok = np.isfinite(z) & (z > 0)
    return cv2.distanceTransform(ok.astype(np.uint8), cv2.DIST_L2, 3)[ok]


def _rendered_depth(draw: Path, truth: dict):
    """idx -> the left eye's rendered z-depth (H, W) m of frame idx: from draw/depth, else rendered again from
    the draw's ``random_spec`` (cached per frame)."""
    import functools

    if (draw / "depth").is_dir():
        return lambda idx: np.load(draw / "depth" / f"{idx:06d}.npy")
    from stereo_recon.synthetic.envelope import build_draw, spec_from_dict
    from stereo_recon.synthetic.render import StereoRenderer

    d = build_draw(spec_from_dict(truth["random_spec"]))
    renderer = StereoRenderer(d.scene, d.rig, d.render_config, noise_seed=d.noise_seed)
    return functools.lru_cache(maxsize=2)(lambda idx: renderer.render(d.poses[idx]).depth_left_m)


def bias(draw: Path, run: Path, by_hole_distance: bool = False) -> dict:
    """{'rig': {class: [(median, MAD) per view]}, 'wide': {...}} for one draw and its kept-work run."""
    from calib.io import load_rig
    from stereo_recon.trajectory import read_tum

    truth = json.loads((draw / "truth.json").read_text())
    meta = json.loads((run / "run.json").read_text())
    rig = load_rig(glob.glob(str(draw / "SN*.conf"))[0], image_size=tuple(meta["rig"]["image_size"]))
    R1 = rig.rectification(alpha=0.0).R1          # raw left -> rectified left (the pipeline's camera)
    K_rect = np.asarray(meta["rig"]["rectified"]["K_rect"], float)
    gt = read_tum(draw / "poses_gt.txt", fps=float(truth["fps"]))
    scale = float(meta["counts"].get("motion_stereo_depth_scale", 1.0))
    views = sorted(int(p.stem) for p in (run / "work" / "depth").glob("*.npy"))
    wide = {int(p.stem) for p in (run / "work" / "wide").glob("*.npz")}  # views with motion-stereo depth
    res: dict = {"rig": {c: [] for c in CLASSES}, "wide": {c: [] for c in CLASSES}}
    depth_of = _rendered_depth(draw, truth)
    for idx in views:
        if idx in wide or not wide:  # the fused views (with a partner when there is motion stereo)
            z = np.load(run / "work" / "depth" / f"{idx:06d}.npy").astype(float)
            for c, v in _errors(_pixels(z, K_rect) @ R1, idx, depth_of, rig, gt.T_wc[idx], truth).items():
                res["rig"][c].append(v)
        f = run / "work" / "wide" / f"{idx:06d}.npz"
        if f.exists():
            d = np.load(f)
            zw = d["depth"].astype(float) * scale
            X = _pixels(zw, d["K"]) @ (d["R_rect"] @ R1)
            hole = _hole_distance(zw) if by_hole_distance else None
            for c, v in _errors(X, idx, depth_of, rig, gt.T_wc[idx], truth, hole).items():
                res["wide"].setdefault(c, []).append(v)
    return res


def resample_rendered(z_shape: tuple[int, int], K_view: np.ndarray, R_view: np.ndarray, R1: np.ndarray, rig,
                      rendered: np.ndarray) -> np.ndarray:
    """The rendered depth seen from a fused view's frame: its z-depth (m) at each of the view's pixels.

    z_shape: (H, W) of the view's depth map; K_view (3, 3) px its intrinsics; R_view (3, 3) the rotation from the
    rectified left camera to the view's frame (a wide pair's ``R_rect``; identity for the rig's own depth); R1 the
    rig's raw-left-to-rectified rotation; rig: K1, D1 of the raw left eye; rendered: (H', W') z-depth of the raw
    left eye, m. Pixels whose ray leaves the rendered image are NaN (nearest-pixel lookup: no mixing across edges).
    """
    import cv2

    h, w = z_shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3) @ np.linalg.inv(K_view).T
    d_raw = rays @ R_view @ R1                                   # = R1^T R_view^T ray: the raw left camera's frame
    ahead = d_raw[:, 2] > 1e-9
    uv = np.full((len(d_raw), 2), -1.0, np.float32)
    if ahead.any():
        p, _ = cv2.projectPoints(d_raw[ahead].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), rig.K1, rig.D1)
        uv[ahead] = p.reshape(-1, 2)
    z_raw = cv2.remap(np.asarray(rendered, np.float32), uv[:, 0].reshape(h, w), uv[:, 1].reshape(h, w),
                      cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan).reshape(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = z_raw * (rays[:, 2] / d_raw[:, 2])                     # along one ray, z scales with the ray's z
    z[~ahead | ~np.isfinite(z)] = np.nan
    return z.reshape(h, w)


def refused_faces(draw: Path, run: Path) -> dict:
    """{variant: bench_error_budget.face_offsets_mm of the run's views fused again} (see ``--refuse``), plus voxel_m."""
    import dataclasses
    import importlib.util

    import cv2

    from calib.io import load_rig
    from stereo_recon.fusion import FusionConfig, TSDFFusion
    from stereo_recon.stages.fuse import subsample_for_fusion
    from stereo_recon.stages.state import rot4
    from stereo_recon.trajectory import align_trajectories, read_tum

    spec = importlib.util.spec_from_file_location("bench_error_budget", Path(__file__).with_name("bench_error_budget.py"))
    budget = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(budget)
    truth = json.loads((draw / "truth.json").read_text())
    meta = json.loads((run / "run.json").read_text())
    rig = load_rig(glob.glob(str(draw / "SN*.conf"))[0], image_size=tuple(meta["rig"]["image_size"]))
    R1 = rig.rectification(alpha=0.0).R1
    K_rect = np.asarray(meta["rig"]["rectified"]["K_rect"], float)
    fields = {f.name for f in dataclasses.fields(FusionConfig)}
    fcfg = FusionConfig(**{k: v for k, v in meta["parameters"]["fusion"].items() if k in fields})
    fps = float(truth.get("fps", 15.0))
    est, gt = read_tum(run / "poses.txt", fps=fps), read_tum(draw / "poses_gt.txt", fps=fps)
    pose_sets = {"run": {int(i): T for i, T in zip(est.indices, est.T_wc)},
                 "true": {int(i): T @ rot4(R1.T) for i, T in zip(gt.indices, gt.T_wc)}}  # rectified left camera
    scale = float(meta["counts"].get("motion_stereo_depth_scale", 1.0))
    sub = int(meta["counts"].get("fusion_subsample", 1))
    depth_of = _rendered_depth(draw, truth)
    T_wt = np.asarray(truth["truck"]["T_world_truck"], float)
    body = truth["truck"].get("body", "box")
    tank = budget._tank_axes(truth) if body == "tanker" else None
    # Each fused view as the run fused it, and its rendered depth at the same pixels: read and rendered once,
    # fused four times.
    inputs = {}
    for idx in meta["fused_views"]:
        wide = run / "work" / "wide" / f"{idx:06d}.npz"
        if wide.is_file():
            v = np.load(wide)
            color, depth, K_view, R_view = v["color"], v["depth"] * np.float32(scale), v["K"], v["R_rect"]
        else:
            color = cv2.imread(str(run / "work" / "images" / f"{idx:06d}.png"), cv2.IMREAD_COLOR)
            color, depth, K_view = subsample_for_fusion(color, np.load(run / "work" / "depth" / f"{idx:06d}.npy"),
                                                        K_rect, sub)
            R_view = np.eye(3)
        exact = resample_rendered(depth.shape, K_view, R_view, R1, rig, depth_of(idx))
        rendered = np.where(np.isfinite(depth) & (depth > 0), exact, np.nan)
        inputs[idx] = (color, {"run": np.asarray(depth, np.float32), "rendered": rendered.astype(np.float32)},
                       K_view, R_view)
    out = {"voxel_m": float(fcfg.voxel_m)}
    for depth_kind in ("run", "rendered"):
        for pose_kind in ("run", "true"):
            fusion = TSDFFusion(fcfg)
            views = [i for i in meta["fused_views"] if i in pose_sets[pose_kind]]
            for idx in views:
                color, depths, K_view, R_view = inputs[idx]
                fusion.integrate(color, depths[depth_kind], K_view, pose_sets[pose_kind][idx] @ rot4(R_view.T))
            pts = fusion.extract_cloud(min_weight=min(fcfg.min_weight, max(1.0, len(views) / 3.0)))[0]
            s, R, t = align_trajectories(est, gt) if pose_kind == "run" else (1.0, np.eye(3), np.zeros(3))
            truck = (s * (pts @ R.T) + t - T_wt[:3, 3]) @ T_wt[:3, :3]
            out[f"{depth_kind} depth, {pose_kind} poses"] = budget.face_offsets_mm(
                truck, truth["length_m"], truth["width_m"], truth["height_m"], walls=body != "flatbed", tank=tank)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pairs", nargs="+", help="DRAW:RUN (synth folder rendered with --depth : reconstruct --keep-work folder)")
    ap.add_argument("--by-hole-distance", action="store_true",
                    help="also split the wide pairs' sides by distance to the nearest invalid depth pixel")
    ap.add_argument("--refuse", action="store_true",
                    help="fuse each run's views again with its own or the rendered depth, its own or the true poses, "
                         "and print the walls' and roof's offsets from the truth")
    args = ap.parse_args(argv)
    pairs = [pair.partition(":")[::2] for pair in args.pairs]
    for pair, (d, r) in zip(args.pairs, pairs):
        t = Path(d) / "truth.json"
        rendered = (Path(d) / "depth").is_dir() or (t.is_file() and "random_spec" in json.loads(t.read_text()))
        if not (t.is_file() and rendered and (Path(r) / "work" / "depth").is_dir()):
            ap.error(f"{pair}: expected DRAW:RUN, a synth folder rendered with --depth (or a random draw) and a "
                     "reconstruct --keep-work folder")
    if args.refuse:
        print(f"{'draw':28s} {'fused again with':28s} {'wall L mm':>9s} {'wall R mm':>9s} {'voxels':>7s} {'roof mm':>8s}")
        for d, r in pairs:
            res = refused_faces(Path(d), Path(r))
            vox = res.pop("voxel_m")
            for variant, f in res.items():
                mean_vox = 0.5 * (f["wall_left_mm"] + f["wall_right_mm"]) / 1000 / vox
                print(f"{Path(d).name[-28:]:28s} {variant:28s} {f['wall_left_mm']:+9.1f} {f['wall_right_mm']:+9.1f} "
                      f"{mean_vox:+7.2f} {f['roof_mm']:+8.1f}")
        return 0
    per_draw = {"rig": {c: [] for c in CLASSES}, "wide": {c: [] for c in CLASSES}}
    print(f"{'draw':28s} {'depth':5s} " + " ".join(f"{c + ' med/MAD %':>22s}" for c in CLASSES))
    for d, r in pairs:
        res = bias(Path(d), Path(r), args.by_hole_distance)
        for kind in ("rig", "wide"):
            cells = []
            for c in CLASSES:
                v = np.array(res[kind][c])
                if len(v):
                    med = float(np.median(v[:, 0]))
                    per_draw[kind][c].append(med)
                    cells.append(f"{100 * med:+8.3f} / {100 * np.median(v[:, 1]):5.2f} ({len(v):2d})")
                else:
                    cells.append(f"{'-':>22s}")
            print(f"{Path(d).name[-28:]:28s} {kind:5s} " + " ".join(f"{s:>22s}" for s in cells))
        bands = [c for c in res["wide"] if c.startswith("sides ")]
        if bands:
            for c in bands:
                per_draw["wide"].setdefault(c, []).append(float(np.median(np.array(res["wide"][c])[:, 0])))
            print(f"{'':28s} wide sides by distance to a hole: " + "  ".join(
                f"{c[6:]} {100 * np.median(np.array(res['wide'][c])[:, 0]):+.3f}" for c in bands))
    print("median over draws (%):")
    for kind in ("rig", "wide"):
        print(f"  {kind:5s} " + "  ".join(f"{c} {100 * np.median(v):+.3f} (n={len(v)})" if v else f"{c} -"
                                          for c, v in per_draw[kind].items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
