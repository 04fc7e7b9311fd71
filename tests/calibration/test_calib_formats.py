"""Calibration file formats: round trips keep projections within 0.01 px; the real Qualisys
export converts to cameras that look at the studio; bad files give InputErrors."""


import numpy as np
import pytest
from repo_paths import SHARED

from calibration.formats import read_rig, write_rig
from calibration.formats.qualisys import read_qca
from spinemocap.bench.calibration_scenes import make_ring_rig
from spinemocap.cli import main
from spinemocap.fileio import InputError

QCA = SHARED / "data" / "calibration" / "pose2sim_demo" / "Calib.qca.txt"


def _rig_with_full_distortion():
    rig = make_ring_rig(4, size=(640, 480), seed=5)
    for k, cam in enumerate(rig):
        cam.dist[:] = [-0.11 + 0.02 * k, 0.04, 0.0011, -0.0007, 0.01 * (k % 2)]
        cam.K[0, 1] = 0.0
        cam.K[1, 1] = cam.K[0, 0] * 1.002
    return rig


def _max_projection_change(a, b):
    points = np.random.default_rng(0).uniform([-1500, -1500, 0], [1500, 1500, 2000], (500, 3))
    worst = 0.0
    for ca, cb in zip(a, b):
        pa, pb = ca.project(points), cb.project(points)
        visible = ca.in_image(pa) & (ca.depth(points) > 0)
        worst = max(worst, float(np.max(np.linalg.norm(pa[visible] - pb[visible], axis=1))))
    return worst


@pytest.mark.parametrize("name,fmt", [("rig.toml", None), ("calib.toml", "pose2sim"), ("cams.xcp", None)])
def test_round_trip_keeps_projections(tmp_path, name, fmt):
    rig = _rig_with_full_distortion()
    write_rig(rig, tmp_path / name, fmt)
    back = read_rig(tmp_path / name)
    assert back.names == rig.names
    assert [c.size for c in back] == [c.size for c in rig]
    assert _max_projection_change(rig, back) < 0.01


def test_pose2sim_file_is_in_metres_with_rodrigues(tmp_path):
    rig = _rig_with_full_distortion()
    write_rig(rig, tmp_path / "c.toml", "pose2sim")
    import tomllib

    data = tomllib.loads((tmp_path / "c.toml").read_text())
    cam = data["cam_01"]
    np.testing.assert_allclose(np.array(cam["translation"]) * 1000, rig[0].t, atol=1e-9)
    np.testing.assert_allclose(cam["rotation"], rig[0].rvec, atol=1e-12)
    assert cam["matrix"][0][0] == pytest.approx(rig[0].K[0, 0])


def test_xcp_nexus_only_radial_terms(tmp_path):
    """A Nexus file has only VICON_RADIAL: k1 k2 come back, nothing else is invented."""
    rig = make_ring_rig(2, seed=1)
    write_rig(rig, tmp_path / "n.xcp")
    text = (tmp_path / "n.xcp").read_text()
    assert "SPINEMOCAP_DISTORTION" not in text  # no tangential/k3 terms to carry
    back = read_rig(tmp_path / "n.xcp")
    np.testing.assert_allclose(back[0].dist, rig[0].dist, atol=1e-15)


def test_convert_cli(tmp_path, capsys):
    rig = _rig_with_full_distortion()
    rig.to_toml(tmp_path / "rig.toml")
    assert main(["calibrate", "convert", str(tmp_path / "rig.toml"), str(tmp_path / "out.xcp")]) == 0
    assert main(["calibrate", "convert", str(tmp_path / "out.xcp"), str(tmp_path / "p2s.toml"),
                 "--format", "pose2sim"]) == 0
    assert _max_projection_change(rig, read_rig(tmp_path / "p2s.toml")) < 0.01


def test_bad_calibration_files(tmp_path, capsys):
    (tmp_path / "x.xcp").write_text("<Cameras><Camera NAME='a'><KeyFrames/></Camera></Cameras>")
    with pytest.raises(InputError, match="KeyFrame"):
        read_rig(tmp_path / "x.xcp")
    (tmp_path / "y.qca.txt").write_text("not xml")
    with pytest.raises(InputError, match="qca"):
        read_rig(tmp_path / "y.qca.txt")
    with pytest.raises(InputError, match="unknown calibration format"):
        read_rig(tmp_path / "z.yaml")
    with pytest.raises(InputError, match="read only"):
        write_rig(_rig_with_full_distortion(), tmp_path / "w.qca.txt")
    assert main(["calibrate", "convert", str(tmp_path / "x.xcp"), str(tmp_path / "o.toml")]) == 2
    assert "KeyFrame" in capsys.readouterr().err


def test_real_qualisys_file():
    if not QCA.is_file():
        pytest.skip("shared calibration data not present")
    rig = read_qca(QCA)
    assert rig.names == ["cam01", "cam02", "cam03", "cam04"]
    for cam in rig:
        assert cam.size == (1088, 1920)
        # sensor units -> px: 69568 units span 1088 px
        assert 1670 < cam.K[0, 0] < 1690
        assert abs(cam.K[0, 2] - 544) < 40 and abs(cam.K[1, 2] - 960) < 40
        # every camera sees the studio origin in front of it, and world Z up points up in the image
        origin, above = cam.project(np.array([[0.0, 0, 0], [0, 0, 1000]]))
        assert cam.depth(np.zeros((1, 3)))[0] > 1000
        assert cam.in_image(origin[None])[0]
        assert above[1] < origin[1]
    first = rig[0]
    np.testing.assert_allclose(first.center, [1460.2323709212087, -1909.1590482454608, 1896.5058524092062], atol=1e-6)
    assert first.dist[0] == pytest.approx(-0.046183)
