"""A nuScenes scene (the devkit's tables, two samples) read into CAM_FRONT and mapped back onto the drive."""

import json
import os

import pytest

from scpainter_blender.core.errors import InputError
from scpainter_blender.core.recording import nuscenes, reader

from .recording_fixtures import assert_same, drive, write_nuscenes


def test_two_samples_come_back_in_the_world(tmp_path):
    d = drive(2)
    folder = write_nuscenes(str(tmp_path / "v1.0-mini"), d)
    rec = nuscenes.read(folder, "scene-0001")
    assert rec.num_frames == 2 and rec.world_to_camera.shape == (2, 4, 4)
    assert_same(reader.recorded_objects(rec, d["world_to_camera"], 1).objects, d["objects"], frame_start=1)
    assert reader.detect(folder) == "nuscenes" == reader.detect(os.path.join(folder, "scene.json"))
    assert nuscenes.read(os.path.join(folder, "sample.json"), "scene-1").num_frames == 2  # by token, from a table


def test_scene_camera_and_class_problems_name_the_table(tmp_path):
    d = drive(2)
    folder = write_nuscenes(str(tmp_path), d, extra_category="vehicle.hovercraft")
    with pytest.raises(InputError, match=r"2 scenes among \['scene-0001', 'scene-0002'\]") as e:
        nuscenes.read(folder)
    assert e.value.path.endswith("scene.json")
    with pytest.raises(InputError, match="no CAM_BACK keyframe image"):
        nuscenes.read(folder, "scene-0001", "CAM_BACK")
    rows = json.load(open(os.path.join(folder, "instance.json")))
    rows[0]["category_token"] = "cat-extra"
    json.dump(rows, open(os.path.join(folder, "instance.json"), "w"))
    with pytest.raises(InputError) as e:
        nuscenes.read(folder, "scene-0001")
    assert e.value.path.endswith("category.json") and e.value.field == "category 'cat-extra'.name"
    assert "'vehicle.hovercraft' is not in the class table (core/categories.py CATEGORIES" in e.value.message


def test_unlabelled_devkit_classes_become_ignore_regions_and_bad_sizes_are_refused(tmp_path):
    d = drive(2)
    folder = write_nuscenes(str(tmp_path), d, extra_category="animal")
    rows = json.load(open(os.path.join(folder, "instance.json")))
    rows[1]["category_token"] = "cat-extra"
    json.dump(rows, open(os.path.join(folder, "instance.json"), "w"))
    walker = {t.id: t for t in nuscenes.read(folder, "scene-0001").tracks}["ped-b"]
    assert walker.ignore and walker.category == nuscenes.NOT_LABELLED_CLASS
    anns = json.load(open(os.path.join(folder, "sample_annotation.json")))
    anns[1]["size"] = [1.8, 0.0, 1.5]
    json.dump(anns, open(os.path.join(folder, "sample_annotation.json"), "w"))
    with pytest.raises(InputError) as e:
        nuscenes.read(folder, "scene-0001")
    assert e.value.field == "sample_annotation 'ann-0-1'.size" and "positive finite" in e.value.message


def test_a_recording_of_another_length_or_order_is_refused(tmp_path):
    d = drive(3)
    rec = nuscenes.read(write_nuscenes(str(tmp_path), d), "scene-0001")
    with pytest.raises(InputError, match="the recording has 3 frames, the reconstruction 2"):
        reader.recorded_objects(rec, d["world_to_camera"][:2], 1)
    with pytest.raises(InputError, match="camera path does not match"):
        reader.recorded_objects(rec, d["world_to_camera"][::-1], 1)
