"""Body-model backends: the SMPL backend on a tiny SMPL-format file the test writes (skipped
without ``smplx``), the AMASS loader on both layouts, and anny's sparse path."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from spinemocap.bodymodel.amass import load_amass
from spinemocap.bodymodel.base import SurfaceAnchors
from spinemocap.fileio import InputError

SMPL_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]


def write_tiny_smpl(path, n_per_joint: int = 6, seed: int = 0):
    """A 24-joint SMPL-format model (chumpy-free pickle) with 6 vertices around each joint of a
    stick figure in SMPL's frame (Y up, facing +Z, metres)."""
    rng = np.random.default_rng(seed)
    joints = np.zeros((24, 3))
    step = {1: (0.09, -0.08, 0), 2: (-0.09, -0.08, 0), 3: (0, 0.1, 0), 4: (0, -0.4, 0), 5: (0, -0.4, 0),
            6: (0, 0.12, 0), 7: (0, -0.4, 0), 8: (0, -0.4, 0), 9: (0, 0.05, 0), 10: (0, -0.05, 0.12),
            11: (0, -0.05, 0.12), 12: (0, 0.2, 0), 13: (0.08, 0.12, 0), 14: (-0.08, 0.12, 0), 15: (0, 0.1, 0.03),
            16: (0.1, 0.02, 0), 17: (-0.1, 0.02, 0), 18: (0.26, 0, 0), 19: (-0.26, 0, 0), 20: (0.25, 0, 0),
            21: (-0.25, 0, 0), 22: (0.08, 0, 0), 23: (-0.08, 0, 0)}
    for j in range(1, 24):
        joints[j] = joints[SMPL_PARENTS[j]] + np.array(step[j])
    joints[:, 1] += 0.9
    V = 24 * n_per_joint
    owner = np.repeat(np.arange(24), n_per_joint)
    v_template = joints[owner] + rng.normal(0, 0.03, (V, 3))
    weights = np.zeros((V, 24))
    weights[np.arange(V), owner] = 0.7
    weights[np.arange(V), np.maximum(np.array(SMPL_PARENTS)[owner], 0)] += 0.3
    J_regressor = np.zeros((24, V))
    J_regressor[owner, np.arange(V)] = 1.0 / n_per_joint
    faces = np.array([[i, i + 1, i + 2] for i in range(0, V - 2, 3)], dtype=np.uint32)
    model = {"v_template": v_template, "weights": weights, "J_regressor": J_regressor,
             "kintree_table": np.array([[4294967295] + SMPL_PARENTS[1:], list(range(24))], dtype=np.int64),
             "shapedirs": rng.normal(0, 0.01, (V, 3, 10)), "posedirs": rng.normal(0, 0.002, (V, 3, 207)),
             "f": faces}
    with open(path, "wb") as handle:
        pickle.dump(model, handle)
    return model


def test_smpl_backend_matches_smplx_on_a_tiny_model(tmp_path):
    pytest.importorskip("smplx")
    import torch

    from spinemocap.bodymodel import load_model
    from spinemocap.bodymodel.smpl_body import SMPL_TO_STUDIO

    path = tmp_path / "SMPL_NEUTRAL.pkl"
    write_tiny_smpl(path)
    model = load_model("smpl", path)
    assert model.pose_size == 6 + 3 * 23
    rng = np.random.default_rng(1)
    pose = np.zeros((2, model.pose_size))
    pose[:, 6:] = rng.normal(0, 0.3, (2, 69))
    betas = rng.normal(0, 1.0, 10)
    ours = model.vertices(pose, betas)
    with torch.no_grad():
        out = model.module(betas=torch.tensor(betas[None], dtype=torch.float32).repeat(2, 1),
                           body_pose=torch.tensor(pose[:, 6:], dtype=torch.float32),
                           global_orient=torch.zeros(2, 3), transl=torch.zeros(2, 3))
    reference = out.vertices.double().numpy() @ SMPL_TO_STUDIO.T * 1000.0
    assert np.abs(ours - reference).max() < 0.05  # mm (float32 reference)
    # global rotation about the rest pelvis, then translation
    rest = model.rest(betas)
    pose[:, 3:6] = [0.0, 0.0, np.pi / 2]
    pose[:, :3] = [10.0, 20.0, 30.0]
    turned = model.vertices(pose, betas)
    c = rest.pelvis
    Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(turned, (reference - c) @ Rz.T + c + [10, 20, 30], atol=0.05)
    # sparse path = dense path; a rest-pose offset moves with the skin
    idx = np.array([5, 40, 100])
    sparse = model.points(torch.tensor(pose), betas, SurfaceAnchors(idx, np.zeros((3, 3)))).numpy()
    np.testing.assert_allclose(sparse, turned[:, idx], atol=0.05)


