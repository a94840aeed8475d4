"""Calibration boards: spec parsing, object points, sub-pixel corner detection.

Specs (the ``--board`` option):
  ``chessboard:COLSxROWS:SQUARE_M`` -- COLS x ROWS *inner* corners, square side in metres;
  ``charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT`` -- COLS x ROWS *squares*, square and marker sides in
  metres, ArUco dictionary name (``DICT_4X4_50``, ``5X5_100``, ...).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field

import numpy as np

from stereo_recon.core.errors import ConfigError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BoardSpec:
    """A planar calibration target. cols x rows: inner corners (chessboard) or squares (charuco)."""

    kind: str            # "chessboard" | "charuco"
    cols: int
    rows: int
    square_m: float      # side of one square, metres
    marker_m: float = 0.0  # ArUco marker side (charuco only), metres
    dictionary: str = ""   # ArUco dictionary name (charuco only)

    @property
    def n_corners(self) -> int:
        """Number of chessboard corners a full detection yields."""
        if self.kind == "chessboard":
            return self.cols * self.rows
        return (self.cols - 1) * (self.rows - 1)

    @property
    def inner_size(self) -> tuple[int, int]:
        """(cols, rows) of inner chessboard corners."""
        if self.kind == "chessboard":
            return (self.cols, self.rows)
        return (self.cols - 1, self.rows - 1)

    def object_points(self) -> np.ndarray:
        """(n_corners, 3) float32 board-frame corner coordinates, metres, z = 0, in detection id order."""
        if self.kind == "charuco":
            return np.asarray(self.charuco_board().getChessboardCorners(), dtype=np.float32).reshape(-1, 3)
        c, r = self.inner_size
        g = np.zeros((r * c, 3), np.float32)
        g[:, :2] = np.mgrid[0:c, 0:r].T.reshape(-1, 2) * self.square_m
        return g

    def charuco_board(self):
        """The cv2.aruco.CharucoBoard of a charuco spec."""
        import cv2

        if self.kind != "charuco":
            raise ValueError("not a charuco board")
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, d)

    def __str__(self) -> str:
        if self.kind == "chessboard":
            return f"chessboard:{self.cols}x{self.rows}:{self.square_m:g}"
        return f"charuco:{self.cols}x{self.rows}:{self.square_m:g}:{self.marker_m:g}:{self.dictionary}"


def parse_board(text: str) -> BoardSpec:
    """Parse a ``--board`` spec (see module doc); ConfigError with the expected form otherwise."""
    import cv2

    t = str(text).strip()
    parts = t.split(":")
    kind = parts[0].lower()
    usage = ("expected chessboard:COLSxROWS:SQUARE_M (inner corners) or "
             "charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT (squares), e.g. chessboard:9x6:0.025")
    if kind not in ("chessboard", "charuco") or len(parts) != (3 if kind == "chessboard" else 5):
        raise ConfigError(f"--board {t}: {usage}")
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", parts[1])
    if not m:
        raise ConfigError(f"--board {t}: '{parts[1]}' is not COLSxROWS; {usage}")
    cols, rows = int(m.group(1)), int(m.group(2))
    try:
        square = float(parts[2])
        marker = float(parts[3]) if kind == "charuco" else 0.0
    except ValueError:
        raise ConfigError(f"--board {t}: sizes must be numbers in metres; {usage}") from None
    if not square > 0 or (kind == "charuco" and not 0 < marker < square):
        raise ConfigError(f"--board {t}: need SQUARE_M > 0" + (" and 0 < MARKER_M < SQUARE_M" if kind == "charuco" else ""))
    if kind == "chessboard":
        if cols < 3 or rows < 3:
            raise ConfigError(f"--board {t}: a chessboard needs at least 3x3 inner corners")
        if cols == rows:
            # a square grid has no defined orientation: corners could be numbered from any side
            raise ConfigError(f"--board {t}: use a chessboard with different numbers of inner corners per side")
        return BoardSpec("chessboard", cols, rows, square)
    if cols < 3 or rows < 3:
        raise ConfigError(f"--board {t}: a ChArUco board needs at least 3x3 squares")
    name = parts[4].strip().upper()
    if not name.startswith("DICT_"):
        name = "DICT_" + name
    if not hasattr(cv2.aruco, name):
        raise ConfigError(f"--board {t}: unknown ArUco dictionary '{parts[4]}' (e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250)")
    spec = BoardSpec("charuco", cols, rows, square, marker, name)
    n_markers = (cols * rows) // 2
    dict_size = int(re.search(r"_(\d+)$", name).group(1)) if re.search(r"_(\d+)$", name) else 10**6
    if n_markers > dict_size:
        raise ConfigError(f"--board {t}: the board needs {n_markers} markers but {name} has {dict_size}")
    return spec


@dataclass(frozen=True)
class Detection:
    """Board corners found in one image. corners (N,2) float32 px; ids (N,) indices into object_points()."""

    corners: np.ndarray
    ids: np.ndarray
    method: str = ""   # "sb", "classic", "charuco"
    extra: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class DetectConfig:
    """Corner detection settings."""

    use_sb: bool = True          # findChessboardCornersSB first (more accurate where it succeeds)
    classic_fallback: bool = True  # then findChessboardCorners + cornerSubPix
    upscale_retry: bool = True     # retry the classic detector on a 2x upscaled image (small boards)
    min_charuco_corners: int = 6   # fewer interpolated ChArUco corners: treat as not found


def _subpix_window(corners: np.ndarray, inner: tuple[int, int]) -> int:
    """cornerSubPix half-window: below half the smallest corner spacing, at most 11 (OpenCV's stereo sample)."""
    c, r = inner
    g = corners.reshape(r, c, 2)
    dx = np.linalg.norm(np.diff(g, axis=1), axis=2).min() if c > 1 else 50
    dy = np.linalg.norm(np.diff(g, axis=0), axis=2).min() if r > 1 else 50
    return int(max(2, min(11, np.floor(0.45 * min(dx, dy)))))


def _classic(gray: np.ndarray, inner: tuple[int, int], upscale: bool) -> np.ndarray | None:
    import cv2

    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    for scale in ((1, 2) if upscale else (1,)):
        img = gray if scale == 1 else cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
        ok, corners = cv2.findChessboardCorners(img, inner, flags=flags)
        if ok:
            corners = corners.reshape(-1, 2).astype(np.float32)
            if scale != 1:
                corners = ((corners + 0.5) / scale - 0.5).astype(np.float32)
            win = _subpix_window(corners, inner)
            crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-3)
            corners = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (win, win), (-1, -1), crit)
            return corners.reshape(-1, 2)
    return None


