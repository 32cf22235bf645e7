"""scene/recording_rig.py: the rig stored with a multi-camera import read back (the import itself:
tests/scene/test_importer.py::test_multi_camera_recording)."""

import json

import bpy
import numpy as np
import pytest

from scpainter_blender.core import rig as R
from scpainter_blender.core.errors import InputError
from scpainter_blender.scene import keys, kinds, recording_rig


def _points(name):
    obj = bpy.data.objects.new(name, bpy.data.meshes.new(name))
    bpy.context.scene.collection.objects.link(obj)
    kinds.mark(obj, kinds.POINTS)
    return obj


def test_stored_rig_read_back_or_none_or_refused(empty_scene):
    scene = empty_scene
    assert recording_rig.recording_rig(scene) is None           # no import
    single = _points("single points")                           # a single-camera import: no rig
    assert recording_rig.recording_rig(scene) is None
    stored = R.preset("nuscenes", lidar=False, scale=0.1)
    multi = _points("multi points")
    multi[keys.RECORDING_RIG] = json.dumps({**stored.to_dict(), "name": "recording"})
    got = recording_rig.recording_rig(scene)
    assert got.name == "recording" and got.sensor_names == list(R.NUSCENES_CAMERAS)
    np.testing.assert_allclose(got.camera("CAM_BACK").camera_to_ego, stored.camera("CAM_BACK").camera_to_ego)
    assert recording_rig.recording_rig(scene, single) is None   # that object's own
    multi[keys.RECORDING_RIG] = "{not json"
    with pytest.raises(InputError) as e:
        recording_rig.recording_rig(scene)
    assert e.value.path == "(object 'multi points')" and e.value.field == keys.RECORDING_RIG
    d = stored.to_dict()
    d["cameras"][1]["name"] = "CAM_FRONT"
    multi[keys.RECORDING_RIG] = json.dumps(d)
    with pytest.raises(InputError, match="two sensors with one name") as e:
        recording_rig.recording_rig(scene)
    assert e.value.field == f"{keys.RECORDING_RIG}.cameras[1].name"
