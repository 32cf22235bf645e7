"""OpenLABEL export: valid against the official ASAM OpenLABEL 1.0 schema (jsonschema, draft-07); loaded by
Vicomtech's ``vcd`` 6.0.3 (a test-only tool), whose scene evaluates the camera's transform chain; boxes, camera,
intrinsics and ignore regions round-trip."""

import json
import os

import jsonschema
import numpy as np
import pytest

from tests.backend.export import export_fixtures as F
from backend.export import common, openlabel
from scpainter_blender.core import labels
from scpainter_blender.core.geometry import boxes, cameras

#: The official schema (Vicomtech's snapshot, MIT; README.md beside this file says where from).
SCHEMA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "openlabel_json_schema-v1.0.0.json")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out, frames, counts = F.write_dataset(tmp_path_factory, openlabel, "openlabel")
    return out, frames, counts, json.loads((out / "openlabel.json").read_text())["openlabel"]


def test_valid_against_the_official_schema(exported):
    out, _, _, doc = exported
    schema = json.load(open(SCHEMA, encoding="utf-8"))
    jsonschema.Draft7Validator.check_schema(schema)
    errors = list(jsonschema.Draft7Validator(schema).iter_errors({"openlabel": doc}))
    assert not errors, [e.message for e in errors[:5]]
    # and the validator does refuse a broken document (the check is not vacuous)
    broken = json.loads(json.dumps({"openlabel": doc}))
    broken["openlabel"]["metadata"]["schema_version"] = "0.9"
    assert list(jsonschema.Draft7Validator(schema).iter_errors(broken))


def test_cuboid_of_a_known_box_round_trips(exported):
    _, frames, counts, doc = exported
    j = F.job()
    assert counts == {"frames": 2, "objects": 6, "ignore_regions": 2}
    for i, entry in enumerate(j.frames):
        fo = doc["frames"][str(i)]["objects"]
        for a, asset in enumerate(j.assets):
            bw, size = labels.asset_box_to_world(asset, F.CAR, entry.frame)
            (cub,) = fo[str(a + 1)]["object_data"]["cuboid"]
            assert cub["coordinate_system"] == "odom" and len(cub["val"]) == 10
            x, y, z, qx, qy, qz, qw, sx, sy, sz = cub["val"]
            R = cameras.quaternion_to_rotation([qw, qx, qy, qz])      # object frame: x forward, y left, z up
            corners = (np.array([[i_, j_, k_] for i_ in (-.5, .5) for j_ in (-.5, .5) for k_ in (-.5, .5)])
                       * [sx, sy, sz]) @ R.T + [x, y, z]
            truth = boxes.corners(bw, size)
            assert np.allclose(np.sort(corners, axis=0), np.sort(truth, axis=0), atol=1e-9)
            assert (sx, sy, sz) == pytest.approx((size[1], size[0], size[2]))   # length, width, height
            fwd = bw[:3, 1]                                                   # the box's front: +y of its frame
            assert R[:, 0] == pytest.approx(fwd)
    assert doc["objects"]["1"] == {"name": "car_a", "type": "car", "frame_intervals": [{"frame_start": 0,
                                                                                         "frame_end": 1}],
                                   "object_data": {"boolean": [{"name": "synthetic", "val": True}]}}
    assert doc["objects"]["3"]["type"] == "van" and doc["objects"]["3"]["object_data"]["boolean"][0]["val"] is False


def test_camera_pose_intrinsics_and_boxes(exported):
    _, frames, _, doc = exported
    cs = doc["coordinate_systems"]
    assert cs["odom"]["parent"] == "" and cs["camera"]["parent"] == "odom"
    assert cs["odom"]["children"] == ["camera"] and cs["camera"]["children"] == []
    for i, fr in enumerate(frames):
        w2c = np.asarray(fr.labels["camera"]["world_to_camera"])
        props = doc["frames"][str(i)]["frame_properties"]
        assert props["timestamp"] == fr.labels["timestamp_s"] and props["scene_frame"] == fr.labels["frame"]
        assert props["streams"]["camera"]["uri"] == f"images/00000{i}.png"
        t = props["transforms"]["camera_to_odom"]
        assert (t["src"], t["dst"]) == ("camera", "odom")
        M = np.array(t["transform_src_to_dst"]["matrix4x4"]).reshape(4, 4)   # X_odom = M X_camera
        assert np.allclose(M @ w2c, np.eye(4), atol=1e-12)
        if i == 0:
            assert np.array_equal(np.array(cs["camera"]["pose_wrt_parent"]["matrix4x4"]).reshape(4, 4), M)
        # a world point through the stream's camera_matrix: our projection, in OpenCV's pixel convention
        pin = doc["streams"]["camera"]["stream_properties"]["intrinsics_pinhole"]
        assert (pin["width_px"], pin["height_px"]) == (F.W, F.H) and pin["distortion_coeffs"] == [0.0] * 5
        P = np.array(pin["camera_matrix_3x4"]).reshape(3, 4)
        X = np.array([1.0, 12.0, 0.4, 1.0])
        u = P @ np.linalg.inv(M) @ X
        ours = cameras.project(fr.labels["camera"]["K"], w2c, X[None, :3])
        ours = np.asarray(ours[0] if isinstance(ours, tuple) else ours).reshape(-1)[:2]
        assert u[:2] / u[2] == pytest.approx(ours - common.OPENCV_SHIFT)
        for o in fr.labels["objects"]:
            if o["ignore"]:
                continue
            data = doc["frames"][str(i)]["objects"][str(o["track_id"])]["object_data"]
            vis = next(b for b in data["bbox"] if b["name"] == "visible")
            x0, y0, x1, y1 = o["bbox_visible"]
            assert vis["coordinate_system"] == "camera"
            assert vis["val"] == pytest.approx([(x0 + x1) / 2 - 0.5, (y0 + y1) / 2 - 0.5, x1 - x0, y1 - y0])
            nums = {n["name"]: n["val"] for n in data["num"]}
            assert nums == {"visible_fraction": o["visible_fraction"], "occlusion": o["occlusion"],
                            "truncation": o["truncation"], "hole_fraction": o["hole_fraction"]}


