"""Data-quality gates of a recording: what the frames and the reconstruction say about the input.

Before the reconstruction (a few frames, seconds): are the two eyes different images, in the right
order, and does the calibration fit them (its size, and whether the frames are already rectified,
as ``calib-check`` judges it)? After it (``run.json``): were all the frames decoded? A gate is a
check ``{"name", "status": "pass" | "warn" | "fail", "detail"}`` (the ``data_quality`` contract of
``measurement.json``); where nothing can be measured at all the recording is refused (InputError).
The orbit, camera-motion and per-face checks need the measured truck: ``measure.quality``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from stereo_recon.core.errors import InputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordingQualityConfig:
    """Thresholds of the recording gates."""

    check_frames: int = 3                  # frames spread over the selection, matched eye to eye before the run
    identical_eyes_max_diff: float = 0.5   # mean |left - right| (grey levels, 0-255) below which the eyes are one image
    swapped_min_fraction: float = 0.8      # raw matches with negative disparity above this share: eyes swapped
    min_decoded_fraction: float = 0.95     # decoded frames / frames the container announces, below: incomplete orbit
    min_parallax_deg: float = 5.0          # camera travel seen from the scene (deg), below: a static camera


def check(name: str, status: str, detail: str) -> dict:
    """One data-quality check in the ``measurement.json`` contract."""
    return {"name": name, "status": status, "detail": detail}


def sample_pairs(source, n: int) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``n`` (name, left, right) frames spread over a stereo source's selection; undecodable ones are skipped."""
    import cv2

    from stereo_recon.core.frames import split_side_by_side
    from stereo_recon.video import SideBySideVideo

    idx = list(source.selected_indices())
    if not idx:
        return []
    want = sorted({idx[int(round(i))] for i in np.linspace(0, len(idx) - 1, min(n, len(idx)))})
    pairs = []
    if isinstance(source, SideBySideVideo):
        cap = cv2.VideoCapture(str(source.path))
        try:
            for i in want:
                cap.set(cv2.CAP_PROP_POS_FRAMES, i)
                ok, frame = cap.read()
                if ok and frame is not None:
                    left, right = split_side_by_side(frame, f"{source.path} frame {i}")
                    pairs.append((f"frame {i}", left, right))
        finally:
            cap.release()
        return pairs
    for frame in source:
        if frame.index in want:
            pairs.append((f"frame {frame.index}", frame.left, frame.right))
        if frame.index >= want[-1]:
            break
    return pairs


def _calibration_size(calib, rig) -> tuple[int, int]:
    """The eye size the calibration was made for, before any scaling to the video."""
    from calib.io import parse_calib_arg
    from calib.zedconf import ZED_RESOLUTIONS

    res = rig.metadata.get("zed_resolution")
    if str(calib).lower().endswith(".conf") and res in ZED_RESOLUTIONS:
        return tuple(ZED_RESOLUTIONS[res])
    try:
        return tuple(parse_calib_arg(str(calib)).image_size)
    except InputError:  # inline parameters without a size: made for the video's own
        return tuple(rig.image_size)


def _rectified_rig(rig):
    """The rectified camera of a raw calibration (OpenCV's stereoRectify, alpha 0) as a rectified rig, and
    its ``--calib`` text: what an exporter that rectifies with the same calibration gives."""
    from calib.rig import StereoRig

    rect = rig.rectification(alpha=0.0)
    K = rect.K_rect
    text = f"--calib {K[0, 0]:.3f},{K[1, 1]:.3f},{K[0, 2]:.3f},{K[1, 2]:.3f},{rect.baseline_m:.6f}"
    return StereoRig.from_rectified(K[0, 0], K[1, 1], K[0, 2], K[1, 2], rect.baseline_m, rig.image_size,
                                    source=f"rectified camera of {rig.metadata.get('source', 'the calibration')}"), text


