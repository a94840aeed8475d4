"""Export a reconstruction's fused views as a COLMAP model (cameras, images with poses; no 3D points) via pycolmap.

Layout, as COLMAP's own automatic reconstructor leaves it, so ``colmap image_undistorter --image_path DIR/images
--input_path DIR/sparse/0`` and hloc/pycolmap tools take it as is:

    DIR/images/frame_NNNNNN.png   the physical left eye's raw frames of the fused views
    DIR/sparse/0/                 cameras.bin, images.bin, points3D.bin (empty), rigs.bin, frames.bin

One camera: the left eye's intrinsics and distortion (OPENCV model, FULL_OPENCV when k3 is not zero), in
pixels of the frames; each image's pose is ``cam_from_world`` = the inverse of poses.txt's world-from-camera
at that frame (same world frame as cloud.ply, metres).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np

from stereo_recon.core.errors import InputError
from stereo_recon.core.paths import RunPaths

log = logging.getLogger(__name__)


def colmap_camera_params(K: np.ndarray, D: np.ndarray) -> tuple[str, list[float]]:
    """COLMAP camera model name and parameters for OpenCV intrinsics K (3x3) and distortion D (k1 k2 p1 p2 [k3])."""
    d = np.zeros(5)
    D = np.asarray(D, float).reshape(-1)
    if len(D) > 5 and np.any(D[5:] != 0):
        raise InputError(f"distortion with {len(D)} coefficients: only k1 k2 p1 p2 k3 can be exported to COLMAP")
    d[:min(5, len(D))] = D[:5]
    base = [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])]
    if d[4] == 0:
        return "OPENCV", base + [float(v) for v in d[:4]]
    return "FULL_OPENCV", base + [float(v) for v in d] + [0.0, 0.0, 0.0]


def export_colmap(run_dir: str | os.PathLike, out_dir: str | os.PathLike, write_images: bool = True) -> Path:
    """Write the fused views of a reconstruct/run output folder as a COLMAP model under ``out_dir``.

    run_dir: folder with run.json (rig, source, fused_views) and poses.txt (TUM, world-from-left-camera).
    out_dir: the COLMAP project folder (images/ and sparse/0/); written atomically.
    Returns the model folder (``out_dir/sparse/0``). Raises InputError when run_dir lacks what is needed.
    """
    import pycolmap

    from stereo_recon.core.atomic import staged_output_dir
    from stereo_recon.trajectory import read_tum

    run_dir, out_dir = Path(run_dir), Path(out_dir)
    try:
        run = json.loads(RunPaths(run_dir).run_json.read_text(encoding="utf-8"))
        rig, fps, views = run["rig"], float(run["source"]["fps"]), [int(i) for i in run["fused_views"]]
    except (OSError, KeyError, TypeError, ValueError) as err:
        raise InputError(f"{RunPaths(run_dir).run_json}: not a reconstruction manifest with fused views ({err})") from None
    traj = read_tum(RunPaths(run_dir).poses, fps=fps)
    pose_of = {int(i): T for i, T in zip(traj.indices, traj.T_wc)}
    K, D = np.asarray(rig["K1"], float), np.asarray(rig["D1"], float)
    w, h = (int(v) for v in rig["image_size"])
    model, params = colmap_camera_params(K, D)

    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model=model, width=w, height=h, params=params, camera_id=1))
    names: dict[int, str] = {}
    for image_id, idx in enumerate((i for i in views if i in pose_of), start=1):
        T_wc = pose_of[idx]
        R_cw = T_wc[:3, :3].T
        names[idx] = f"frame_{idx:06d}.png"
        image = pycolmap.Image(name=names[idx], camera_id=1, image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R_cw), -R_cw @ T_wc[:3, 3]))
    if not names:
        raise InputError(f"{run_dir}: no fused view has a pose in poses.txt")
    with staged_output_dir(out_dir) as tmp:
        model_dir = tmp / "sparse" / "0"
        model_dir.mkdir(parents=True)
        rec.write(str(model_dir))
        if write_images:
            _write_frames(run["source"]["path"], names, tmp / "images", (w, h))
    if not write_images and (out_dir / "images").is_dir():
        shutil.rmtree(out_dir / "images")
    log.info("COLMAP model: %d images, camera %s, in %s", len(names), model, out_dir / "sparse" / "0")
    return out_dir / "sparse" / "0"


def _write_frames(source: str, names: dict[int, str], folder: Path, size: tuple[int, int]) -> None:
    """Decode the left eye of the given frames (index -> file name) into ``folder``."""
    import cv2

    from stereo_recon.video import open_stereo_source

    folder.mkdir(parents=True)
    first, last = min(names), max(names)
    for frame in open_stereo_source(source, (first, last + 1), 1):
        if frame.index in names:
            img = frame.left if (frame.left.shape[1], frame.left.shape[0]) == size else cv2.resize(frame.left, size)
            cv2.imwrite(str(folder / names[frame.index]), img)