def test_intervals():
    assert openlabel.intervals([0, 1, 2, 5, 7, 8]) == [{"frame_start": 0, "frame_end": 2},
                                                       {"frame_start": 5, "frame_end": 5},
                                                       {"frame_start": 7, "frame_end": 8}]


def test_ignore_regions_are_objects_of_type_ignore(exported):
    _, frames, _, doc = exported
    offset = openlabel.ignore_key_offset(frames)
    assert offset == 4
    for i, fr in enumerate(frames):
        (o,) = [o for o in fr.labels["objects"] if o["ignore"]]
        assert str(o["track_id"]) not in doc["frames"][str(i)]["objects"]        # never a normal label
        key = str(o["track_id"] + offset)
        data = doc["frames"][str(i)]["objects"][key]["object_data"]
        assert {n["name"]: n["val"] for n in data["num"]}["occlusion"] == o["occlusion"]
        (box,) = data["bbox"]
        assert (box["name"], box["coordinate_system"]) == ("region", "camera")
        assert box["val"] == pytest.approx(openlabel.bbox_val(labels.ignore_region(o)))
    assert doc["objects"][str(4 + offset)] == {
        "name": "rec_8", "type": "ignore", "frame_intervals": [{"frame_start": 0, "frame_end": 1}],
        "object_data": {"text": [{"name": "class", "val": "car"}], "num": [{"name": "track_id", "val": 4}]}}


def test_vcd_loads_it_and_evaluates_the_transform_chain(tmp_path):
    """``vcd.core.OpenLABEL`` loads the file (validating it against the schema it ships) and ``vcd.scl.Scene``'s
    ``get_transform`` between ``camera`` and ``odom`` at each frame gives our camera_to_world and world_to_camera,
    for a tilted camera; the ignore region reads back as an object of type ignore."""
    from vcd import core as vcd_core
    from vcd import scl

    frames = F.export_frames(tmp_path, [F.tilted_camera(0.1 * i) for i in range(len(F.FRAMES))])
    out = tmp_path / "d"
    out.mkdir()
    openlabel.write(str(out), frames)
    doc = vcd_core.OpenLABEL()
    doc.load_from_file(str(out / "openlabel.json"), validation=True)
    scene = scl.Scene(doc)
    for i, fr in enumerate(frames):
        to_world, static = scene.get_transform("camera", "odom", frame_num=i)
        assert not static and np.allclose(to_world, fr.labels["camera"]["camera_to_world"], atol=1e-12)
        to_camera, _ = scene.get_transform("odom", "camera", frame_num=i)
        assert np.allclose(to_camera, fr.labels["camera"]["world_to_camera"], atol=1e-12)
    key = str(4 + openlabel.ignore_key_offset(frames))
    assert doc.get_object(key)["type"] == "ignore"
    (o,) = [o for o in frames[1].labels["objects"] if o["ignore"]]
    assert doc.get_object_data(key, "region", 1)["val"] == pytest.approx(openlabel.bbox_val(o["bbox_visible"]))
    # the check is not vacuous: without the leaf's children list vcd cannot chain the transforms
    raw = json.loads((out / "openlabel.json").read_text())
    del raw["openlabel"]["coordinate_systems"]["camera"]["children"]
    (out / "old.json").write_text(json.dumps(raw))
    old = vcd_core.OpenLABEL()
    old.load_from_file(str(out / "old.json"))
    with pytest.raises(KeyError, match="children"):
        scl.Scene(old).get_transform("camera", "odom", frame_num=0)