def check_recording(source, rig, rcfg, calib, config: RecordingQualityConfig = RecordingQualityConfig()):
    """Gates on a few frames before the reconstruction; returns (rig, reconstruct config, checks).

    source: an opened ``StereoSource``; rig: the calibration scaled to it; rcfg: ``ReconstructConfig``;
    calib: the ``--calib`` value (for messages). Frames that are already rectified but given a raw
    calibration are reconstructed as rectified (left intrinsics, ``rcfg.rectified``), with a warning.
    Raises InputError where nothing could be measured: identical or swapped eyes, a calibration whose
    rows do not fit (of another size, or raw/rectified the wrong way round).
    """
    from calib.check import check_pairs

    pairs = sample_pairs(source, config.check_frames)
    if not pairs:
        raise InputError(f"{source.path}: no decodable frame in the selected range")
    checks = []
    diff = float(np.mean([np.abs(l.astype(np.int16) - r.astype(np.int16)).mean() for _, l, r in pairs]))
    if diff < config.identical_eyes_max_diff:
        raise InputError(f"{source.path}: both eyes identical (left and right halves differ by {diff:.2f} grey levels "
                         f"on average over {len(pairs)} frames): not a stereo recording, nothing can be measured")
    checks.append(check("eyes_distinct", "pass", f"left and right differ by {diff:.1f} grey levels on average"))
    res = check_pairs(pairs, rig)
    raw, verdict = res["raw"], res["verdict"]
    # The eye order is judged on rectified rows when they align: raw disparities of a far scene (a few px) can
    # be negative for a correct rig (its eyes' principal points and convergence differ by more than that).
    rec = res.get("rectified") or {}
    order = rec if rec.get("matches", 0) >= 20 and np.isfinite(rec.get("negative_disparity_fraction", np.nan)) else raw
    if verdict == "swapped_eyes" or (order["matches"] >= 20 and order["negative_disparity_fraction"] > config.swapped_min_fraction):
        raise InputError(f"{source.path}: eyes swapped: {100 * order['negative_disparity_fraction']:.0f}% of "
                         f"{order['matches']} matched features sit further left in the left half than in the right half (negative disparity); "
                         "the left eye must be the left half (swap the halves of the video)")
    checks.append(check("eye_order", "pass" if order["matches"] >= 20 else "warn",
                        f"{100 * (1 - order['negative_disparity_fraction']):.0f}% of {order['matches']} matches have a "
                        "positive disparity" if order["matches"] else "no feature matches to check the eye order"))
    cal_size, eye = _calibration_size(calib, rig), tuple(source.eye_size)
    size_txt = f"the calibration is for {cal_size[0]}x{cal_size[1]}, the video's eyes are {eye[0]}x{eye[1]}"
    if verdict == "calibration_mismatch":
        if cal_size == eye:
            raise InputError(f"{calib}: does not fit {source.path}: {res['message']}")
        raise InputError(f"{calib}: does not fit {source.path}: rows of matched features disagree both raw (median "
                         f"{raw['median_dy_px']:.2f} px) and rectified (median {res['rectified']['median_dy_px']:.2f} px); "
                         f"{size_txt}; pass the calibration made for {eye[0]}x{eye[1]}")
    if verdict == "not_rectified":
        raise InputError(f"{calib}: {res['message']}")
    if rcfg.rectified and verdict == "ok" and raw["median_dy_px"] > res["thresholds"]["median_px"]:
        raise InputError(f"--rectified: the frames of {source.path} are not rectified (rows of matched features differ by "
                         f"median {raw['median_dy_px']:.2f} px; {calib}'s rectification brings them to "
                         f"{res['rectified']['median_dy_px']:.2f} px): drop --rectified")
    checks.append(check("calibration_size", "pass" if cal_size == eye else "warn",
                        size_txt if cal_size != eye else f"calibration and video are both {eye[0]}x{eye[1]}"))
    if verdict == "already_rectified" and not rcfg.rectified:
        rig, hint = _rectified_rig(rig)
        detail = (f"the video is already rectified (raw rows agree: median |dy| {raw['median_dy_px']:.2f} px; rectified "
                  f"again {res['rectified']['median_dy_px']:.2f} px) but {calib} is a raw calibration: reconstructed "
                  f"with the rectified camera this calibration gives ({hint}); if the exporter's rectified camera "
                  "differs, pass it as --calib fx,fy,cx,cy,baseline_m")
        log.warning("%s", detail)
        checks.append(check("rectification", "warn", detail))
    elif verdict == "inconclusive":
        checks.append(check("rectification", "warn", f"calibration not checked on the frames: {res['message']}"))
    else:
        checks.append(check("rectification", "pass", res["message"]))
    return rig, rcfg, checks


def camera_motion_check(run: dict, centres: np.ndarray | None, config: RecordingQualityConfig = RecordingQualityConfig()):
    """How far the camera moved, seen from the scene (deg of parallax): a static camera has no views around the truck.

    run: ``run.json`` (the first view's disparity, focal length and baseline give the scene depth);
    centres: camera centres (N, 3), metres. None when either is missing.
    """
    counts, rect = run.get("counts") or {}, ((run.get("rig") or {}).get("rectified") or {})
    disp, f, B = counts.get("first_view_disparity_px"), rect.get("focal_px"), rect.get("baseline_m")
    if centres is None or not len(centres) or not (disp and f and B):
        return None
    depth = float(f) * float(B) / float(disp)
    spread = float(np.linalg.norm(np.ptp(np.asarray(centres, float), axis=0)))
    parallax = float(np.degrees(spread / max(depth, 1e-9)))
    if parallax < config.min_parallax_deg:
        return check("camera_motion", "fail", f"the camera moved {spread:.3g} m over the recording, {parallax:.1f} deg seen "
                                              f"from the scene {depth:.3g} m away: a static camera has no views around "
                                              "the truck, so its far faces are not measured")
    return check("camera_motion", "pass", f"the camera moved {spread:.3g} m, {parallax:.0f} deg seen from the scene "
                                          f"{depth:.3g} m away")


