"""Calibration boards: specification, texture, detection and view-quality checks.

Board frame: origin at the top-left corner of the printed pattern, x to the right along the
columns, y down along the rows, z into the board (right-handed), millimetres. Object points lie
on z = 0. Two kinds:

* ``checkerboard:COLSxROWS:SQUARE_MM`` — COLS x ROWS *inner* corners (OpenCV convention), found
  with ``cv2.findChessboardCornersSB``. OpenCV's corner order can start at any corner of the
  grid; :func:`order_checkerboard` puts every view into one order (the board frame above, the
  pattern's corner square at the origin black, as :meth:`BoardSpec.texture` prints it), so the
  same corner id is the same physical corner in every camera and multi-camera extrinsics work.
  That needs a board with one odd and one even count of inner corners (e.g. 4x7): a board with
  both odd or both even looks the same after a half turn and its views stay ambiguous.
* ``charuco:COLSxROWS:SQUARE_MM[:MARKER_MM[:DICT]]`` — COLS x ROWS *squares*, ArUco markers of
  MARKER_MM (default 0.75 * square) from dictionary DICT (default ``DICT_4X4_50``); corners carry
  ids, so every view is unambiguous and partial views still count.

Options follow the spec, in any order (``charuco:4x5:54:40.5:DICT_4X4_1000:inverted:legacy``):

* ``normal`` / ``inverted`` — printed polarity (inverted: white and black swapped, markers light on
  dark). Detection runs on the inverted image, so the board frame and corner ids are the same.
* ``current`` / ``legacy`` — ChArUco layout: OpenCV >= 4.6 moved the markers of boards with an even
  number of rows (``CharucoBoard.setLegacyPattern``); boards printed before use the legacy one.
* ``front`` / ``mirrored`` — the pattern reads mirrored (a board in a glass frame seen from behind):
  detection runs on the horizontally flipped image and the corners are mapped back.

An option left out is ``auto``: :func:`detect_board` tries the variants (:meth:`BoardSpec.variants`)
and records the one that read the board in :attr:`BoardDetection.variant`. A checkerboard reads the
same in both polarities and mirrored (its order would change), so for it ``auto`` means ``normal``
and ``front``: say ``inverted`` / ``mirrored`` when the board is.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from itertools import product
from typing import Literal

import cv2
import numpy as np

from spinemocap.capture import to_grey
from spinemocap.fileio import InputError

#: Largest accepted blur (Gaussian sigma of the board edges, px) before a view is rejected.
MAX_BLUR_SIGMA_PX = 3.0

Polarity = Literal["auto", "normal", "inverted"]
Layout = Literal["auto", "current", "legacy"]
Facing = Literal["auto", "front", "mirrored"]
POLARITY_WORDS: dict[str, Polarity] = {"normal": "normal", "inverted": "inverted"}
LAYOUT_WORDS: dict[str, Layout] = {"current": "current", "legacy": "legacy"}
FACING_WORDS: dict[str, Facing] = {"front": "front", "mirrored": "mirrored"}
#: option word -> (BoardSpec field, value)
BOARD_OPTIONS: dict[str, tuple[str, str]] = {
    **{word: ("polarity", word) for word in POLARITY_WORDS}, **{word: ("layout", word) for word in LAYOUT_WORDS},
    **{word: ("facing", word) for word in FACING_WORDS},
}


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
    polarity: Polarity = "auto"
    layout: Layout = "auto"
    facing: Facing = "auto"

    # ------------------------------------------------------------------ parsing
    @classmethod
    def parse(cls, text: str) -> "BoardSpec":
        """Parse ``checkerboard:7x4:60`` or ``charuco:8x6:40[:30[:DICT_5X5_100]]``."""
        parts, options = split_board_options(text)
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
                "board", f"cannot parse board {text!r}; expected checkerboard:COLSxROWS:SQUARE_MM "
                "(inner corners) or charuco:COLSxROWS:SQUARE_MM[:MARKER_MM[:DICT]] (squares)"
            ) from None
        spec = replace(spec, polarity=POLARITY_WORDS.get(options.get("polarity", ""), "auto"),
                       layout=LAYOUT_WORDS.get(options.get("layout", ""), "auto"),
                       facing=FACING_WORDS.get(options.get("facing", ""), "auto"))
        spec.validate()
        return spec

    def validate(self) -> None:
        if self.cols < 2 or self.rows < 2 or self.square_mm <= 0:
            raise InputError("board", f"board {self} needs at least 2x2 corners/squares and a positive square size")
        if self.kind == "charuco":
            if not 0 < self.marker_mm < self.square_mm:
                raise InputError("board", "ChArUco marker size must be positive and smaller than the square")
            if not hasattr(cv2.aruco, self.dictionary):
                raise InputError("board", f"unknown ArUco dictionary {self.dictionary!r}")

    def __str__(self) -> str:
        base = f"{self.kind}:{self.cols}x{self.rows}:{self.square_mm:g}"
        base += f":{self.marker_mm:g}:{self.dictionary}" if self.kind == "charuco" else ""
        return base + "".join(f":{value}" for value in (self.polarity, self.layout, self.facing) if value != "auto")

    # ------------------------------------------------------------------ variants
    @property
    def layout_matters(self) -> bool:
        """Only ChArUco boards with an even number of rows differ between the two layouts."""
        return self.kind == "charuco" and self.rows % 2 == 0

    def variants(self) -> list["BoardSpec"]:
        """The fully specified boards this spec may be, most likely first: its ``auto`` options
        expanded (ChArUco: both polarities, both layouts where they differ, front and mirrored;
        checkerboard: ``normal`` and ``front``, which a view cannot tell apart)."""
        charuco = self.kind == "charuco"
        polarities: list[Polarity] = ["normal", "inverted"] if self.polarity == "auto" and charuco else [
            "normal" if self.polarity == "auto" else self.polarity]
        layouts: list[Layout] = (["current", "legacy"] if self.layout == "auto" else [self.layout]) if self.layout_matters else [
            "current" if self.layout == "auto" else self.layout]
        facings: list[Facing] = ["front", "mirrored"] if self.facing == "auto" and charuco else [
            "front" if self.facing == "auto" else self.facing]
        return [replace(self, polarity=p, layout=lay, facing=f)
                for f, p, lay in product(facings, polarities, layouts)]

    @property
    def board_variant(self) -> tuple[Polarity, Layout]:
        """(polarity, layout): what the printed board is, whoever looks at it."""
        return self.polarity, self.layout

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
            return _charuco(self.cols, self.rows, self.square_mm, self.marker_mm, self.dictionary,
                            self.layout == "legacy")[1].copy()
        return np.column_stack([xy, np.zeros(len(xy))]).astype(float)

    def charuco_board(self) -> "cv2.aruco.CharucoBoard":
        return _charuco(self.cols, self.rows, self.square_mm, self.marker_mm, self.dictionary, self.layout == "legacy")[0]

    def texture(self, px_per_mm: float) -> np.ndarray:
        """Grey uint8 image of the printed pattern, texture pixel = mm * px_per_mm - 0.5 (no margin)."""
        w_mm, h_mm = self.size_mm
        size = (int(round(w_mm * px_per_mm)), int(round(h_mm * px_per_mm)))
        if self.kind == "charuco":
            pattern = self.charuco_board().generateImage(size, marginSize=0, borderBits=1)
        else:
            sq = self.square_mm * px_per_mm
            v, u = np.mgrid[0 : size[1], 0 : size[0]]
            parity = (np.floor((u + 0.5) / sq).astype(int) + np.floor((v + 0.5) / sq).astype(int)) % 2
            pattern = np.where(parity == 0, 0, 255).astype(np.uint8)
        return 255 - pattern if self.polarity == "inverted" else pattern


@lru_cache(maxsize=32)
def _charuco(cols: int, rows: int, square_mm: float, marker_mm: float, dictionary: str, legacy: bool
             ) -> tuple["cv2.aruco.CharucoBoard", np.ndarray]:
    """The OpenCV board and its (N, 3) chessboard corners, built once. The board's markers are ids
    0 .. n-1 of ``dictionary``; the detector gets a dictionary of those alone (same codes and
    error correction), since matching every candidate against all of e.g. DICT_4X4_1000's codes
    costs ten times the whole detection."""
    full = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n_markers = (cols * rows) // 2
    if n_markers > len(full.bytesList):
        raise InputError("board", f"a {cols}x{rows} ChArUco board needs {n_markers} markers but {dictionary} has "
                         f"{len(full.bytesList)}; use a larger dictionary")
    own = cv2.aruco.Dictionary(full.bytesList[:n_markers], full.markerSize, full.maxCorrectionBits)
    board = cv2.aruco.CharucoBoard((cols, rows), square_mm, marker_mm, own)
    board.setLegacyPattern(legacy)
    return board, np.asarray(board.getChessboardCorners(), float).reshape(-1, 3)


def split_board_options(text: str) -> tuple[list[str], dict[str, str]]:
    """``charuco:4x5:54:inverted`` -> (the spec's fields, {"polarity": "inverted"}); the option
    words (:data:`BOARD_OPTIONS`) may follow the spec in any order, each field at most once."""
    parts = text.strip().split(":")
    fields = [p for p in parts if p.lower() not in BOARD_OPTIONS]
    options: dict[str, str] = {}
    for word in (p.lower() for p in parts if p.lower() in BOARD_OPTIONS):
        field_name, value = BOARD_OPTIONS[word]
        if field_name in options and options[field_name] != value:
            raise InputError("board", f"board {text!r} says both {options[field_name]!r} and {value!r}; "
                             f"give at most one of {', '.join(w for w, (f, _) in BOARD_OPTIONS.items() if f == field_name)}")
        options[field_name] = value
    return fields, options


@dataclass
class BoardDetection:
    """Corners of one board in one image: ``ids`` (N,) index :meth:`BoardSpec.object_points`;
    ``pixels`` (N, 2) distorted pixel positions; ``blur_px`` estimated edge blur sigma (the
    blurrier of the board's two edge directions: motion blur counts)."""

    ids: np.ndarray
    pixels: np.ndarray
    blur_px: float = 0.0
    #: Why the corner order cannot be trusted across cameras (checkerboards only), else None.
    order_problem: str | None = None
    #: The fully specified board that read this view (:meth:`BoardSpec.variants`), when known.
    variant: BoardSpec | None = None

    def __len__(self) -> int:
        return len(self.ids)


def detect_board(image: np.ndarray, board: BoardSpec) -> BoardDetection | None:
    """Find the board's corners (sub-pixel) in a BGR or grey image; None when not found. A spec
    with ``auto`` options tries :meth:`BoardSpec.variants` in order and keeps the first that reads
    the board with corners that fit its layout; :attr:`BoardDetection.variant` says which."""
    grey = to_grey(image)
    for variant in board.variants():
        detection = _detect_variant(grey, variant)
        if detection is not None and (len(board.variants()) == 1 or _fits_layout(detection, variant)):
            return detection
    return None


def _detect_variant(grey: np.ndarray, board: BoardSpec) -> BoardDetection | None:
    """:func:`detect_board` for one fully specified board: the image is inverted and/or flipped
    as the board's options say, and the corners are mapped back to the original image."""
    seen = 255 - grey if board.polarity == "inverted" else grey
    if board.facing == "mirrored":
        seen = np.ascontiguousarray(seen[:, ::-1])
    found = _detect_checkerboard(seen, board) if board.kind == "checkerboard" else _detect_charuco(seen, board)
    if found is None:
        return None
    ids, pixels, problem = found
    axes = board_axes(board, ids, pixels)
    blur = edge_blur_sigma(seen, pixels, axes)
    if board.facing == "mirrored":
        pixels = pixels.copy()
        pixels[:, 0] = grey.shape[1] - 1 - pixels[:, 0]
    return BoardDetection(ids, pixels, blur, problem, board)


def _detect_checkerboard(grey: np.ndarray, board: BoardSpec) -> tuple[np.ndarray, np.ndarray, str | None] | None:
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
    pixels, problem = order_checkerboard(grey, pixels, board)
    return np.arange(len(pixels)), pixels, problem


def _detect_charuco(grey: np.ndarray, board: BoardSpec) -> tuple[np.ndarray, np.ndarray, None] | None:
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
    return ids.ravel().astype(int), pixels.astype(float), None


def _fits_layout(detection: BoardDetection, board: BoardSpec) -> bool:
    """The corners map to the board by a homography (a view read with the wrong variant does not)."""
    return len(detection) >= 4 and _homography_misfit(detection, board)[1] <= 0.03 * float(
        np.ptp(detection.pixels, axis=0).max()) + 1.0


def _homography_misfit(detection: BoardDetection, board: BoardSpec) -> tuple[np.ndarray | None, float]:
    """(board -> image homography, RMS misfit px) of the detected corners (np.inf when none fits)."""
    obj = board.object_points()[detection.ids, :2]
    H, _ = cv2.findHomography(obj, detection.pixels, 0)
    if H is None:
        return None, float("inf")
    fit = cv2.perspectiveTransform(obj[None], H)[0]
    return H, float(np.sqrt(np.mean(np.sum((fit - detection.pixels) ** 2, axis=1))))


def board_axes(board: BoardSpec, ids: np.ndarray, pixels: np.ndarray) -> np.ndarray | None:
    """(N, 2, 2) image directions (unit rows) of the board's x and y axes at each corner, from
    the board -> image homography of the corners; None when fewer than 4 corners."""
    if len(ids) < 4:
        return None
    obj = board.object_points()[ids, :2]
    H, _ = cv2.findHomography(obj, pixels, 0)
    if H is None:
        return None
    axes = np.stack([_jacobian(H, xy).T for xy in obj])
    return axes / np.linalg.norm(axes, axis=2, keepdims=True)


def _jacobian(H: np.ndarray, at_xy: np.ndarray) -> np.ndarray:
    """2x2 Jacobian d(u, v) / d(x, y) of the homography at board point ``at_xy``."""
    x, y = at_xy
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    u = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w
    v = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
    return np.array([[H[0, 0] - u * H[2, 0], H[0, 1] - u * H[2, 1]], [H[1, 0] - v * H[2, 0], H[1, 1] - v * H[2, 1]]]) / w


def is_half_turn_symmetric(board: BoardSpec) -> bool:
    """A checkerboard whose inner-corner counts are both odd or both even prints the same after a
    half turn about its centre, so no view can tell its origin corner."""
    return board.kind == "checkerboard" and (board.cols + board.rows) % 2 == 0


def order_checkerboard(grey: np.ndarray, pixels: np.ndarray, board: BoardSpec,
                       min_contrast: float = 4.0) -> tuple[np.ndarray, str | None]:
    """Checkerboard corners (OpenCV's row-major grid, any start corner) in the board's own order.

    1. Mirror: the printed face is what a camera sees, so the board's x (along COLS) and y (along
       ROWS) axes must turn the same way as the image's u and v (board z, into the board, points
       away from the camera). If every grid cell turns the other way, the rows are reversed.
    2. Half turn: the pattern's corner square at the origin is black, so the square between
       corners (i, j) and (i+1, j+1) is black when i + j is even. Over all squares between the
       detected corners, the ones predicted black must be darker than the ones predicted white;
       when they are brighter the order is turned by half a turn. With one odd and one even side
       a half turn changes every square's colour, so this decides; otherwise it cannot.

    Returns (pixels in board order, None) or (pixels, reason) when the order stays ambiguous.
    ``min_contrast``: least separation of the two square classes (difference of their medians
    over the pooled spread of the squares' brightness) for a decision.
    """
    grid = pixels.reshape(board.rows, board.cols, 2)
    along_x = grid[:-1, 1:] - grid[:-1, :-1]
    along_y = grid[1:, :-1] - grid[:-1, :-1]
    turn = along_x[..., 0] * along_y[..., 1] - along_x[..., 1] * along_y[..., 0]
    if not (np.all(turn > 0) or np.all(turn < 0)):
        return pixels, "the corner grid folds over (cells turn both ways): a mis-ordered detection"
    if np.all(turn < 0):
        grid = grid[::-1]
    if is_half_turn_symmetric(board):
        return grid.reshape(-1, 2), (f"checkerboard {board.cols}x{board.rows} looks the same after a half turn "
                                     "(inner corners both odd or both even); use a board with one odd and one "
                                     "even count of inner corners, e.g. 4x7, or a ChArUco board")
    darkness = _square_brightness(grey, grid)
    parity = np.add.outer(np.arange(board.rows - 1), np.arange(board.cols - 1)) % 2
    black, white = darkness[parity == 0], darkness[parity == 1]
    spread = np.sqrt(0.5 * (np.var(black) + np.var(white))) + 1.0
    separation = (np.median(white) - np.median(black)) / spread
    if abs(separation) < min_contrast:
        return grid.reshape(-1, 2), (f"black and white squares cannot be told apart (separation {abs(separation):.1f} "
                                     f"< {min_contrast:g}): glare, a washed-out print or a mis-detection")
    if separation < 0:
        grid = grid[::-1, ::-1]
    return grid.reshape(-1, 2), None


def _square_brightness(grey: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """(rows-1, cols-1) median gray level inside each square between detected corners, sampled
    on a 5x5 lattice over the square's middle half (bilinear in the corners' positions)."""
    s = np.linspace(0.25, 0.75, 5)
    a, b = np.meshgrid(s, s)
    p00, p01, p10, p11 = grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1], grid[1:, 1:]
    w = [((1 - a) * (1 - b)).ravel(), (a * (1 - b)).ravel(), ((1 - a) * b).ravel(), (a * b).ravel()]
    points = np.sum([p[..., None, :] * wk[:, None] for p, wk in zip((p00, p01, p10, p11), w)], axis=0)
    h, wd = grey.shape
    u = np.clip(np.round(points[..., 0]).astype(int), 0, wd - 1)
    v = np.clip(np.round(points[..., 1]).astype(int), 0, h - 1)
    return np.median(grey[v, u].astype(float), axis=-1)


def _median_spacing(pixels: np.ndarray) -> float:
    if len(pixels) < 2:
        return 10.0
    d = np.linalg.norm(pixels[:, None] - pixels[None], axis=2)
    d[d == 0] = np.inf
    return float(np.median(d.min(axis=1)))


def edge_blur_sigma(grey: np.ndarray, corners: np.ndarray, axes: np.ndarray | None = None) -> float:
    """Blur of the board edges as a Gaussian sigma (px): a step of contrast C blurred by sigma
    has peak gradient C / (sigma sqrt(2 pi)), so sigma = C / (peak gradient sqrt(2 pi)).
    Measured in patches around the corners (median over patches). ``axes`` (N, 2, 2): the board's
    x and y directions in the image at each corner (:func:`board_axes`); with them each patch's
    sigma is that of its blurrier edge family (the gradient across the edges along x, and across
    those along y), so motion blur, which smears one direction only, counts in full."""
    half = int(np.clip(0.4 * _median_spacing(corners), 4, 30))
    img = grey.astype(np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    h, w = grey.shape
    sigmas = []
    for k, (u, v) in enumerate(np.round(corners).astype(int)):
        y0, y1, x0, x1 = max(v - half, 0), min(v + half + 1, h), max(u - half, 0), min(u + half + 1, w)
        if y1 - y0 < 5 or x1 - x0 < 5:
            continue
        patch = img[y0:y1, x0:x1]
        contrast = np.percentile(patch, 95) - np.percentile(patch, 5)
        px, py = gx[y0:y1, x0:x1], gy[y0:y1, x0:x1]
        if axes is None:
            peaks = [np.percentile(np.hypot(px, py), 99)]
        else:  # normals of the edges along each board axis
            peaks = [np.percentile(np.abs(-px * a[1] + py * a[0]), 99) for a in axes[k]]
        peak = min(peaks)
        if contrast > 20 and peak > 0:
            sigmas.append(contrast / (peak * np.sqrt(2 * np.pi)))
    return float(np.median(sigmas)) if sigmas else float("inf")


def _foreshortening(H: np.ndarray, at_xy: np.ndarray) -> float:
    """Ratio of the smaller to the larger singular value of the homography's local Jacobian at
    board point ``at_xy`` (about cos of the viewing angle from the board normal)."""
    sv = np.linalg.svd(_jacobian(H, at_xy), compute_uv=False)
    return float(sv[1] / sv[0])


def view_problem(detection: BoardDetection | None, board: BoardSpec, image_size: tuple[int, int],
                 max_blur_px: float = MAX_BLUR_SIGMA_PX, need_order: bool = False) -> str | None:
    """Why a detected view is unusable for calibration, or None if it is fine. ``need_order``:
    the view is shared with other cameras (extrinsics), so a checkerboard's corner order must
    be unambiguous (:func:`order_checkerboard`)."""
    if detection is None:
        return "board not found"
    if need_order and detection.order_problem:
        return f"corner order ambiguous: {detection.order_problem}"
    min_corners = max(6, int(0.3 * board.n_corners))
    if len(detection) < min_corners:
        return f"only {len(detection)} corners (< {min_corners})"
    if detection.blur_px > max_blur_px:
        return f"blurred (edge sigma {detection.blur_px:.1f} px > {max_blur_px:g}; motion or focus blur)"
    # Degenerate geometry: corners must span two dimensions (not all on one board row/line).
    centred = detection.pixels - detection.pixels.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[1] < 0.05 * sv[0]:
        return "corners nearly collinear (board edge-on or only one row visible)"
    # Corners must map to the board by a homography (up to lens distortion): a mis-ordered or
    # partly wrong detection does not.
    obj = board.object_points()[detection.ids, :2]
    H, misfit = _homography_misfit(detection, board)
    if H is None:
        return "corners do not fit the board's layout"
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
