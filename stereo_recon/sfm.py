"""Camera poses by structure from motion (pycolmap), made metric with stereo depth.

Pipeline: SIFT extraction with the rectified pinhole intrinsics fixed -> matching (exhaustive for
small sets; otherwise sequential neighbours plus a sparse grid of loop pairs, written as an explicit
pair list so that no vocabulary tree is needed and nothing is fetched at run time) -> incremental
mapping with focal length, principal point and distortion held fixed -> metric scale as the
median ratio of stereo depth to SfM depth at the triangulated points.

Output poses are world-from-left-camera in metres, with the world frame put at the first
registered camera (as the visual-odometry back-end does).
"""

from __future__ import annotations

import math

import logging
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereo_recon.core.errors import InputError, StageError
from stereo_recon.trajectory import Trajectory

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


@dataclass(frozen=True)
class SfMConfig:
    """Settings of the pycolmap back-end."""

    # "auto": exhaustive matching up to exhaustive_max_images images, else sequential + loop pairs
    # (exhaustive matching grows with the square of the image count: 60 HD720 frames take minutes).
    matching: str = "auto"
    exhaustive_max_images: int = 25
    # Sequential matching: each image is matched with its next `sequential_overlap` images.
    sequential_overlap: int = 6
    # Loop pairs: every `loop_stride`-th image is matched with every other such image that is more
    # than sequential_overlap frames away, so an orbit returning to its start gets closed.
    loop_stride: int = 6
    # SIFT features per image; matching time grows with its square. None: 4096 for small images
    # (long side <= 1000 px, e.g. the 640x480 temple ring, which needs them), 2048 for video frames.
    max_num_features: int | None = None
    # SIFT first octave: -1 upsamples the image twice (4x the extraction time; helps small images),
    # 0 starts at full size. None: -1 for images up to 1000 px on the long side, else 0.
    sift_first_octave: int | None = None
    # Longest image side fed to SIFT (-1: full size); intrinsics are given at full size.
    max_image_size: int = -1
    # SIFT peak threshold: lower than COLMAP's 0.0067 finds more features on texture-poor surfaces
    # (temple ring, seeds 0-2: worst rotation error 0.41-0.43 deg at 0.002, 0.44-0.49 at 0.004).
    sift_peak_threshold: float = 0.002
    # Re-match pairs guided by their verified epipolar geometry (more matches on weak texture; about
    # doubles the matching time). None: on for small images only, as max_num_features.
    guided_matching: bool | None = None
    # When too few images register without guided matching, match once more with it. A noisy, far
    # view set (draw random-2081-38: pixel noise 5.9 DN, a full-scale semi-trailer 11 m away) keeps
    # 15-250 verified matches per neighbouring pair and registers 7 of 34 images; guided it registers
    # 34 of 34 (rotation error 0.35 deg against the odometry's 4.6). Only failures pay the extra time.
    guided_retry: bool = True
    # Mapper thresholds, relaxed from COLMAP's 15 / 100 / 30 so that sparse, weakly textured
    # views (e.g. the Middlebury temple ring) still register; geometric verification stays on.
    min_num_matches: int = 10
    init_min_num_inliers: int = 50
    abs_pose_min_num_inliers: int = 15
    # Observations reprojecting further than this (px) are dropped after bundle adjustment. COLMAP's
    # default is 4 px; with the intrinsics known, 1 px halves the rotation errors on the temple ring.
    filter_max_reproj_error_px: float = 1.0
    # Fewer registered images than this fraction of the input -> StageError.
    min_registered_fraction: float = 0.5
    # Depth samples outside this range are ignored when estimating the metric scale (metres).
    scale_depth_min_m: float = 0.3
    scale_depth_max_m: float = math.inf
    # At least this many depth/SfM correspondences are needed for a metric scale.
    scale_min_samples: int = 50
    # Threads for pycolmap's matching and mapping (-1: all cores). One by default: COLMAP's multi-threaded matching and
    # bundle adjustment differ between identical runs in the last digits, which moves the fused cloud
    # (the 12 m preset's far-scene refinement: different cloud bytes per run); one thread repeats
    # exactly, at ~1.3x the time (poses stage there 29 s instead of 23 s).
    num_threads: int = 1
    # Threads for SIFT extraction alone (-1: all cores). Each image's features are the same whatever the count, but
    # COLMAP numbers the images in the order their extraction finishes, so with more threads the image ids, hence
    # the mapper's order and the poses' last digits, change from run to run (2085/4's 34 views: ids permuted in 2 of
    # 3 runs on 2 threads, poses not bit-identical). One keeps runs repeatable; more is faster (there 9.7 s instead of
    # 21.9 s on 2 cores: `benchmarks/bench_sfm.py`, docs/ROUNDS.md, issue 12's fifty-seventh round).
    extraction_threads: int = 1
    # Seed of pycolmap's RANSAC and mapper.
    seed: int = 0

    def __post_init__(self) -> None:
        from stereo_recon.core.errors import ConfigError

        if self.matching not in ("auto", "exhaustive", "sequential"):
            raise ConfigError(f"SfMConfig.matching: {self.matching!r} is not auto, exhaustive or sequential")
        if self.sequential_overlap < 1 or self.loop_stride < 1:
            raise ConfigError("SfMConfig: sequential_overlap and loop_stride must be >= 1")