def trajectory_scale_check(counts: dict) -> dict | None:
    """The camera path's scale against the rig's depth (motion stereo's ``counts`` in run.json); None without.

    Fails when the two disagree by more than the run corrects (``MotionStereoConfig.max_rescale``): the path
    keeps odometry's scale, and every dimension may be off by as much. Seen on evaluation seed 2035: three
    full-scale tankers whose odometry was 5.6, 10.8 and 23.5 % short by the rig's depth were measured with
    it, one as a confident ``within`` with all three dimensions 16-19 % low.
    """
    ratio = counts.get("trajectory_scale_from_rig")
    if ratio is None:
        return None
    off = 100 * (float(ratio) - 1)
    if abs(float(counts.get("motion_stereo_depth_scale", ratio)) - float(ratio)) > 1e-9:  # measured, not applied
        return check("trajectory_scale", "fail", f"the rig's depth puts the camera path's scale {off:+.1f} % off, more "
                                                 "than the run corrects: every dimension may be that far off")
    return check("trajectory_scale", "pass", f"camera path rescaled by {off:+.2f} % to the rig's depth")


def pose_refinement_check(counts: dict) -> dict | None:
    """Whether SfM's bundle adjustment refined odometry's poses (``counts["sfm_refine"]`` in run.json); None if not run.

    Warns when it failed or was rejected (its poses far from odometry's: another solution, not a refinement):
    the run then keeps odometry's poses, whose views turn by a few tenths of a degree at full scale; and when it
    was another solution kept over odometry's because the views' depth agreed better with it.
    """
    refine = counts.get("sfm_refine")
    if refine is None:
        return None
    if isinstance(refine, dict) and refine.get("rejected"):
        return check("pose_refinement", "warn", f"bundle adjustment rejected: {refine['rejected']}; visual odometry's "
                                                "poses kept")
    if isinstance(refine, dict) and refine.get("kept_over_odometry"):
        # Two different solutions, one chosen by the views' depth (``sfm.refine_with_sfm``): worth a look.
        return check("pose_refinement", "warn", f"bundle adjustment found another solution than visual odometry: "
                                                f"{refine['kept_over_odometry']}")
    if isinstance(refine, dict):
        # Guided matching runs only after a first pass registered too few: worth saying (SfMConfig.guided_retry).
        how = "matched again guided by epipolar geometry, " if refine.get("guided_matching") else ""
        return check("pose_refinement", "pass", f"{refine.get('grafted_frames', 0)} views bundle-adjusted by SfM "
                                                f"({how}median change {refine.get('turned_deg_median', 0.0):.2f} deg)")
    return check("pose_refinement", "warn", f"bundle adjustment {refine}; visual odometry's poses kept")


def checks_from_reconstruction(run: dict, config: RecordingQualityConfig = RecordingQualityConfig()) -> list[dict]:
    """Gates from a reconstruction's ``run.json``: frames decoded against what the container announces, the
    camera path's scale against the rig's depth (far scenes), and whether bundle adjustment refined the poses."""
    src, counts = run.get("source") or {}, run.get("counts") or {}
    extra = [c for c in (trajectory_scale_check(counts), pose_refinement_check(counts)) if c is not None]
    return _frames_decoded_check(src, counts, config) + extra


def _frames_decoded_check(src: dict, counts: dict, config: RecordingQualityConfig) -> list[dict]:
    """Frames decoded against what the container announces (one check, in a list)."""
    fc = int(src.get("frame_count") or 0)
    decoded = int(counts.get("frames_read", 0))
    bad = len(counts.get("bad_frames") or [])
    if fc <= 0:
        return [check("frames_decoded", "warn", f"{decoded} frames decoded; the container does not say how many it holds")]
    start, stop, step = int(src.get("start") or 0), src.get("stop"), int(src.get("step") or 1)
    expected = len(range(start, fc if stop is None else min(int(stop), fc), step))
    if decoded < config.min_decoded_fraction * expected:
        return [check("frames_decoded", "fail", f"only {decoded} of the {expected} frames the video announces were "
                                                 "decoded: the file ends early or is damaged, so the orbit is incomplete")]
    if bad:
        return [check("frames_decoded", "warn", f"{decoded} of {expected} frames decoded; {bad} undecodable and skipped")]
    return [check("frames_decoded", "pass", f"{decoded} of {expected} frames decoded")]
