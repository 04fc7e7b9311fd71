"""reference.toml: the L-frame round-trips; an object that cannot fix a world frame is refused
with the reason, a damaged file with its name."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.fileio import InputError
from spinemocap.reference import LFRAME_MARKERS_MM, ReferenceObject


def _turned() -> tuple[np.ndarray, np.ndarray]:
    rotation = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    return rotation, np.array([370.0, 189.0, 993.0])


def test_the_lframe_round_trips_and_stands_where_its_pose_puts_it(tmp_path):
    rotation, translation = _turned()
    lframe = ReferenceObject.lframe(rotation, translation)
    path = tmp_path / "reference.toml"
    lframe.to_toml(path)
    back = ReferenceObject.from_toml(path)
    assert back.labels == lframe.labels and back.n_markers == 5
    np.testing.assert_allclose(back.world_mm, lframe.world_mm)
    np.testing.assert_allclose(back.world_mm[0], translation)  # the corner marker at the origin of the object
    np.testing.assert_allclose(back.world_mm[2] - back.world_mm[0], [-190.0, 0.0, 0.0])
    assert ReferenceObject.lframe().world_mm.tolist() == [list(m) for m in LFRAME_MARKERS_MM]


@pytest.mark.parametrize("change, reason", [
    ({"markers_mm": [[0, 0, 0], [100, 0, 0], [200, 0, 0]]}, "one line"),
    ({"markers_mm": [[0, 0, 0], [100, 0, 0]]}, "at least 3 markers"),
    ({"labels": ["A", "A", "B", "C", "D"]}, "labels repeat"),
    ({"rotation": np.diag([1.0, 1.0, -1.0])}, "proper rotation"),
    ({"marker_diameter_mm": 0.0}, "positive"),
    ({"markers_mm": [[0, 0, 0], [5, 0, 0], [0, 100, 0]]}, "closer than a marker's diameter"),
])
def test_an_object_that_cannot_fix_the_world_is_refused_with_the_reason(change, reason):
    fields = {"name": "x", "labels": ["A", "B", "C", "D", "E"][: len(change.get("markers_mm", LFRAME_MARKERS_MM))],
              "markers_mm": LFRAME_MARKERS_MM, "marker_diameter_mm": 14.0, **change}
    with pytest.raises(ValueError, match=reason):
        ReferenceObject(**fields)


def test_a_damaged_reference_toml_is_an_input_error_naming_it(tmp_path):
    path = tmp_path / "reference.toml"
    path.write_text("[other]\nx = 1\n")
    with pytest.raises(InputError, match="reference.toml.*missing \\[reference\\] table"):
        ReferenceObject.from_toml(path)
    path.write_text('[reference]\nlabels = ["A", "B", "C"]\nmarker_diameter_mm = 14.0\n')
    with pytest.raises(InputError, match="lacks 'markers_mm'"):
        ReferenceObject.from_toml(path)
    path.write_text('[reference]\nlabels = ["A", "B", "C"]\nmarker_diameter_mm = 14.0\n'
                    'markers_mm = [[0, 0, 0], [100, 0, 0], [200, 0, 0]]\n')
    with pytest.raises(InputError, match=f"{path.name}.*one line"):
        ReferenceObject.from_toml(path)
