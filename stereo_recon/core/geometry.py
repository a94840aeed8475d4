"""Small geometry helpers shared by every layer (numpy only)."""

from __future__ import annotations

import numpy as np


def plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane with unit normal ``normal`` (a right-handed pair: e1 x e2 = normal)."""
    n = np.asarray(normal, dtype=np.float64)
    a_ = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(n, a_)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)