def detect_board(image: np.ndarray, spec: BoardSpec, config: DetectConfig = DetectConfig()) -> Detection | None:
    """Find the board's corners to sub-pixel accuracy in one image (gray or BGR), or None.

    Chessboards: ``findChessboardCornersSB`` (sector based, accurate), else the classic detector
    + ``cornerSubPix`` so that hard views are still used. ChArUco: ``cv2.aruco.CharucoDetector``.
    """
    import cv2

    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if spec.kind == "charuco":
        det = cv2.aruco.CharucoDetector(spec.charuco_board())
        cc, cid, _, _ = det.detectBoard(gray)
        if cid is None or len(cid) < config.min_charuco_corners:
            return None
        return Detection(cc.reshape(-1, 2).astype(np.float32), cid.reshape(-1).astype(np.int32), "charuco")
    inner = spec.inner_size
    ids = np.arange(spec.n_corners, dtype=np.int32)
    if config.use_sb:
        base = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY
        # the exhaustive search finds some boards the default one misses, and vice versa
        for flags in (base, base | cv2.CALIB_CB_EXHAUSTIVE):
            ok, corners = cv2.findChessboardCornersSB(gray, inner, flags=flags)
            if ok:
                return Detection(corners.reshape(-1, 2).astype(np.float32), ids, "sb")
    if config.classic_fallback:
        corners = _classic(gray, inner, config.upscale_retry)
        if corners is not None:
            return Detection(corners, ids, "classic")
    return None


def reverse_if_flipped(left: Detection, right: Detection, spec: BoardSpec) -> Detection:
    """Make the right eye's chessboard corner order match the left's.

    A chessboard detector may number the corners from either end (a 180-degree turn of the grid);
    in a side-by-side rig both eyes see the board the same way up, so the first-to-last corner
    direction must agree. ChArUco ids are unambiguous and returned unchanged.
    """
    if spec.kind != "chessboard":
        return right
    dl = left.corners[-1] - left.corners[0]
    dr = right.corners[-1] - right.corners[0]
    if float(dl @ dr) < 0:
        return Detection(right.corners[::-1].copy(), right.ids, right.method, right.extra)
    return right


def render_board_texture(spec: BoardSpec, px_per_square: int = 100, margin_squares: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A grayscale image of the board and the 3x3 affine map from board metres (x, y, 1) to texture pixels.

    The board frame is the one of ``object_points()`` (first inner corner at the origin for chessboards).
    """
    import cv2

    pps = int(px_per_square)
    m = int(round(margin_squares * pps))
    if spec.kind == "charuco":
        w, h = spec.cols * pps, spec.rows * pps
        img = spec.charuco_board().generateImage((w + 2 * m, h + 2 * m), marginSize=m)
        # charuco object points are measured from the board's outer corner
        A = np.array([[pps / spec.square_m, 0, m - 0.5], [0, pps / spec.square_m, m - 0.5], [0, 0, 1]])
        return img, A
    c, r = spec.cols + 1, spec.rows + 1  # squares
    img = np.full((r * pps + 2 * m, c * pps + 2 * m), 255, np.uint8)
    for j in range(r):
        for i in range(c):
            if (i + j) % 2 == 0:
                img[m + j * pps: m + (j + 1) * pps, m + i * pps: m + (i + 1) * pps] = 0
    # first inner corner sits one square in from the board's outer corner; pixel centres at +0.5
    A = np.array([[pps / spec.square_m, 0, m + pps - 0.5], [0, pps / spec.square_m, m + pps - 0.5], [0, 0, 1]])
    return img, A
