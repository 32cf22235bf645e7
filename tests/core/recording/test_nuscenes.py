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
    assert e.value.path.endswith("scene.json") and "--objects-scene" in e.value.hint
    with pytest.raises(InputError, match="no scene 'scene-9'") as e:   # the sensors command's option is --scene
        nuscenes.sensors(folder, "scene-9")
    assert "--scene)" in e.value.hint and "--objects-scene" not in e.value.hint
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


def test_sensors_sidecar_from_the_tables(tmp_path):
    """The sidecar of VGGT run on a scene's keyframe images of two cameras: sample-major, channels in nuScenes'
    order, sample_data timestamps, calibrated sensors and image sizes; a channel missing is refused by name."""
    import numpy as np

    from scpainter_blender.core.errors import InputError as Bad
    from scpainter_blender.core.vggt import sensors as S

    from .recording_fixtures import CAMERA_TO_EGO, EXTRA_CAMERAS

    d = drive(3)
    folder = write_nuscenes(str(tmp_path / "v1.0-mini"), d, extra_cameras=("CAM_BACK",))
    read = nuscenes.sensors(folder, "scene-0001")
    s, images = read.sensors, read.images
    assert s.sensor == ["CAM_FRONT", "CAM_BACK"] * 3 and s.reference == "CAM_FRONT"
    assert list(s.timestamp_us) == [1_000_005, 1_007_000, 1_500_005, 1_507_000, 2_000_005, 2_007_000]
    assert images[:2] == ["samples/CAM_FRONT/sd-cam-0.jpg", "samples/CAM_BACK/0.jpg"]
    np.testing.assert_allclose(s.info["CAM_FRONT"].camera_to_ego, CAMERA_TO_EGO, atol=1e-12)
    np.testing.assert_allclose(s.info["CAM_BACK"].camera_to_ego, EXTRA_CAMERAS["CAM_BACK"], atol=1e-12)
    assert s.info["CAM_FRONT"].resolution == (1600, 900) and s.info["CAM_BACK"].resolution == (800, 450)
    # the cameras' poses in the global frame: a metric trajectory of the frames
    from scpainter_blender.core.geometry import cameras as C
    for i in range(3):
        np.testing.assert_allclose(read.world_to_camera[2 * i], d["world_to_camera"][i], atol=1e-9)
        ego = d["camera_to_world"][i] @ C.rigid_inverse(CAMERA_TO_EGO)
        np.testing.assert_allclose(read.world_to_camera[2 * i + 1],
                                   C.rigid_inverse(ego @ EXTRA_CAMERAS["CAM_BACK"]), atol=1e-9)
    S.write(tmp_path / "p.sensors.json", s)
    assert S.read(tmp_path / "p.sensors.json").sensor == s.sensor
    # the order VGGT was given: the channels named; no calibration
    s = nuscenes.sensors(folder, "scene-0001", ["CAM_BACK", "CAM_FRONT"], calibration=False).sensors
    assert s.sensor[:2] == ["CAM_BACK", "CAM_FRONT"] and s.info == {}
    with pytest.raises(Bad) as e:
        nuscenes.sensors(folder, "scene-0001", ["CAM_FRONT", "CAM_FRONT_LEFT"])
    assert e.value.path.endswith("sample_data.json") and "no CAM_FRONT_LEFT keyframe image for sample" in e.value.message