def test_smpl_backend_names_the_licence_when_files_are_absent(tmp_path):
    pytest.importorskip("smplx")
    from spinemocap.bodymodel import load_model

    for kind in ("smpl", "smplx"):
        with pytest.raises(InputError, match="licence-gated.*https://smpl"):
            load_model(kind, tmp_path / "nowhere")
        with pytest.raises(InputError, match="licence-gated"):
            load_model(kind, None)


def test_amass_loader_reads_both_layouts(tmp_path):
    rng = np.random.default_rng(2)
    n = 7
    poses = rng.normal(0, 0.2, (n, 156))
    trans = rng.normal(0, 1.0, (n, 3))
    betas = rng.normal(0, 1.0, 16)
    np.savez(tmp_path / "smplh.npz", poses=poses, trans=trans, betas=betas, gender=np.array("female"),
             mocap_framerate=np.array(120.0))
    a = load_amass(tmp_path / "smplh.npz")
    assert a.layout == "smplh" and a.gender == "female" and a.fps == 120.0 and a.n_frames == n
    np.testing.assert_array_equal(a.root_orient, poses[:, :3])
    np.testing.assert_array_equal(a.pose_body, poses[:, 3:66])
    np.testing.assert_array_equal(a.pose_hand, poses[:, 66:])
    np.testing.assert_array_equal(a.trans, trans)

    np.savez(tmp_path / "smplx.npz", root_orient=poses[:, :3], pose_body=poses[:, 3:66], pose_hand=poses[:, 66:],
             pose_jaw=poses[:, :3] * 2, trans=trans, betas=betas[:10], gender=np.array(b"male"),
             mocap_frame_rate=np.array(60.0))
    b = load_amass(tmp_path / "smplx.npz")
    assert b.layout == "smplx" and b.gender == "male" and b.fps == 60.0
    np.testing.assert_array_equal(b.pose_body, a.pose_body)
    np.testing.assert_array_equal(b.pose_jaw, poses[:, :3] * 2)
    assert len(b.betas) == 10

    np.savez(tmp_path / "bad.npz", trans=trans)
    with pytest.raises(InputError, match="neither the SMPL\\+H"):
        load_amass(tmp_path / "bad.npz")
    np.savez(tmp_path / "short.npz", poses=poses, trans=trans[:3], betas=betas, mocap_framerate=np.array(1.0))
    with pytest.raises(InputError, match="frames"):
        load_amass(tmp_path / "short.npz")


def test_marker_fit_runs_on_the_smpl_backend(tmp_path):
    pytest.importorskip("smplx")
    import torch

    from spinemocap.bodymodel import load_model
    from spinemocap.bodymodel.fit import FitOptions, MarkerFitter
    from spinemocap.bodymodel.markersets import PLUG_IN_GAIT, place_markers

    write_tiny_smpl(tmp_path / "SMPL_NEUTRAL.pkl", n_per_joint=30)
    model = load_model("smpl", tmp_path / "SMPL_NEUTRAL.pkl")
    rest = model.rest()
    labels, vertices = place_markers(rest, list(PLUG_IN_GAIT))  # a stick figure: some rules find no skin
    assert len(labels) >= 20
    pose = np.zeros((2, model.pose_size))
    pose[:, 6:] = np.random.default_rng(0).normal(0, 0.1, model.pose_size - 6) * np.array([[1.0], [1.1]])
    pose[:, :3] = [[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]
    with torch.no_grad():
        markers = model.points(torch.tensor(pose), model.default_shape(),
                               SurfaceAnchors(vertices, rest.normals[vertices] * 9.5)).numpy()
    fit = MarkerFitter(model, vertices, FitOptions(n_key_frames=1, shape_rounds=1, shape_iterations=2)).fit(
        markers, labels=labels, progress=False)
    assert np.sqrt(np.mean(fit.residual_mm ** 2)) < 2.0
