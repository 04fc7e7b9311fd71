"""``bench realism``'s flagged share and vouched-for error, on a hand-made marker table."""

import numpy as np

from spinemocap.bench.realism import flagged_dot_share, vouched_error_mm
from spinemocap.markers import MarkerTable


def test_flagged_share_counts_doubted_and_missing_dot_frames_and_the_vouched_error_leaves_them_out():
    labels = ["R01L", "R01R", "R02L"]
    truth = np.zeros((4, 3, 3))
    positions = truth.copy()
    positions[..., 0] = 0.5                       # every tracked dot 0.5 mm off
    positions[1, :, 0] = 40.0                     # a flagged frame, 40 mm off: not vouched for
    positions[2, 2] = np.nan                      # a missing dot
    positions[3, 1, 0] = 30.0                     # a doubted dot in an unflagged frame
    status = np.full((4, 3), "observed", dtype=object)
    confidence = np.ones((4, 3))
    confidence[1] = 0.5
    confidence[3, 1] = 0.5
    status[3, 2], confidence[3, 2] = "inferred", 0.6  # inferred, vouched for
    table = MarkerTable.from_arrays(labels, positions, fps=50.0, status=status, confidence=confidence)
    assert flagged_dot_share(table) == (3 + 1 + 1) / 12
    assert vouched_error_mm(table, {"dots": truth, "labels": np.array(labels)}) == 0.5


def test_only_wrong_labels_the_tracker_vouches_for_count():
    from spinemocap.bench.realism import vouched_swaps

    labels = ["R01L", "R01R", "R02L"]
    truth = np.tile(np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [15.0, 25.0, 0.0]]), (3, 1, 1))
    positions = truth + 0.3
    positions[0, [0, 1]] = truth[0, [1, 0]]      # frame 0: two labels swapped, vouched for
    positions[1, [0, 1]] = truth[1, [1, 0]]      # frame 1: the same, but the frame is flagged
    confidence = np.ones((3, 3))
    confidence[1] = 0.5
    table = MarkerTable.from_arrays(labels, positions, fps=50.0, status=np.full((3, 3), "observed", dtype=object),
                                    confidence=confidence)
    assert vouched_swaps(table, {"dots": truth, "labels": np.array(labels)}, 25.0) == 2
