"""Render a whole synthetic drone sequence into a folder: video, calibration, poses, truth, depth.

Output folder (written through :func:`stereo_recon.core.atomic.staged_output_dir`, so a failed run
leaves nothing half-written)::

    video.avi | video.mp4   side-by-side stereo (left eye in the left half), MJPG AVI by default
    SN<serial>.conf         ZED-style factory calibration (raw mode only)
    rig.yaml                the project's rig YAML (raw or rectified rig)
    poses_gt.txt            TUM, world-from-LEFT-camera, timestamp = frame index / fps
    truth.json              dimensions, truck pose, scene, seed, preset, over-limit expectation
    synth_run.json          run manifest: parameters, timings, library versions
    depth/NNNNNN.npy        (with depth=True) left-eye z-depth, float32 metres, inf = sky

World frame: metres, z up, the ground is z = 0. Camera axes: OpenCV (x right, y down, z forward).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, replace
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from stereo_recon.core.errors import ConfigError
from stereo_recon.core.atomic import staged_output_dir, write_json_atomic
from stereo_recon.core.manifest import Stopwatch, run_manifest, to_jsonable
from stereo_recon.synthetic.camera import SYNTH_SERIAL, zed2_rig
from stereo_recon.synthetic.flight import PassConfig, look_at, orbit_poses, pass_poses
from stereo_recon.synthetic.mesh import box, pose
from stereo_recon.synthetic.presets import Preset, get_preset, over_limit_expectation
from stereo_recon.synthetic.render import RenderConfig, StereoRenderer
from stereo_recon.synthetic.scene import Scene, ground_mesh, truck_scene
from stereo_recon.synthetic.texture import Material

log = logging.getLogger(__name__)

VIDEO_FORMATS = ("avi", "mp4")
FLIGHTS = ("orbit", "pass")


def _open_writer(path: Path, fmt: str, fps: float, size: tuple[int, int], quality: int):
    """Video writer for side-by-side frames of ``size`` (width, height): MJPG AVI (libjpeg frames) or mp4v MP4."""
    if fmt == "avi":
        from stereo_recon.synthetic.avi import MjpegAviWriter

        return MjpegAviWriter(path, fps, size, quality)
    w = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"mp4v"), float(fps), size)
    if not w.isOpened():
        raise ConfigError(f"{path}: OpenCV cannot write {fmt} video here (no FFmpeg mp4v encoder)")
    return w


def _exposure_drift(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    """Slow multiplicative exposure changes (auto-exposure), mean 1."""
    if sigma <= 0 or n == 0:
        return np.ones(n)
    x = gaussian_filter1d(rng.standard_normal(n + 40), 6.0, mode="nearest")
    x = (x / max(x.std(), 1e-12))[20:20 + n]
    return np.exp(sigma * x)


def _box_corners(T: np.ndarray, L: float, W: float, H: float) -> np.ndarray:
    """(8, 3) world corners of the truck's bounding box (truck frame x in [-L/2, L/2], y in [-W/2, W/2], z in [0, H])."""
    c = np.array([[sx * L / 2, sy * W / 2, z] for z in (0.0, H) for sy in (-1, 1) for sx in (-1, 1)])
    return c @ T[:3, :3].T + T[:3, 3]


