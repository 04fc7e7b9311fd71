"""Angles on the synthetic studio's ground truth follow the applied spine motion (issue goal:
RMSE <= 2 deg, R^2 >= 0.98) and the angles a motion should not move stay flat."""


import numpy as np

from spinemocap.bench.analysis import bench_analytic, bench_studio, mid_bone_rows


def test_pipeline_is_exact_on_the_analytic_rod():
    # no skin, no body model: what is left is the spline/frame pipeline's own error
    for motion, r in bench_analytic(frames=20).items():
        assert r["rmse_deg"] < 0.1 and r["crosstalk_peak_deg"] < 0.1, motion


def test_mid_bone_rows_pick_rows_inside_bone_segments():
    rows = 945.0 + 25.0 * np.arange(13)
    joints = np.array([866.0, 934, 1002, 1077, 1211, 1379])
    assert mid_bone_rows(rows, joints) == (2, 9, 2)  # spine03 and spine02 heads lie between


def test_angles_follow_the_studio_motions():
    results = bench_studio(frames=24, fps=8.0, rows=13, progress=False)
    for motion, r in results.items():
        # the goal, as stated; crosstalk held to the same 2 deg budget (a spurious angle
        # below the accuracy target cannot be told from error)
        assert r["rmse_deg"] <= 2.0, (motion, r)
        assert r["r2"] >= 0.98, (motion, r)
        assert r["crosstalk_rms_deg"] <= 2.0, (motion, r)
        assert r["expected_peak_deg"] > 10.0  # the motion was really there