def _frame_index(stem: str, fallback: int) -> int:
    m = re.search(r"(\d+)$", stem)
    return int(m.group(1)) if m else fallback


def list_images(image_dir) -> list[str]:
    """Sorted image file names (not paths) in image_dir; InputError if there are fewer than 3."""
    image_dir = Path(image_dir)
    if not image_dir.is_dir():
        raise InputError(f"{image_dir}: image folder not found")
    names = sorted(p.name for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    if len(names) < 3:
        raise InputError(f"{image_dir}: {len(names)} images, SfM needs at least 3")
    return names


def loop_pairs(n: int, overlap: int, stride: int) -> list[tuple[int, int]]:
    """Image index pairs for sequential + loop matching (i < j, no duplicates).

    n: images in video order. overlap: each image is paired with the next `overlap` ones.
    stride: images 0, stride, 2*stride ... are also paired with each other when further apart than overlap.
    """
    pairs = {(i, j) for i in range(n) for j in range(i + 1, min(n, i + overlap + 1))}
    sparse = list(range(0, n, stride))
    pairs |= {(i, j) for a, i in enumerate(sparse) for j in sparse[a + 1 :] if j - i > overlap}
    return sorted(pairs)


def _pose_T_wc(image) -> np.ndarray:
    cfw = image.cam_from_world
    cfw = cfw() if callable(cfw) else cfw
    M = np.eye(4)
    M[:3, :4] = np.asarray(cfw.matrix())
    return np.linalg.inv(M)


def _metric_scale(rec, names_by_id: dict, depth_dir: Path, config: SfMConfig) -> tuple[float, dict]:
    """Median of stereo depth / SfM depth over triangulated points seen in images with depth maps."""
    ratios = []
    used = 0
    for image_id, image in rec.images.items():
        name = names_by_id[image_id]
        path = depth_dir / (Path(name).stem + ".npy")
        if not path.is_file():
            continue
        depth = np.load(path, mmap_mode="r")
        T_cw = np.linalg.inv(_pose_T_wc(image))
        uv, xyz = [], []
        for p2d in image.points2D:
            if p2d.has_point3D():
                uv.append(p2d.xy)
                xyz.append(rec.points3D[p2d.point3D_id].xyz)
        if not uv:
            continue
        uv = np.asarray(uv)
        Xc = np.asarray(xyz) @ T_cw[:3, :3].T + T_cw[:3, 3]
        # COLMAP's pixel centres are at +0.5; depth map pixel (r, c) has its centre at (c + 0.5, r + 0.5).
        cols = np.floor(uv[:, 0]).astype(int)
        rows = np.floor(uv[:, 1]).astype(int)
        h, w = depth.shape[:2]
        ok = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h) & (Xc[:, 2] > 0)
        d = np.full(len(uv), np.nan)
        d[ok] = depth[rows[ok], cols[ok]]
        ok &= np.isfinite(d) & (d >= config.scale_depth_min_m) & (d <= config.scale_depth_max_m)
        if ok.any():
            used += 1
            ratios.append(d[ok] / Xc[ok, 2])
    r = np.concatenate(ratios) if ratios else np.zeros(0)
    if len(r) < config.scale_min_samples:
        raise StageError(
            "poses",
            f"SfM metric scale: only {len(r)} stereo-depth samples at triangulated points "
            f"(need {config.scale_min_samples}); check the depth maps in {depth_dir}",
        )
    s = float(np.median(r))
    mad = float(np.median(np.abs(r - s)))
    q25, q75 = np.percentile(r, [25, 75])
    stats = {
        "scale_source": "stereo_depth_ratio",
        "scale": s,
        "scale_mad_rel": mad / s,
        "scale_iqr_rel": float((q75 - q25) / s),
        "scale_samples": int(len(r)),
        "scale_images": int(used),
    }
    return s, stats


