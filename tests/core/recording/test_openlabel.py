"""OpenLABEL cuboids (static and per frame, in a root system with per-frame camera transforms) read into the camera;
the test file is valid against the official schema."""

import json

import jsonschema
import pytest

from scpainter_blender.core.errors import InputError
from scpainter_blender.core.recording import openlabel, reader

from .recording_fixtures import assert_same, drive, openlabel_document, write_json

SCHEMA = "/work/shared/formats/openlabel_json_schema-v1.0.0.json"


def _schema():
    import os
    here = os.path.dirname(os.path.abspath(__file__))
    for path in (SCHEMA, os.path.join(here, "..", "..", "..", "..", "shared", "formats", os.path.basename(SCHEMA))):
        if os.path.isfile(path):
            return json.load(open(path))
    pytest.skip("the OpenLABEL schema is not on this machine")


def test_static_and_per_frame_cuboids_come_back_in_the_world(tmp_path):
    d = drive(3)
    doc = openlabel_document(d)
    jsonschema.validate(doc, _schema())
    path = write_json(tmp_path / "labels.json", doc)
    assert reader.detect(path) == "openlabel"
    rec = openlabel.read(path)
    assert rec.num_frames == 3 and rec.world_to_camera.shape == (3, 4, 4)
    assert [t.id for t in rec.tracks] == ["0", "1"]
    assert_same(reader.recorded_objects(rec, d["world_to_camera"], 0).objects, d["objects"], ids=["0", "1"])


def test_euler_cuboids_and_quaternion_poses_are_read(tmp_path):
    """A 9-value cuboid (Euler, R = Rz Ry Rx) in the camera system itself, the camera posed by quaternion."""
    import numpy as np

    from scpainter_blender.core.geometry import boxes, cameras
    d = drive(1)
    doc = openlabel_document(d, static_car=False)
    ol = doc["openlabel"]
    B = d["world_to_camera"][0] @ d["objects"][0]["boxes"][0]       # the car in the camera
    R = B[:3, :3] @ boxes.OBJECT_TO_BOX
    rz, ry, rx = np.arctan2(R[1, 0], R[0, 0]), np.arcsin(-R[2, 0]), np.arctan2(R[2, 1], R[2, 2])
    w, l, h = d["objects"][0]["size"]
    ol["frames"]["0"]["objects"]["0"]["object_data"]["cuboid"][0] = {
        "name": "box3d", "val": [*B[:3, 3], rx, ry, rz, l, w, h], "coordinate_system": "camera"}
    del ol["frames"]["0"]["frame_properties"]
    q = cameras.rotation_to_quaternion(d["camera_to_world"][0][:3, :3])
    ol["coordinate_systems"]["camera"]["pose_wrt_parent"] = {"quaternion": [*q[1:], q[0]],
                                                             "translation": d["camera_to_world"][0][:3, 3].tolist()}
    jsonschema.validate(doc, _schema())
    rec = openlabel.read(write_json(tmp_path / "e.json", doc))
    np.testing.assert_allclose(rec.tracks[0].boxes[0], B, atol=1e-9)
    assert_same(reader.recorded_objects(rec, d["world_to_camera"], 0).objects, d["objects"], ids=["0", "1"])


@pytest.mark.parametrize("edit, field, words", [
    (lambda ol: ol["objects"]["1"].update(type="zeppelin"), "openlabel.objects['1'].type", "class table"),
    (lambda ol: ol["frames"]["1"]["objects"]["1"]["object_data"]["cuboid"][0]["val"].__setitem__(8, 0.0),
     "openlabel.frames['1'].objects['1'].object_data.cuboid[0].val (sx, sy, sz)", "positive finite"),
    (lambda ol: ol["frames"].update({"7": {}}), "openlabel.frames['7']", "outside the recording"),
    (lambda ol: ol["coordinate_systems"]["camera"].update(type="local") or ol["coordinate_systems"].update(
        cam2=ol["coordinate_systems"].pop("camera")), "openlabel.coordinate_systems", "is not clear"),
])
def test_bad_files_name_the_field(tmp_path, edit, field, words):
    doc = openlabel_document(drive(2))
    edit(doc["openlabel"])
    path = write_json(tmp_path / "bad.json", doc)
    with pytest.raises(InputError) as e:
        openlabel.read(path)
    assert e.value.field == field and words in e.value.message


def test_rotations_are_vcds():
    """Both rotation spellings a cuboid may use mean what Vicomtech's ``vcd`` (the OpenLABEL toolkit, a test-only
    dependency) makes of them: Euler (rx, ry, rz) as ``vcd.utils.euler2R([rz, ry, rx])`` (ZYX), quaternions as
    ``q2R`` — checked on the cuboid's 8 corners, as ``generate_cuboid_points_ref_4x8`` places them."""
    import numpy as np
    from vcd import utils as vcd_utils

    from scpainter_blender.core.recording import openlabel as ol

    rng = np.random.default_rng(7)
    for _ in range(20):
        rx, ry, rz = rng.uniform(-np.pi, np.pi, 3)
        assert np.allclose(ol._euler([rz, ry, rx]), vcd_utils.euler2R([rz, ry, rx]), atol=1e-12)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        for val in ([1.0, 2.0, 3.0, rx, ry, rz, 4.2, 1.8, 1.5], [1.0, 2.0, 3.0, *q, 4.2, 1.8, 1.5]):
            box_to_cs, size, _ = ol._cuboid_box({"val": val}, "f.json", "cuboid")
            corners = vcd_utils.generate_cuboid_points_ref_4x8(val)[:3].T        # (8, 3) in the cuboid's system
            unit = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
            ours = (box_to_cs[:3, :3] @ (unit * size).T).T + box_to_cs[:3, 3]   # our box frame: x width, y length
            gap = np.linalg.norm(ours[:, None, :] - corners[None, :, :], axis=2)   # the same 8 points, any order
            assert gap.min(axis=1).max() < 1e-9 and gap.min(axis=0).max() < 1e-9
