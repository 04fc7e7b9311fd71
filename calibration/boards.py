"""Calibration boards: specification, texture, detection and view-quality checks.

Board frame: origin at the top-left corner of the printed pattern, x to the right along the
columns, y down along the rows, z into the board (right-handed), millimetres. Object points lie
on z = 0. Two kinds:

* ``checkerboard:COLSxROWS:SQUARE_MM`` — COLS x ROWS *inner* corners (OpenCV convention), found
  with ``cv2.findChessboardCornersSB`` (sub-pixel by construction). Its corner order can flip by
  180 degrees between views, so it serves intrinsics; multi-camera extrinsics need ChArUco.
* ``charuco:COLSxROWS:SQUARE_MM[:MARKER_MM[:DICT]]`` — COLS x ROWS *squares*, ArUco markers of
  MARKER_MM (default 0.75 * square) from dictionary DICT (default ``DICT_4X4_50``); corners carry
  ids, so every view is unambiguous and partial views still count.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from spinemocap.capture import to_grey
from spinemocap.fileio import InputError

#: Largest accepted blur (Gaussian sigma of the board edges, px) before a view is rejected.
MAX_BLUR_SIGMA_PX = 3.0


@dataclass(frozen=True)
class BoardSpec:
    """A planar calibration target. ``cols``/``rows``: inner corners (checkerboard) or squares
    (ChArUco); ``square_mm``: square side; ``marker_mm``/``dictionary``: ChArUco only."""

    kind: str
    cols: int
    rows: int
    square_mm: float
    marker_mm: float = 0.0
    dictionary: str = "DICT_4X4_50"

    # ------------------------------------------------------------------ parsing
    @classmethod
    def parse(cls, text: str) -> "BoardSpec":
        """Parse ``checkerboard:7x4:60`` or ``charuco:8x6:40[:30[:DICT_5X5_100]]``."""
        parts = text.strip().split(":")
        try:
            kind = parts[0].lower()
            cols, rows = (int(v) for v in parts[1].lower().split("x"))
            square = float(parts[2])
            if kind == "checkerboard" and len(parts) == 3:
                spec = cls("checkerboard", cols, rows, square)
            elif kind == "charuco" and 3 <= len(parts) <= 5:
                marker = float(parts[3]) if len(parts) > 3 else 0.75 * square
                spec = cls("charuco", cols, rows, square, marker, parts[4] if len(parts) > 4 else "DICT_4X4_50")
            else:
                raise ValueError
        except (ValueError, IndexError):
            raise InputError(
                "--board", f"cannot parse board {text!r}; expected checkerboard:COLSxROWS:SQUARE_MM "
                "(inner corners) or charuco:COLSxROWS:SQUARE_MM[:MARKER_MM[:DICT]] (squares)"
            ) from None
        spec.validate()
        return spec

    def validate(self) -> None:
        if self.cols < 2 or self.rows < 2 or self.square_mm <= 0:
            raise InputError("--board", f"board {self} needs at least 2x2 corners/squares and a positive square size")
        if self.kind == "charuco":
            if not 0 < self.marker_mm < self.square_mm:
                raise InputError("--board", "ChArUco marker size must be positive and smaller than the square")
            if not hasattr(cv2.aruco, self.dictionary):
                raise InputError("--board", f"unknown ArUco dictionary {self.dictionary!r}")

    def __str__(self) -> str:
        base = f"{self.kind}:{self.cols}x{self.rows}:{self.square_mm:g}"
        return base + (f":{self.marker_mm:g}:{self.dictionary}" if self.kind == "charuco" else "")

    # ------------------------------------------------------------------ geometry
    @property
    def n_corners(self) -> int:
        return self.cols * self.rows if self.kind == "checkerboard" else (self.cols - 1) * (self.rows - 1)

    @property
    def size_mm(self) -> tuple[float, float]:
        """Printed pattern size (width, height) in mm; a checkerboard has one square beyond
        its outer inner-corners on each side."""
        if self.kind == "checkerboard":
            return ((self.cols + 1) * self.square_mm, (self.rows + 1) * self.square_mm)
        return (self.cols * self.square_mm, self.rows * self.square_mm)

    def object_points(self) -> np.ndarray:
        """(n_corners, 3) corner positions in the board frame (mm), indexed by corner id."""
        if self.kind == "checkerboard":
            j, i = np.mgrid[0 : self.rows, 0 : self.cols]
            xy = np.column_stack([(i.ravel() + 1), (j.ravel() + 1)]) * self.square_mm
        else:
            return np.asarray(self.charuco_board().getChessboardCorners(), float).reshape(-1, 3)
        return np.column_stack([xy, np.zeros(len(xy))]).astype(float)

    def charuco_board(self) -> "cv2.aruco.CharucoBoard":
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_mm, self.marker_mm, dictionary)

    def texture(self, px_per_mm: float) -> np.ndarray:
        """Grey uint8 image of the printed pattern, texture pixel = mm * px_per_mm - 0.5 (no margin)."""
        w_mm, h_mm = self.size_mm
        size = (int(round(w_mm * px_per_mm)), int(round(h_mm * px_per_mm)))
        if self.kind == "charuco":
            return self.charuco_board().generateImage(size, marginSize=0, borderBits=1)
        sq = self.square_mm * px_per_mm
        v, u = np.mgrid[0 : size[1], 0 : size[0]]
        parity = (np.floor((u + 0.5) / sq).astype(int) + np.floor((v + 0.5) / sq).astype(int)) % 2
        return np.where(parity == 0, 0, 255).astype(np.uint8)


@dataclass
class BoardDetection:
    """Corners of one board in one image: ``ids`` (N,) index :meth:`BoardSpec.object_points`;
    ``pixels`` (N, 2) distorted pixel positions; ``blur_px`` estimated edge blur sigma."""

    ids: np.ndarray
    pixels: np.ndarray
    blur_px: float = 0.0

    def __len__(self) -> int:
        return len(self.ids)


def detect_board(image: np.ndarray, board: BoardSpec) -> BoardDetection | None:
    """Find the board's corners (sub-pixel) in a BGR or grey image; None when not found."""
    grey = to_grey(image)
    if board.kind == "checkerboard":
        # The sector-based detector; its ACCURACY mode costs ~5x, so corners are refined with
        # cornerSubPix instead (no markers to avoid: the window may span a third of a square).
        found, corners = cv2.findChessboardCornersSB(grey, (board.cols, board.rows), flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            found, corners = cv2.findChessboardCornersSB(
                grey, (board.cols, board.rows), flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE)
        if not found:
            return None
        corners = corners.reshape(-1, 2).astype(np.float32)
        win = int(np.clip(0.3 * _median_spacing(corners), 2, 15))
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
        pixels = cv2.cornerSubPix(grey, corners.reshape(-1, 1, 2), (win, win), (-1, -1), crit).reshape(-1, 2).astype(float)
        ids = np.arange(len(pixels))
    else:
        detector = cv2.aruco.CharucoDetector(board.charuco_board())
        corners, ids, _, _ = detector.detectBoard(grey)
        if ids is None or len(ids) < 4:
            return None
        pixels = corners.reshape(-1, 2).astype(np.float32)
        # Refine to sub-pixel. The window's half-size must stay inside the white margin between
        # a corner and the nearest ArUco marker ((square - marker) / 2), else the marker's edges
        # pull the corner by tenths of a pixel.
        margin = 0.5 * (1.0 - board.marker_mm / board.square_mm)
        win = int(np.clip(0.8 * margin * _median_spacing(pixels), 2, 11))
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
        pixels = cv2.cornerSubPix(grey, pixels.reshape(-1, 1, 2), (win, win), (-1, -1), crit).reshape(-1, 2)
        pixels = pixels.astype(float)
        ids = ids.ravel().astype(int)
    return BoardDetection(ids, pixels, edge_blur_sigma(grey, pixels))


def _median_spacing(pixels: np.ndarray) -> float:
    if len(pixels) < 2:
        return 10.0
    d = np.linalg.norm(pixels[:, None] - pixels[None], axis=2)
    d[d == 0] = np.inf
    return float(np.median(d.min(axis=1)))


def edge_blur_sigma(grey: np.ndarray, corners: np.ndarray) -> float:
    """Blur of the board edges as a Gaussian sigma (px): a step of contrast C blurred by sigma
    has peak gradient C / (sigma sqrt(2 pi)), so sigma = C / (peak gradient sqrt(2 pi)).
    Measured in patches around the corners (median over patches)."""
    half = int(np.clip(0.4 * _median_spacing(corners), 4, 30))
    img = grey.astype(np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = np.hypot(gx, gy)
    h, w = grey.shape
    sigmas = []
    for u, v in np.round(corners).astype(int):
        y0, y1, x0, x1 = max(v - half, 0), min(v + half + 1, h), max(u - half, 0), min(u + half + 1, w)
        if y1 - y0 < 5 or x1 - x0 < 5:
            continue
        patch = img[y0:y1, x0:x1]
        contrast = np.percentile(patch, 95) - np.percentile(patch, 5)
        peak = np.percentile(mag[y0:y1, x0:x1], 99)
        if contrast > 20 and peak > 0:
            sigmas.append(contrast / (peak * np.sqrt(2 * np.pi)))
    return float(np.median(sigmas)) if sigmas else float("inf")


def _foreshortening(H: np.ndarray, at_xy: np.ndarray) -> float:
    """Ratio of the smaller to the larger singular value of the homography's local Jacobian at
    board point ``at_xy`` (about cos of the viewing angle from the board normal)."""
    x, y = at_xy
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    u = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w
    v = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
    J = np.array([[H[0, 0] - u * H[2, 0], H[0, 1] - u * H[2, 1]], [H[1, 0] - v * H[2, 0], H[1, 1] - v * H[2, 1]]]) / w
    sv = np.linalg.svd(J, compute_uv=False)
    return float(sv[1] / sv[0])


def view_problem(detection: BoardDetection | None, board: BoardSpec, image_size: tuple[int, int],
                 max_blur_px: float = MAX_BLUR_SIGMA_PX) -> str | None:
    """Why a detected view is unusable for calibration, or None if it is fine."""
    if detection is None:
        return "board not found"
    min_corners = max(6, int(0.3 * board.n_corners))
    if len(detection) < min_corners:
        return f"only {len(detection)} corners (< {min_corners})"
    if detection.blur_px > max_blur_px:
        return f"blurred (edge sigma {detection.blur_px:.1f} px > {max_blur_px:g})"
    # Degenerate geometry: corners must span two dimensions (not all on one board row/line).
    centred = detection.pixels - detection.pixels.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[1] < 0.05 * sv[0]:
        return "corners nearly collinear (board edge-on or only one row visible)"
    # Corners must map to the board by a homography (up to lens distortion): a mis-ordered or
    # partly wrong detection does not.
    obj = board.object_points()[detection.ids, :2]
    H, _ = cv2.findHomography(obj, detection.pixels, 0)
    if H is None:
        return "corners do not fit the board's layout"
    fit = cv2.perspectiveTransform(obj[None], H)[0]
    misfit = float(np.sqrt(np.mean(np.sum((fit - detection.pixels) ** 2, axis=1))))
    extent = float(np.ptp(detection.pixels, axis=0).max())
    if misfit > 0.01 * extent + 0.5:
        return f"corners do not fit the board's layout (homography misfit {misfit:.1f} px; mis-ordered detection)"
    # Strong foreshortening (board seen > 65 deg from its normal) gives biased corners.
    if _foreshortening(H, obj.mean(axis=0)) < np.cos(np.radians(65.0)):
        return "board seen too obliquely (> 65 deg from its normal)"
    hull_area = cv2.contourArea(cv2.convexHull(detection.pixels.astype(np.float32)))
    if hull_area < 0.002 * image_size[0] * image_size[1]:
        return "board too small in the image"
    return None