def _reset_work_dir(work_dir: Path) -> tuple[Path, Path]:
    """(database.db, sparse/) in work_dir, the previous SfM files removed."""
    work_dir.mkdir(parents=True, exist_ok=True)
    db = work_dir / "database.db"
    sparse = work_dir / "sparse"
    for p in (db, work_dir / "database.db-shm", work_dir / "database.db-wal"):
        p.unlink(missing_ok=True)
    shutil.rmtree(sparse, ignore_errors=True)
    sparse.mkdir()
    return db, sparse


def _feature_options(pycolmap, K: np.ndarray, first_image: Path, config: SfMConfig):
    """(reader, extraction, matching, verification) options: the rectified pinhole K fixed, SIFT sized to the images."""
    import cv2

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    # COLMAP puts pixel centres at +0.5 (image origin at the top-left corner), OpenCV at integers.
    reader.camera_params = ",".join(f"{v:.9g}" for v in (K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5))
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = config.extraction_threads
    extraction.max_image_size = config.max_image_size
    extraction.sift.peak_threshold = config.sift_peak_threshold
    first = cv2.imread(str(first_image), cv2.IMREAD_UNCHANGED)
    if first is None:
        raise InputError(f"{first_image}: cannot read image")
    small = max(first.shape[:2]) <= 1000
    extraction.sift.first_octave = (config.sift_first_octave if config.sift_first_octave is not None
                                    else -1 if small else 0)
    extraction.sift.max_num_features = (config.max_num_features if config.max_num_features is not None
                                        else 4096 if small else 2048)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = config.num_threads
    matching.guided_matching = config.guided_matching if config.guided_matching is not None else small
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = config.seed
    return reader, extraction, matching, verification


def _mapping_options(pycolmap, config: SfMConfig):
    """Incremental mapping options: intrinsics held fixed, seeded."""
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = config.num_threads
    opts.random_seed = config.seed
    opts.multiple_models = False
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.mapper.abs_pose_refine_focal_length = False
    opts.mapper.abs_pose_refine_extra_params = False
    opts.min_num_matches = config.min_num_matches
    opts.mapper.init_min_num_inliers = config.init_min_num_inliers
    opts.mapper.abs_pose_min_num_inliers = config.abs_pose_min_num_inliers
    opts.mapper.filter_max_reproj_error = config.filter_max_reproj_error_px
    opts.mapper.random_seed = config.seed
    opts.triangulation.random_seed = config.seed
    return opts


def _match(pycolmap, db: Path, names: list[str], work_dir: Path, matching, verification,
           config: SfMConfig) -> tuple[str, int]:
    """Match the images' features: exhaustive for small sets, else sequential plus loop pairs; (mode, pairs)."""
    mode = config.matching
    if mode == "auto":
        mode = "exhaustive" if len(names) <= config.exhaustive_max_images else "sequential"
    if mode == "exhaustive":
        pycolmap.match_exhaustive(db, matching_options=matching, verification_options=verification,
                                  device=pycolmap.Device.cpu)
        return mode, len(names) * (len(names) - 1) // 2
    pairs = loop_pairs(len(names), config.sequential_overlap, config.loop_stride)
    pair_file = work_dir / "pairs.txt"
    pair_file.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(pair_file)
    pycolmap.match_image_pairs(db, matching_options=matching, pairing_options=pairing,
                               verification_options=verification, device=pycolmap.Device.cpu)
    return mode, len(pairs)


class TooFewRegistered(StageError):
    """SfM ran but registered too few of the images (no initial pair, or under min_registered_fraction)."""

    def __init__(self, reason: str):
        super().__init__("poses", reason)
        self.reason = reason