def _board_scene(preset: Preset, T_w_board: np.ndarray) -> tuple[Scene, dict]:
    """Ground plus a chessboard with a white margin at pose ``T_w_board``.

    Board frame: origin at the outer corner of the checker area, x along the columns, y along the
    rows, z into the board (the printed face is z = 0, facing -z). Returns (scene, board spec for truth.json).
    """
    cols, rows = preset.extra["inner_corners"]
    sq = preset.extra["square_m"]
    mg = preset.extra["margin_m"]
    bw, bh = (cols + 1) * sq, (rows + 1) * sq
    thick = 0.008
    # Board frame: origin at the outer corner of the checker area; the printed face is z = 0 and
    # the board body lies at z > 0 (behind the face as seen by the camera).
    board = box((-mg, -mg, 0.0), (bw + mg, bh + mg, thick), "board").transformed(T_w_board)
    g = ground_mesh(60.0)
    mesh = g.extend(board)
    R = T_w_board[:3, :3]
    board_mat = Material("board", (0.86, 0.86, 0.84), 0.02, 0.0015, 0.3, pattern="checker",
                         params={"origin": T_w_board[:3, 3], "u_axis": R[:, 0], "v_axis": R[:, 1], "square_m": sq,
                                 "squares_x": cols + 1, "squares_y": rows + 1, "black_rgb": (0.05, 0.05, 0.05)})
    ground = Material("ground", (0.40, 0.40, 0.38), 0.25, 0.003, 0.5)
    # Sun behind the rig (which looks along +x) so the printed face is well lit, as for a real calibration.
    sun = np.array([-0.6, 0.25, 0.76]) / np.linalg.norm([-0.6, 0.25, 0.76])
    scene = Scene(mesh=mesh, materials={"board": board_mat, "ground": ground}, sun_dir=sun, ambient=0.45, sun=0.6, scale_m=0.3)
    spec = {"pattern": "chessboard", "inner_corners": [cols, rows], "squares": [cols + 1, rows + 1], "square_m": sq,
            "margin_m": mg, "board_size_m": [bw + 2 * mg, bh + 2 * mg],
            "frame": "origin at the outer corner of the first (black) square; x along the columns, y along the rows, "
                     "z into the board (the printed face is z = 0); inner corner (i, j) is at ((i+1)*square, (j+1)*square, 0)"}
    return scene, spec


