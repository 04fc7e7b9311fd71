"""The detection benchmark's scoring: one-to-one matching within the radius, recall and
precision with hidden dots not counted false, the wall's share of a hole, the peer's set-up."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from spinemocap.bench.detect import MATCH_PX, DotScore, hole_open_share, match, simple_blob_detector


def test_matching_is_one_to_one_within_the_radius():
    gt = np.array([[10.0, 10.0], [20.0, 10.0]])
    pred = np.array([[10.5, 10.0], [11.0, 10.0], [20.0, 10.0 + 2 * MATCH_PX]])
    i, j = match(pred, gt)
    assert list(zip(i, j)) == [(0, 0)]  # the nearer of two claims; the far one matches nothing


def test_scores_count_misses_and_false_dots_but_not_hidden_dots():
    score = DotScore()
    gt = np.array([[10.0, 10.0], [50.0, 50.0]])
    hidden = np.array([[90.0, 90.0]])
    pred = np.array([[10.2, 10.0], [90.1, 90.0], [200.0, 200.0]])
    score.add(pred, gt, hidden, unoccluded=np.array([True, False]), view_angle_deg=np.array([10.0, 80.0]))
    summary = score.summary()
    assert (summary.true_positives, summary.missed, summary.false_positives) == (1, 1, 1)
    assert summary.recall == 0.5 and summary.precision == 0.5 and summary.recall_unoccluded == 1.0
    assert summary.centroid_rms_px == pytest.approx(0.2)
    assert list(summary.to_dict())[:3] == ["recall", "recall_unoccluded", "unoccluded_dots"]


def test_the_tape_wall_hides_more_of_a_hole_the_more_oblique_the_view():
    shares = hole_open_share(np.array([0.0, 30.0, 60.0, 85.0]), thickness_mm=0.8, dot_diameter_mm=3.0)
    assert shares[0] == pytest.approx(1.0) and (np.diff(shares) < 0).all() and shares[-1] >= 0


def test_the_peer_finds_bright_dots_of_the_size_it_is_told():
    image = np.zeros((120, 160), np.uint8)
    centres = [(30, 40), (80, 40), (130, 90)]
    for u, v in centres:
        cv2.circle(image, (u, v), 5, 255, -1)
    found = np.array([k.pt for k in simple_blob_detector(10.0).detect(image)])
    i, j = match(found, np.array(centres, float))
    assert len(found) == 3 and len(i) == 3
