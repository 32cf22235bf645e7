"""Our plain objects file (scpainter.objects/1), in the camera or the world frame."""

import numpy as np
import pytest

from scpainter_blender.core import files
from scpainter_blender.core.errors import InputError
from scpainter_blender.core.recording import plain, reader

from .recording_fixtures import assert_same, drive, write_json


def _camera_objects(d):
    return [{**o, "boxes": {f: d["world_to_camera"][f] @ B for f, B in o["boxes"].items()}} for o in d["objects"]]


@pytest.mark.parametrize("frame", ["camera", "world"])
def test_both_frames_come_back_in_the_world(tmp_path, frame):
    d = drive(3)
    doc = plain.document(3, d["objects"], d["world_to_camera"]) if frame == "world" else \
        plain.document(3, _camera_objects(d))
    path = write_json(tmp_path / "objects.json", doc)
    assert reader.detect(path) == "plain" and files.read_json(path)["frame"] == frame
    rec = plain.read(path)
    assert (rec.world_to_camera is None) == (frame == "camera")
    assert_same(reader.recorded_objects(rec, d["world_to_camera"], 3).objects, d["objects"], frame_start=3)


def test_a_scale_off_reconstruction_is_a_warning(tmp_path):
    d = drive(3)
    path = write_json(tmp_path / "o.json", plain.document(3, d["objects"], d["world_to_camera"]))
    w2c = d["world_to_camera"].copy()
    w2c[:, :3, 3] *= 1.2
    assert "off by +20 %" in reader.recorded_objects(plain.read(path), w2c, 0).warnings[0]


@pytest.mark.parametrize("edit, field, words", [
    (lambda d: d.update(num_frames=2), "objects[0].boxes['2']", "outside the recording"),
    (lambda d: d["objects"][0].update(size=[1.8, 0.0, 1.5]), "objects[0].size", "positive finite"),
    (lambda d: d["objects"][1].update({"class": "unicorn"}), "objects[1].class", "class table"),
    (lambda d: d["objects"][1].update(id="car-a"), "objects[1].id", "unique"),
    (lambda d: d.update(frame="ego"), "frame", "one of"),
    (lambda d: d["objects"][0]["boxes"]["0"][0].__setitem__(0, 2.0), "objects[0].boxes['0']", "not a rigid"),
])
def test_bad_files_name_the_field(tmp_path, edit, field, words):
    d = drive(3)
    doc = plain.document(3, _camera_objects(d))
    edit(doc)
    with pytest.raises(InputError) as e:
        plain.read(write_json(tmp_path / "o.json", doc))
    assert e.value.field == field and words in e.value.message


def test_nan_is_refused_by_the_json_reader(tmp_path):
    d = drive(1)
    p = tmp_path / "o.json"
    p.write_text(write_json(tmp_path / "x.json", plain.document(1, _camera_objects(d))) and
                 (tmp_path / "x.json").read_text().replace("1.8", "NaN", 1))
    with pytest.raises(InputError, match="NaN"):
        plain.read(str(p))
    assert np.isfinite(plain.read(str(tmp_path / "x.json")).tracks[0].size).all()