def _board_poses(preset: Preset, rig, T_wc: np.ndarray, frames: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Random board poses in front of the static rig, fully visible to both eyes (rejection sampled)."""
    from stereo_recon.synthetic.camera import project_points

    cols, rows = preset.extra["inner_corners"]
    sq = preset.extra["square_m"]
    mg = preset.extra["margin_m"]
    bw, bh = (cols + 1) * sq + mg, (rows + 1) * sq + mg
    corners = np.array([[-mg, -mg, 0], [bw, -mg, 0], [bw, bh, 0], [-mg, bh, 0]], float)
    w, h = rig.image_size
    out = []
    tries = 0
    while len(out) < frames and tries < 500 * frames:
        tries += 1
        # Close and spread over the whole field of view (corners included) so that focal length
        # and distortion are separable, as a careful calibration capture would be.
        z = rng.uniform(0.6, 1.6)
        x = rng.uniform(-0.75, 0.75) * z
        y = rng.uniform(-0.45, 0.45) * z
        # Board facing the camera (its z axis = camera +z, i.e. away from the camera, into the board),
        # tilted up to ~35 deg and rolled up to ~20 deg.
        rv = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3)])
        R_cb = Rotation.from_rotvec(rv).as_matrix()
        centre = np.array([(cols + 1) * sq / 2, (rows + 1) * sq / 2, 0.0])
        t_cb = np.array([x, y, z]) - R_cb @ centre
        Xc = corners @ R_cb.T + t_cb
        ok = True
        for K, D, Xe in ((rig.K1, rig.D1, Xc), (rig.K2, rig.D2, Xc @ np.asarray(rig.R).T + np.asarray(rig.T))):
            if np.any(Xe[:, 2] < 0.3):
                ok = False
                break
            uv = project_points(Xe, K, D)
            if np.any(uv[:, 0] < 20) or np.any(uv[:, 0] > w - 21) or np.any(uv[:, 1] < 20) or np.any(uv[:, 1] > h - 21):
                ok = False
                break
        if ok:
            out.append(T_wc @ pose(R_cb, t_cb))
    if len(out) < frames:
        raise ConfigError(f"calibration-board: could only place {len(out)} of {frames} board poses in view")
    return out


def truck_truth(p: Preset, scene: Scene, yaw_rad: float) -> dict:
    """truth.json's truck entries: dimensions, the truck's pose and corners, the second vehicle, the over-limit expectation."""
    spec = p.truck
    T_wt = scene.info["truck_T_world"]
    return dict(kind="truck", length_m=spec.length_m, width_m=spec.width_m, height_m=spec.height_m,
                truck={**asdict(spec), "T_world_truck": T_wt, "yaw_deg": float(np.rad2deg(yaw_rad)),
                       "frame": "origin on the ground at the footprint centre; x to the front, y left, z up; "
                                "the truck spans x in [-L/2, L/2], y in [-W/2, W/2], z in [0, H]"},
                truck_corners_world_m=_box_corners(T_wt, spec.length_m, spec.width_m, spec.height_m),
                second_vehicle=scene.info.get("second_truck"),
                over_limit_expectation=over_limit_expectation(p))


def setting_truth(rig, scene: Scene, orbit, flight_type: str, texel_m: float | None, cfg: RenderConfig, exposure_jitter: float,
                  jpeg_quality: int, video_format: str) -> dict:
    """truth.json's frames, camera, flight, scene and rendering entries."""
    return {
        "world_frame": "metres, right-handed, z up, ground plane z = 0",
        "ground_plane": {"normal": [0.0, 0.0, 1.0], "offset_m": 0.0},
        "camera": {"model": "ZED2-like (synthetic)", "serial": SYNTH_SERIAL, "resolution": rig.metadata.get("resolution"),
                   "image_size": list(rig.image_size), "rectified": bool(rig.rectified), "baseline_m": rig.baseline_m,
                   "K_left": rig.K1, "D_left": rig.D1, "pose_convention": "poses_gt.txt: TUM, world-from-LEFT-camera, OpenCV axes"},
        "flight": {"type": flight_type, **asdict(orbit)},
        "scene": {"texel_m": scene.info.get("texel_m", texel_m), "sun_dir": scene.sun_dir, "ambient": scene.ambient, "sun": scene.sun,
                  "distractors": scene.info.get("distractors", []), "n_triangles": int(len(scene.mesh.triangles))},
        "render": {**asdict(cfg), "exposure_jitter": exposure_jitter, "jpeg_quality": int(jpeg_quality), "video_format": video_format,
                   "renderer": "open3d RaycastingScene, per-pixel rays through the distortion (exact), Lambert + ambient + sun shadows"},
    }


def render_sequence(preset: str, out_dir, seed: int = 0, frames: int | None = None, rectified: bool = False, resolution: str = "HD720",
                    depth: bool = False, video_format: str = "avi", flight: str = "orbit", jpeg_quality: int = 90,
                    render_config: RenderConfig | None = None, exposure_jitter: float = 0.03, arc_deg: float | None = None) -> dict:
    """Render the synthetic sequence ``preset`` into ``out_dir`` and return the truth dict (also in truth.json).

    preset: a name from :func:`presets.preset_names` (``table2:N`` for the paper's Table 2 trucks).
    seed: all randomness (distractors, flight jitter, noise) derives from it; same seed, same bytes.
    frames: number of stereo frames (default per preset). rectified: render the ideal rectified
    pinhole pair (as an SVO export) instead of the raw distorted eyes. resolution: HD720, FHD, 2K, VGA.
    depth: also write left-eye z-depth maps. video_format: "avi" (MJPG) or "mp4" (mp4v).
    flight: "orbit" or "pass" (a straight pass beside the truck). jpeg_quality: JPEG quality 1..100 of the AVI frames (mp4 ignores it).
    exposure_jitter: std of the slow per-frame exposure drift (0 = fixed exposure).
    arc_deg: orbit sweep (default: the preset's, 360).
    """
    p = get_preset(preset)
    if video_format not in VIDEO_FORMATS:
        raise ConfigError(f"--format: must be one of {', '.join(VIDEO_FORMATS)}, got {video_format!r}")
    if flight not in FLIGHTS:
        raise ConfigError(f"--flight: must be one of {', '.join(FLIGHTS)}, got {flight!r}")
    n = p.frames if frames is None else int(frames)
    if n < 1 or n > 100000:
        raise ConfigError(f"--frames: must be between 1 and 100000, got {frames}")
    if not 1 <= int(jpeg_quality) <= 100:
        raise ConfigError(f"--quality: must be between 1 and 100, got {jpeg_quality}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"--seed: must be a non-negative integer, got {seed!r}")
    if Path(out_dir).exists() and not Path(out_dir).is_dir():
        raise ConfigError(f"--out {out_dir}: exists and is not a folder")
    cfg = render_config or RenderConfig()
    rig = zed2_rig(resolution, rectified=rectified)
    ss = np.random.SeedSequence(int(seed))
    scene_rng, flight_rng, noise_rng, expo_rng = (np.random.default_rng(s) for s in ss.spawn(4))
    noise_seed = int(ss.generate_state(1)[0])
    sw = Stopwatch()
    orbit = p.orbit if arc_deg is None else replace(p.orbit, arc_deg=float(arc_deg))
    fps = orbit.fps
    truth: dict = {"preset": p.name, "seed": int(seed), "frames": n, "fps": fps, "scale": p.scale}
    with sw.stage("scene"):
        if p.kind == "calibration-board":
            T_wc0 = look_at((0.0, 0.0, orbit.altitude_m), (5.0, 0.0, orbit.altitude_m))
            poses = np.repeat(T_wc0[None], n, axis=0)
            board_poses = _board_poses(p, rig, T_wc0, n, flight_rng)
            scene, board_spec = _board_scene(p, board_poses[0])
            truth.update(kind="calibration-board", board=board_spec,
                         board_poses_T_world_board=[b for b in board_poses],
                         board_poses_T_left_board=[np.linalg.inv(T_wc0) @ b for b in board_poses])
        else:
            spec = p.truck
            yaw = np.deg2rad(p.truck_yaw_deg)
            scene = truck_scene(spec, truck_xy_m=(0.0, 0.0), truck_yaw_rad=yaw, texel_m=p.texel_m, n_distractors=p.n_distractors,
                                second_truck=p.second_truck, second_offset_m=p.second_gap_m, rng=scene_rng)
            T_wt = scene.info["truck_T_world"]
            if flight == "orbit":
                poses = orbit_poses(n, (0.0, 0.0), orbit, rng=flight_rng)
            else:
                pc = PassConfig(offset_m=orbit.radius_m, altitude_m=orbit.altitude_m, extent_m=0.75 * spec.length_m,
                                look_height_m=orbit.look_height_m, jitter_deg=orbit.jitter_deg, position_jitter_m=orbit.position_jitter_m, fps=fps)
                poses = pass_poses(n, T_wt, pc, rng=flight_rng)
            truth.update(truck_truth(p, scene, yaw))
            truth.update({k: v for k, v in p.extra.items()})
    truth.update(setting_truth(rig, scene, orbit, "static" if p.kind == "calibration-board" else flight, p.texel_m, cfg,
                               exposure_jitter, jpeg_quality, video_format))
    expo = _exposure_drift(expo_rng, n, exposure_jitter)
    board_scene = None
    if p.kind == "calibration-board":
        board_scene = lambda i: _board_scene(p, truth["board_poses_T_world_board"][i])[0] if i > 0 else None  # noqa: E731
    params = {"preset": p.name, "seed": int(seed), "frames": n, "rectified": bool(rectified), "resolution": resolution,
              "depth": bool(depth), "video_format": video_format, "flight": flight, "jpeg_quality": int(jpeg_quality),
              "exposure_jitter": exposure_jitter, "arc_deg": arc_deg, "render": asdict(cfg)}
    write_sequence(out_dir, scene, rig, poses, truth, cfg, fps=fps, noise_seed=noise_seed, noise_rng=noise_rng, exposure=expo,
                   video_format=video_format, jpeg_quality=jpeg_quality, depth=depth, run_params=params, seed=int(seed),
                   stopwatch=sw, scene_for_frame=board_scene)
    log.info("synthetic sequence %s: %d frames in %.1f s -> %s", p.name, n, sum(sw.timings_s.values()), out_dir)
    return to_jsonable(truth)


def _render_frames(renderer, writer, poses: np.ndarray, expo: np.ndarray, noise_rng, depth_dir: Path | None,
                   sw: Stopwatch, scene_for_frame=None) -> None:
    """Render every pose and write its side-by-side frame (and left depth, float32 m, into depth_dir).

    JPEG encoding and file writes of frame i run in one background thread while frame i+1 renders
    (frames are written in order, so the bytes do not depend on the timing).
    """
    from concurrent.futures import ThreadPoolExecutor

    n = len(poses)
    encoder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="synth-encode")

    def emit(i: int, pair) -> None:
        writer.write(np.hstack([pair.left, pair.right]))
        if depth_dir is not None:
            np.save(depth_dir / f"{i:06d}.npy", pair.depth_left_m)

    pending = None
    try:
        for i in range(n):
            scene_i = scene_for_frame(i) if scene_for_frame is not None else None
            if scene_i is not None:
                renderer.set_scene(scene_i)
            with sw.stage("render"):
                pair = renderer.render(poses[i], rng=noise_rng, exposure=float(expo[i]))
            with sw.stage("encode"):  # the wait for the previous frame's encode (overlapped with this render)
                if pending is not None:
                    pending.result()
                pending = encoder.submit(emit, i, pair)
            if (i + 1) % 10 == 0:
                log.info("rendered %d/%d frames", i + 1, n)
        with sw.stage("encode"):
            if pending is not None:
                pending.result()
    finally:
        encoder.shutdown(wait=True)
        writer.release()
        renderer.close()


def _write_truth_files(tmp: Path, video: Path, rig, poses: np.ndarray, truth: dict, fps: float, depth: bool,
                       run_params: dict, seed: int, sw: Stopwatch) -> None:
    """poses_gt.txt (TUM), rig.yaml, the ZED conf (raw rigs), truth.json with the file names, synth_run.json."""
    from calib.io import save_rig

    from stereo_recon.trajectory import Trajectory, write_tum

    n = len(poses)
    write_tum(tmp / "poses_gt.txt", Trajectory(np.arange(n), np.arange(n) / fps, poses))
    save_rig(rig, tmp / "rig.yaml")
    files = {"video": video.name, "rig": "rig.yaml", "poses": "poses_gt.txt"}
    if not rig.rectified:
        try:
            from calib.io import write_zed_conf
        except ImportError:  # older calib layout
            from calib.zedconf import write_zed_conf
        conf = write_zed_conf(rig, tmp / f"SN{SYNTH_SERIAL}.conf", serial=SYNTH_SERIAL)
        files["conf"] = Path(conf).name
    if depth:
        files["depth"] = "depth/NNNNNN.npy (left eye z-depth, float32 m, inf = sky)"
    files["run"] = "synth_run.json"
    truth["files"] = files
    # truth.json holds only seed-determined content (same seed, same bytes); timings and
    # versions go to synth_run.json.
    write_json_atomic(tmp / "truth.json", truth)
    write_json_atomic(tmp / "synth_run.json", run_manifest("synth", {}, run_params, dict(sw.timings_s), seed=int(seed)))


def write_sequence(out_dir, scene: Scene, rig, poses: np.ndarray, truth: dict, cfg: RenderConfig, *, fps: float, noise_seed: int,
                   noise_rng: np.random.Generator, exposure: np.ndarray, video_format: str, jpeg_quality: int, depth: bool,
                   run_params: dict, seed: int, stopwatch: Stopwatch | None = None, scene_for_frame=None) -> Path:
    """Render ``poses`` (N, 4, 4 world-from-left) of ``scene`` through ``rig`` into ``out_dir`` (the layout in the module docstring).

    truth: the scene's truth dict (written as truth.json with the file names added); exposure: (N,) per-frame gain;
    noise_seed / noise_rng: the sensor noise buffer's seed and the per-frame offsets' generator; run_params: what
    synth_run.json records; scene_for_frame: i -> a Scene to switch to before frame i, or None (a moving board).
    Written atomically (a staged folder); an unwritable folder is a one-line ConfigError.
    """
    sw = stopwatch or Stopwatch()
    renderer = StereoRenderer(scene, rig, cfg, noise_seed=noise_seed)
    expo = np.asarray(exposure, float)
    w, h = rig.image_size
    out_dir = Path(out_dir)
    try:
        with staged_output_dir(out_dir) as tmp:
            video = tmp / f"video.{video_format}"
            writer = _open_writer(video, video_format, fps, (2 * w, h), int(jpeg_quality))
            if depth:
                (tmp / "depth").mkdir()
            _render_frames(renderer, writer, poses, expo, noise_rng, tmp / "depth" if depth else None, sw,
                           scene_for_frame)
            with sw.stage("write"):
                _write_truth_files(tmp, video, rig, poses, truth, fps, depth, run_params, seed, sw)
    except OSError as err:  # unwritable / full output folder: one line, not a traceback
        raise ConfigError(f"--out {out_dir}: cannot write the output ({err.strerror or err})") from err
    return out_dir
