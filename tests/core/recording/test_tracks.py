"""The readers' shared checks and conventions."""

import numpy as np
import pytest

from scpainter_blender.core import categories
from scpainter_blender.core.errors import InputError
from scpainter_blender.core.geometry import boxes
from scpainter_blender.core.recording import tracks


def test_object_frame_boxes_turn_into_ours():
    """An object pose (x forward, y left) becomes a box whose +y is that forward axis and whose x is its right."""
    B = tracks.object_box(np.eye(4))
    np.testing.assert_allclose(B[:3, 1], [1, 0, 0])
    np.testing.assert_allclose(B[:3, 0], [0, -1, 0])
    np.testing.assert_allclose(boxes.object_pose(B, [1, 2, 3])["rotation"], np.eye(3), atol=1e-15)


@pytest.mark.parametrize("size", [[1, 2, float("nan")], [1, 0, 2], [1, -2, 2], [1, 2]])
def test_sizes_must_be_three_positive_numbers(size):
    with pytest.raises(InputError, match="positive finite") as e:
        tracks.check_size(size, "f.json", "objects[0].size")
    assert e.value.field == "objects[0].size"


def test_classes_missing_from_the_table_name_file_field_and_table():
    assert tracks.category("Van", categories.from_kitti, "l.txt", "line 1 (type)", "kitti") == "van"
    with pytest.raises(InputError, match=r"class 'Zeppelin' is not in the class table \(core/categories.py") as e:
        tracks.category("Zeppelin", categories.from_kitti, "l.txt", "line 1 (type)", "kitti")
    assert e.value.field == "line 1 (type)" and "'Car'" in e.value.message


def test_tracks_take_the_median_size_and_frames_are_checked():
    t = tracks.track(3, "car", [[1, 4, 1.5], [2, 5, 1.5], [1.1, 4.2, 1.6]], {0: np.eye(4)})
    assert t.id == "3" and t.size.tolist() == [1.1, 4.2, 1.5]
    with pytest.raises(InputError, match=r"frame 4 is outside the recording \(frames 0–3\)"):
        tracks.check_frame(4, 4, "f", "x")
    M = np.eye(4)
    M[:3, :3] *= 1.0 + 1e-5
    assert np.allclose(tracks.rigid(M.tolist(), "f", "x") [:3, :3], np.eye(3))
