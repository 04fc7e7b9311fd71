"""Boards as labs print and film them: OpenCV's own ChArUco images inverted, in the legacy layout,
seen by cameras turned 90 / 180 degrees, mirrored (a glass board seen from behind) and warped by a
homography, found without being told and mapped to the right pixels; explicit board options;
motion blur rejected with a reason."""

import cv2
import numpy as np
import pytest

from calibration.boards import BoardSpec, detect_board, view_problem
from spinemocap.fileio import InputError

PPM = 2.0  # texture px per mm
PAD = 60  # px of margin around the printed pattern
WARP = np.array([[0.92, 0.14, 40.0], [-0.06, 1.0, 25.0], [2e-4, 1e-4, 1.0]])
SIZE = (760, 820)


def render(board: BoardSpec) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's own image of ``board`` (BoardSpec.texture = CharucoBoard.generateImage, inverted
    where the spec says), padded in the print's paper colour and warped by WARP; returns the
    image and every corner's true pixel (indexed by corner id)."""
    pattern = board.texture(PPM)
    paper = 0 if board.polarity == "inverted" else 255
    image = cv2.copyMakeBorder(pattern, PAD, PAD, PAD, PAD, cv2.BORDER_CONSTANT, value=paper)
    corners = board.object_points()[:, :2] * PPM - 0.5 + PAD
    warped = cv2.warpPerspective(image, WARP, SIZE, flags=cv2.INTER_AREA, borderValue=128)
    return warped, cv2.perspectiveTransform(corners[None], WARP)[0]


def turned(image: np.ndarray, pixels: np.ndarray, how: str) -> tuple[np.ndarray, np.ndarray]:
    """The image as a camera turned by 90 / 180 degrees or seeing it mirrored would record it,
    and where the corners land."""
    h, w = image.shape[:2]
    u, v = pixels.T
    if how == "rot90":  # np.rot90: counter-clockwise, (u, v) -> (v, w - 1 - u)
        return np.ascontiguousarray(np.rot90(image)), np.column_stack([v, w - 1 - u])
    if how == "rot180":
        return np.ascontiguousarray(image[::-1, ::-1]), np.column_stack([w - 1 - u, h - 1 - v])
    if how == "mirrored":
        return np.ascontiguousarray(image[:, ::-1]), np.column_stack([w - 1 - u, v])
    return image, pixels


@pytest.mark.parametrize("text, polarity, layout", [
    ("charuco:4x5:54:40.5:DICT_4X4_1000", "inverted", "current"),   # odd rows: one layout
    ("charuco:5x6:50:37:DICT_5X5_100", "normal", "legacy"),
    ("charuco:5x6:50:37:DICT_5X5_100", "inverted", "legacy"),
    ("charuco:6x4:50:37:DICT_6X6_250", "inverted", "current"),
])
@pytest.mark.parametrize("how", ["plain", "rot90", "rot180", "mirrored"])
def test_found_without_being_told_and_mapped_back(text, polarity, layout, how):
    auto = BoardSpec.parse(text)
    printed = BoardSpec.parse(f"{text}:{polarity}:{layout}")
    image, truth = turned(*render(printed), how)
    det = detect_board(image, auto)
    assert det is not None and len(det) == auto.n_corners
    assert det.variant is not None
    assert (det.variant.polarity, det.variant.facing) == (polarity, "mirrored" if how == "mirrored" else "front")
    if auto.layout_matters:
        assert det.variant.layout == layout
    error = np.linalg.norm(det.pixels - truth[det.ids], axis=1)
    assert error.max() < 0.3, error.max()
    assert view_problem(det, auto, (image.shape[1], image.shape[0])) is None


def test_explicit_options_read_only_their_variant():
    text = "charuco:5x6:50:37:DICT_5X5_100"
    image, truth = render(BoardSpec.parse(f"{text}:inverted:legacy"))
    assert detect_board(image, BoardSpec.parse(f"{text}:normal")) is None
    assert detect_board(image, BoardSpec.parse(f"{text}:current")) is None
    assert detect_board(image, BoardSpec.parse(f"{text}:mirrored")) is None
    det = detect_board(image, BoardSpec.parse(f"{text}:legacy:inverted:front"))
    assert det is not None and np.abs(det.pixels - truth[det.ids]).max() < 0.3


def test_board_spec_options_parse_and_print():
    spec = BoardSpec.parse("charuco:4x5:54:40.5:DICT_4X4_1000:inverted:legacy")
    assert (spec.polarity, spec.layout, spec.facing) == ("inverted", "legacy", "auto")
    assert BoardSpec.parse(str(spec)) == spec
    assert BoardSpec.parse("charuco:4x5:54").polarity == "auto"
    assert len(BoardSpec.parse("charuco:4x6:54").variants()) == 8   # 2 polarities x 2 layouts x 2 facings
    assert len(BoardSpec.parse("charuco:4x5:54").variants()) == 4   # odd rows: one layout
    assert [v.polarity for v in BoardSpec.parse("checkerboard:4x7:60").variants()] == ["normal"]
    assert BoardSpec.parse("checkerboard:4x7:60:inverted:mirrored").variants()[0].facing == "mirrored"
    with pytest.raises(InputError, match="both 'normal' and 'inverted'"):
        BoardSpec.parse("charuco:4x5:54:normal:inverted")
    with pytest.raises(InputError, match="needs 55 markers but DICT_4X4_50 has 50"):
        BoardSpec("charuco", 10, 11, 54, 40, "DICT_4X4_50").charuco_board()


def test_inverted_checkerboard_keeps_the_corner_order():
    """A checkerboard reads the same inverted, but its origin square is then white: told so, the
    corners come out in the board's own order, as for the normal print."""
    normal = BoardSpec.parse("checkerboard:4x7:30")
    inverted = BoardSpec.parse("checkerboard:4x7:30:inverted")
    for board in (normal, inverted):
        image, truth = render(board)
        det = detect_board(image, board)
        assert det is not None and det.order_problem is None
        assert np.abs(det.pixels - truth[det.ids]).max() < 0.3


def test_motion_blur_rejected_with_a_reason():
    board = BoardSpec.parse("charuco:4x5:54:40.5:DICT_4X4_1000:inverted")
    image, _ = render(board)
    size = (image.shape[1], image.shape[0])
    sharp = detect_board(image, board)
    assert sharp is not None and view_problem(sharp, board, size) is None
    for kernel in (np.full((1, 9), 1 / 9, np.float32), np.full((9, 1), 1 / 9, np.float32)):
        # a smear of 9 px along one image axis: the board moved during the exposure; the edges
        # along the motion stay sharp, the blurrier family counts
        blurred = detect_board(cv2.filter2D(image, -1, kernel), board)
        assert blurred is not None and blurred.blur_px > 3 * sharp.blur_px
        assert "blurred" in view_problem(blurred, board, size)