def _largest_model(models, names: list[str], config: SfMConfig):
    """The reconstruction with the most registered images; TooFewRegistered when too few are registered."""
    if not models:
        raise TooFewRegistered(f"SfM found no initial image pair among {len(names)} images")
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    n_reg = rec.num_reg_images()
    if n_reg < max(3, int(np.ceil(config.min_registered_fraction * len(names)))):
        raise TooFewRegistered(f"SfM registered only {n_reg} of {len(names)} images")
    return rec


def _metric_trajectory(rec, names: list[str], matching: dict, baseline_m: float | None, depth_dir,
                       config: SfMConfig, fps: float | None) -> Trajectory:
    """World-from-left-camera poses (m) of the registered images, world at the first one, scaled by stereo depth.

    matching: {"mode", "pairs"} of the matching step (recorded in the stats with baseline_m)."""
    names_by_id = {iid: img.name for iid, img in rec.images.items()}
    reg = sorted((names.index(img.name), iid) for iid, img in rec.images.items() if img.has_pose)
    order = [iid for _, iid in reg]
    if not order:
        raise StageError("poses", "SfM registered none of the images")
    T = np.stack([_pose_T_wc(rec.images[iid]) for iid in order])
    stats = {
        "backend": "sfm",
        "images": len(names),
        "registered": len(order),
        "unregistered": sorted(set(names) - {names_by_id[i] for i in order}),
        "matching": matching["mode"],
        "match_pairs": int(matching["pairs"]),
        "points3D": int(rec.num_points3D()),
        "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()),
        "baseline_m": baseline_m,
    }
    scale = 1.0
    if depth_dir is not None:
        scale, sstats = _metric_scale(rec, names_by_id, Path(depth_dir), config)
        stats.update(sstats)
    else:
        stats["scale_source"] = "none"
        log.warning("SfM without depth maps: poses are up to an unknown scale")
    # World frame at the first registered camera, metres.
    T0_inv = np.linalg.inv(T[0])
    T = T0_inv @ T
    T[:, :3, 3] *= scale
    idx = np.array([_frame_index(Path(names_by_id[i]).stem, pos) for pos, i in reg])
    ts = idx / fps if fps else idx.astype(float)
    log.info("SfM: %d/%d images registered, %d points, scale %.5g", len(order), len(names),
             stats["points3D"], scale)
    return Trajectory(idx, ts, T, stats)


def sfm_poses(
    image_dir,
    K_rect: np.ndarray,
    work_dir,
    baseline_m: float | None = None,
    depth_dir=None,
    config: SfMConfig = SfMConfig(),
    fps: float | None = None,
    image_names: list[str] | None = None,
) -> Trajectory:
    """Poses of the (rectified, left-eye) images in image_dir by pycolmap incremental SfM.

    image_dir: folder of images in video order; frame indices come from trailing digits of the names.
    K_rect: (3,3) pinhole intrinsics in px, shared by all images and held fixed.
    work_dir: scratch folder (database.db, sparse/); its previous SfM files are replaced.
    baseline_m: stereo baseline (recorded in the stats; metric scale comes from depth_dir).
    depth_dir: folder of <image stem>.npy left-eye depth maps (metres, NaN invalid) aligned with
        the images; gives the metric scale. Without it the poses keep SfM's arbitrary scale
        (stats["scale_source"] == "none").
    fps: timestamps = index / fps (else the index itself).
    Returns world-from-left-camera poses of the registered images; unregistered names in stats, and
    stats["guided_matching"]: whether the poses come from guided matching (on for small images; for others
    only after a first pass registered too few, ``SfMConfig.guided_retry``).
    Raises StageError('poses', ...) when the reconstruction fails.
    """
    import pycolmap

    if not log.isEnabledFor(logging.DEBUG):
        # COLMAP's per-image INFO lines only with -v -v; a higher level set by the caller (-q) stays.
        pycolmap.logging.minloglevel = max(int(pycolmap.logging.minloglevel), 1)
    image_dir = Path(image_dir)
    names = list(image_names) if image_names is not None else list_images(image_dir)
    K = np.asarray(K_rect, dtype=np.float64)
    if K.shape != (3, 3):
        raise InputError(f"K_rect: expected a 3x3 matrix, got shape {K.shape}")
    work_dir = Path(work_dir)
    options = _feature_options(pycolmap, K, image_dir / names[0], config)
    matching = options[2]
    try:
        rec, mode, n_pairs = _reconstruct(pycolmap, image_dir, names, work_dir, options, config)
    except TooFewRegistered as err:
        if matching.guided_matching or not config.guided_retry:
            raise
        # Guided matching finds the matches a noisy or weakly textured pair's descriptors alone miss.
        log.info("SfM: %s without guided matching; matching again guided by each pair's epipolar geometry",
                 err.reason)
        matching.guided_matching = True
        rec, mode, n_pairs = _reconstruct(pycolmap, image_dir, names, work_dir, options, config)
    traj = _metric_trajectory(rec, names, {"mode": mode, "pairs": n_pairs}, baseline_m, depth_dir, config, fps)
    traj.stats["guided_matching"] = bool(matching.guided_matching)
    return traj


