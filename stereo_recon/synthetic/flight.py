"""Drone flight paths for the synthetic rig: an orbit around the truck and a straight pass.

Poses are world-from-LEFT-camera 4x4 matrices with OpenCV camera axes (x right, y down, z forward)
in the scene's world frame (z up, ground z = 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation


def look_at(position, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World-from-camera pose of a camera at ``position`` looking at ``target`` with image 'up' toward ``up``."""
    p = np.asarray(position, float)
    z = np.asarray(target, float) - p
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:  # looking straight down: pick any right vector
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.c_[x, y, z]
    T[:3, 3] = p
    return T


@dataclass(frozen=True)
class OrbitConfig:
    """A circular orbit around ``centre`` (world xy) looking at a point above it.

    radius_m, altitude_m: orbit radius and camera height above the ground.
    arc_deg: swept angle (360 = full circle, frames spread without repeating the start).
    start_deg: angle of the first frame (0 = on the +x side of the centre).
    look_height_m: height of the aimed point above the centre.
    jitter_deg: gimbal jitter (std, smoothed over ~3 frames) of yaw/pitch/roll.
    position_jitter_m: std of the drone's position wobble.
    fps: frame rate (TUM timestamps = index / fps).
    shake_deg: high-frequency shake (std, smoothed over ~1 frame) on top of the jitter: propeller
        vibration the gimbal does not absorb (0 = none).
    """

    radius_m: float = 1.7
    altitude_m: float = 1.0
    arc_deg: float = 360.0
    start_deg: float = 0.0
    look_height_m: float = 0.15
    jitter_deg: float = 0.6
    position_jitter_m: float = 0.01
    fps: float = 15.0
    shake_deg: float = 0.0


def _smooth_noise(rng: np.random.Generator, n: int, dims: int, sigma: float, smooth_frames: float = 3.0) -> np.ndarray:
    x = rng.standard_normal((n + 12, dims))
    if n > 1:
        x = gaussian_filter1d(x, smooth_frames, axis=0, mode="wrap")
        x /= max(x.std(), 1e-12)
    return sigma * x[6: 6 + n]


def orbit_poses(frames: int, centre_xy, config: OrbitConfig = OrbitConfig(), rng=None) -> np.ndarray:
    """(frames, 4, 4) world-from-left-camera poses on an orbit (see :class:`OrbitConfig`)."""
    rng = np.random.default_rng(rng)
    c = config
    full = abs(c.arc_deg) >= 359.999
    steps = frames if full else max(frames - 1, 1)
    ang = np.deg2rad(c.start_deg + c.arc_deg * np.arange(frames) / steps)
    jit = _smooth_noise(rng, frames, 3, np.deg2rad(c.jitter_deg))
    pj = _smooth_noise(rng, frames, 3, c.position_jitter_m)
    if c.shake_deg > 0:  # drawn after the jitter: orbits without shake keep their poses
        jit = jit + _smooth_noise(rng, frames, 3, np.deg2rad(c.shake_deg), smooth_frames=0.7)
    target = np.array([centre_xy[0], centre_xy[1], c.look_height_m])
    out = np.empty((frames, 4, 4))
    for i, a in enumerate(ang):
        pos = np.array([centre_xy[0] + c.radius_m * np.cos(a), centre_xy[1] + c.radius_m * np.sin(a), c.altitude_m]) + pj[i]
        T = look_at(pos, target)
        T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(jit[i]).as_matrix()  # gimbal jitter in the camera frame
        out[i] = T
    return out


@dataclass(frozen=True)
class PassConfig:
    """A straight pass beside the truck, parallel to its length, camera pitched toward it.

    offset_m: lateral distance of the track from the truck's axis; altitude_m: flight height;
    extent_m: half length of the track (along the truck's x); look_height_m: aimed height.
    """

    offset_m: float = 1.5
    altitude_m: float = 1.0
    extent_m: float = 1.6
    look_height_m: float = 0.15
    jitter_deg: float = 0.5
    position_jitter_m: float = 0.01
    fps: float = 15.0


def pass_poses(frames: int, T_world_truck: np.ndarray, config: PassConfig = PassConfig(), rng=None) -> np.ndarray:
    """(frames, 4, 4) poses of a straight pass along the truck's x axis at ``offset_m`` to its left."""
    rng = np.random.default_rng(rng)
    c = config
    s = np.linspace(-c.extent_m, c.extent_m, frames)
    jit = _smooth_noise(rng, frames, 3, np.deg2rad(c.jitter_deg))
    pj = _smooth_noise(rng, frames, 3, c.position_jitter_m)
    R, t = T_world_truck[:3, :3], T_world_truck[:3, 3]
    out = np.empty((frames, 4, 4))
    for i, si in enumerate(s):
        pos = R @ np.array([si, c.offset_m, c.altitude_m]) + t + pj[i]
        tgt = R @ np.array([si, 0.0, c.look_height_m]) + t
        T = look_at(pos, tgt)
        T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(jit[i]).as_matrix()
        out[i] = T
    return out
