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