def _reconstruct(pycolmap, image_dir: Path, names: list[str], work_dir: Path, options, config: SfMConfig):
    """(largest reconstruction, matching mode, pairs matched) of one extraction-matching-mapping pass in work_dir.

    options: (reader, extraction, matching, verification) from ``_feature_options``. Raises StageError('poses').
    """
    reader, extraction, matching, verification = options
    db, sparse = _reset_work_dir(work_dir)
    try:
        pycolmap.extract_features(
            db, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
        )
        mode, n_pairs = _match(pycolmap, db, names, work_dir, matching, verification, config)
        models = pycolmap.incremental_mapping(db, image_dir, sparse, options=_mapping_options(pycolmap, config))
    except StageError:
        raise
    except Exception as err:  # pycolmap raises plain RuntimeError/ValueError on bad input
        raise StageError("poses", f"pycolmap SfM failed: {err}") from err
    return _largest_model(models, names, config), mode, n_pairs


def _depth_witness(vo: Trajectory, sfm: Trajectory, keyframes, depth_dir: Path, K: np.ndarray,
                   baseline_m: float) -> dict | None:
    """Mean depth agreement of consecutive fused views under VO's and under SfM's (grafted) poses: {"vo", "sfm",
    "pairs"}; None when fewer than two views have a pose in both and a depth map (``fusion.depth_agreement``)."""
    from stereo_recon.fusion import depth_agreement

    pos_vo = {int(i): k for k, i in enumerate(vo.indices)}
    pos_sfm = {int(i): k for k, i in enumerate(sfm.indices)}
    views = [int(i) for i in sorted(keyframes)
             if int(i) in pos_vo and int(i) in pos_sfm and (depth_dir / f"{int(i):06d}.npy").is_file()]
    if len(views) < 2:
        return None
    depths = [np.load(depth_dir / f"{i:06d}.npy") for i in views]
    fb = float(K[0, 0]) * float(baseline_m)
    agree = {name: float(np.mean(depth_agreement(np.stack([tr.T_wc[pos[i]] for i in views]), depths, K, fb)))
             for name, tr, pos in (("vo", vo, pos_vo), ("sfm", sfm, pos_sfm))}
    return {**agree, "pairs": len(views) - 1}


