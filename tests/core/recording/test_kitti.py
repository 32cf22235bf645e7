"""KITTI tracking labels (label_02 + calib) read into image_02's camera and mapped back onto the drive."""

import numpy as np
import pytest

from scpainter_blender.core.errors import InputError
from scpainter_blender.core.geometry import boxes
from scpainter_blender.core.recording import kitti, reader

from .recording_fixtures import T2, assert_same, drive, write_kitti


def test_a_tracking_sequence_comes_back_in_the_world(tmp_path):
    d = drive(3)
    path = write_kitti(str(tmp_path), d)
    rec = kitti.read(path)
    assert rec.format == "kitti" and rec.num_frames is None  # KITTI files list only frames with objects
    assert [t.id for t in rec.tracks] == ["0", "1"]           # DontCare lines left out
    mapped = reader.recorded_objects(rec, d["world_to_camera"], 5)
    assert_same(mapped.objects, d["objects"], frame_start=5, atol=1e-6, ids=["0", "1"])


def test_the_box_convention_matches_the_exports_rotation_y(tmp_path):
    """The yaw read back is the one boxes.rotation_y (the KITTI export's) writes: one convention both ways."""
    d = drive(1)
    rec = kitti.read(write_kitti(str(tmp_path), d))
    B = rec.tracks[0].boxes[0]
    line = open(tmp_path / "label_02" / "0000.txt").read().split("\n")[0].split()
    assert boxes.rotation_y(B[:3, :3] @ boxes.OBJECT_TO_BOX) == pytest.approx(float(line[16]), abs=1e-9)
    np.testing.assert_allclose(kitti.camera_offset(str(tmp_path / "calib" / "0000.txt")), T2, atol=1e-12)


@pytest.mark.parametrize("line, field, words", [
    ("0 7 Car 0 0 0 1 1 2 2 nan 1.8 4.4 1 1.6 10 0", "line 7 (height width length)", "positive finite"),
    ("0 7 Car 0 0 0 1 1 2 2 1.5 0 4.4 1 1.6 10 0", "line 7 (height width length)", "positive finite"),
    ("0 7 Tractor 0 0 0 1 1 2 2 1.5 1.8 4.4 1 1.6 10 0", "line 7 (type)", "class table"),
    ("-1 7 Car 0 0 0 1 1 2 2 1.5 1.8 4.4 1 1.6 10 0", "line 7 (frame)", "outside the recording"),
    ("0 7 Car 0 0", "line 7", "expected 17 fields"),
])
def test_bad_lines_name_the_file_and_line(tmp_path, line, field, words):
    path = write_kitti(str(tmp_path), drive(2), extra_lines=[line])
    with pytest.raises(InputError) as e:
        kitti.read(path)
    assert e.value.field == field and words in e.value.message and e.value.path == path


def test_a_frame_beyond_the_reconstruction_and_a_missing_calib_are_refused(tmp_path):
    d = drive(3)
    path = write_kitti(str(tmp_path), d)
    with pytest.raises(InputError, match=r"track '0': is in frame 2, outside the reconstruction's 2 frames"):
        reader.recorded_objects(kitti.read(path), d["world_to_camera"][:2], 1)
    (tmp_path / "calib" / "0000.txt").unlink()
    with pytest.raises(InputError, match="calibration is missing"):
        kitti.read(path)