def refine_with_sfm(traj: Trajectory, keyframes, partners: dict[int, int], work: Path, K: np.ndarray,
                    baseline_m: float, fps: float | None, counts: dict, max_move_rel: float,
                    max_turn_deg: float) -> Trajectory:
    """VO's trajectory with the fused views' and partners' poses replaced by pycolmap SfM's (VO's world, SfM's scale).

    traj: VO's trajectory (rectified left camera, m); keyframes: the fused views' frame indices, images in
    work/images/<index>.png and depth in work/depth; partners: view -> motion-stereo partner frame, images in
    work/partner/<view>.png; K (3,3) px and baseline_m (m): the rectified rig. max_move_rel / max_turn_deg:
    the largest median correction of VO's views that is still a refinement (a fraction of the path's rms
    radius; degrees: ``ReconstructConfig.refine_max_move_rel`` / ``refine_max_turn_deg``). Records the outcome
    in counts["sfm_refine"]; on failure, or when SfM's poses lie further from VO's than that, logs it and
    returns traj unchanged.
    """
    import os

    from stereo_recon.trajectory import graft_poses

    folder = work / "sfm_images"
    folder.mkdir()
    sources = {idx: work / "images" / f"{idx:06d}.png" for idx in keyframes}
    for view, j in partners.items():  # partner images are stored under their view's index
        sources.setdefault(j, work / "partner" / f"{view:06d}.png")
    names = []
    for idx in sorted(sources):
        if sources[idx].is_file():
            os.link(sources[idx], folder / f"{idx:06d}.png")
            names.append(f"{idx:06d}.png")
    if len(names) < 3:
        counts["sfm_refine"] = "skipped: fewer than 3 images"
        return traj
    try:
        refined = sfm_poses(folder, K, work / "sfm", baseline_m=baseline_m, depth_dir=work / "depth",
                            config=SfMConfig(), fps=fps, image_names=names)
        # SfM's scale, not VO's: both are metric from the rig's depth, but the bundle adjustment's (the median
        # stereo/SfM depth ratio over thousands of points in every view) is the better one. Tuning seeds
        # 2079-2082 (139 runs with both): SfM's path length lay within -0.5..+1.0 % (5th-95th percentile) of
        # where motion stereo's rescale to the rig's depth finally put it, VO's within -5.6..+0.2 %, down to
        # -24.6 % (2082/21, a far flatbed whose VO turned 14 deg off), which motion stereo refused to correct
        # (beyond its max_rescale). Measured: docs/ROUNDS.md, issue 12's fifty-third round.
        out, stats = graft_poses(traj, refined, keep_refined_scale=True)
    except (StageError, ValueError) as err:
        log.warning("pose refinement by SfM failed (%s); keeping visual odometry's poses", err)
        # The record (run.json, and measurement.json's pose_refinement check) names no work folder (pycolmap's own
        # messages may): a run's is a temporary one, gone once its outputs are committed, whose name would make two
        # runs' records differ.
        counts["sfm_refine"] = "failed: " + str(err).replace(str(work), "the work folder")
        return traj
    counts["sfm_refine"] = {"images": len(names), "registered": int(refined.stats.get("registered", len(refined))),
                            "guided_matching": bool(refined.stats.get("guided_matching", False)), **stats}
    if stats["moved_rel_median"] > max_move_rel or stats["turned_deg_median"] > max_turn_deg:
        # Not a refinement but another solution, and one of the two is wrong: SfM can converge to a
        # self-consistent wrong orbit (each view's points still agree with its stereo depth; fiftieth round), and
        # VO can break (a far tanker's odometry turned 130 deg off at four of its twelve views while SfM was
        # right to 0.02 m; fifty-sixth round). The witness is the views' own depth: whichever poses make
        # consecutive views' depth maps agree better are kept (``depth_agreement``); without depth, VO's.
        where = (f"SfM's poses lie {stats['moved_rel_median']:.2f} of the path's radius and "
                 f"{stats['turned_deg_median']:.1f} deg from visual odometry's (median; a refinement stays within "
                 f"{max_move_rel:g} and {max_turn_deg:g} deg)")
        witness = _depth_witness(traj, out, keyframes, work / "depth", K, baseline_m)
        if witness is not None:
            counts["sfm_refine"]["depth_agreement"] = witness
        if witness is None or not witness["sfm"] > witness["vo"]:
            reason = where + ("" if witness is None else
                              f"; consecutive views' depth agrees on {100 * witness['vo']:.1f} % of their pixels with "
                              f"visual odometry's poses, {100 * witness['sfm']:.1f} % with SfM's")
            log.warning("pose refinement by SfM rejected: %s; keeping visual odometry's poses", reason)
            counts["sfm_refine"]["rejected"] = reason
            return traj
        counts["sfm_refine"]["kept_over_odometry"] = (
            where + f"; kept: consecutive views' depth agrees on {100 * witness['sfm']:.1f} % of their pixels with "
                    f"SfM's poses, {100 * witness['vo']:.1f} % with visual odometry's")
        log.warning("pose refinement by SfM is another solution than visual odometry's (%s), kept: consecutive "
                    "views' depth agrees better with it (%.1f %% against %.1f %% of their pixels)", where,
                    100 * witness["sfm"], 100 * witness["vo"])
        return out
    log.info("poses: %d of %d frames bundle-adjusted by SfM (median change %.1f mm, %.3f deg)",
             stats["grafted_frames"], len(names), 1000 * stats["moved_m_median"], stats["turned_deg_median"])
    return out
