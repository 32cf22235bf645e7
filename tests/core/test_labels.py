"""core.labels: a frame's labels from the job and its layers (geometry, recorded objects, flags, timestamps)."""

import numpy as np

from scpainter_blender.core import job as J
from scpainter_blender.core import labels
from scpainter_blender.core.geometry import boxes, cameras

K = [[100.0, 0, 80], [0, 100.0, 48], [0, 0, 1]]
W, H = 160, 96


def _w2c(centre):
    w2c = np.eye(4)
    w2c[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]      # looking along world +y
    w2c[:3, 3] = -w2c[:3, :3] @ np.asarray(centre, np.float64)
    return w2c


def _box(x, y, yaw_deg=0.0, z=0.8):
    a = np.radians(yaw_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    T[:3, 3] = [x, y, z]
    return T


def _job(frames=(1, 2, 3), fps=10.0, recorded=None, removal=()):
    d = {"schema": J.SCHEMA, "resolution": [W, H], "output_dir": "out", "fps": fps,
         "frames": [{"frame": f, "K": K, "world_to_camera": _w2c([0, f * 1.0, 1.5]).tolist()} for f in frames],
         "scene": {"predictions": "p.npz", "vggt_to_world": np.eye(4).tolist(), "recorded_frames": [1, 2],
                   "recorded_objects": recorded or [],
                   "removal_boxes": [{"box_to_world": b.tolist(), "size": [2, 5, 2]} for b in removal]},
         "assets": [{"name": "car", "ply": "car.ply", "class": "van",
                     "object_to_world": {str(f): _box(0, 12 + 2.0 * f, 0, 0).tolist() for f in frames}}]}
    return J.Job.from_dict(d)


def _labels(job, index, instance=None, hole=None, depth=None, amodal=(100,)):
    inst = np.zeros((H, W)) if instance is None else instance
    return labels.frame_labels(job, index, instance=inst, hole=np.zeros((H, W)) if hole is None else hole,
                               depth=np.full((H, W), np.inf) if depth is None else depth,
                               amodal_pixels=np.array(amodal), asset_hashes=["ab" * 32],
                               asset_boxes=[(_box(0, 0, 0, 0.79), np.array([1.8, 4.4, 1.58]), "job")])


def test_camera_and_time():
    job = _job()
    lab = _labels(job, 1)
    assert lab["schema"] == labels.SCHEMA and lab["frame"] == 2 and lab["index"] == 1
    assert lab["timestamp_s"] == 0.1 and lab["fps"] == 10.0 and lab["fps_source"] == "job"
    c = lab["camera"]
    assert np.allclose(np.array(c["world_to_camera"]) @ np.array(c["camera_to_world"]), np.eye(4))
    assert c["K"] == K and c["vggt_to_world"] == np.eye(4).tolist()
    nofps = J.Job.from_dict({k: v for k, v in job.to_dict().items() if k != "fps"})
    assert _labels(nofps, 2)["fps_source"] == "default"


def test_asset_box_in_world_and_camera_and_velocity():
    job = _job()
    o = _labels(job, 1)["objects"][0]
    assert o["track_id"] == 1 and o["class"] == "van" and o["synthetic"] and o["box_source"] == "job"
    assert o["asset"] == {"file": "car.ply", "sha256": "ab" * 32}
    assert np.allclose(o["box_world"]["center"], [0, 16, 0.79]) and np.allclose(o["box_world"]["size"],
                                                                                 [4.4, 1.8, 1.58])
    assert np.isclose(o["box_world"]["yaw"], np.pi / 2)           # front along world +y
    # camera 2 m along y at 1.5 m high, looking along +y: the car 14 m ahead, 0.71 m below the axis
    assert np.allclose(o["box_camera"]["center"], [0, 0.71, 14])
    assert np.isclose(o["box_camera"]["yaw"], -np.pi / 2)         # driving away (+z): KITTI ry = -pi/2
    assert np.allclose(o["velocity"], [0, 20.0, 0])               # 2 m per frame at 10 fps
    corners = boxes.corners(_box(0, 16, 0, 0.79), [1.8, 4.4, 1.58])
    uv = cameras.project(np.array(K), _w2c([0, 2, 1.5]), corners)[0]
    assert np.allclose(o["bbox_amodal"], [uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
    assert o["truncation"] == 0.0 and o["in_view"] and not o["camera_inside"]
    assert _labels(J.Job.from_dict({**job.to_dict(), "frames": job.to_dict()["frames"][:1]}), 0)["objects"][0][
        "velocity"] is None


def test_visible_pixels_and_occlusion_from_the_instance_pass():
    job = _job()
    inst = np.zeros((H, W))
    inst[40:50, 70:90] = 1                                          # 200 visible pixels
    o = _labels(job, 0, instance=inst, amodal=(400,))["objects"][0]
    assert o["visible_pixels"] == 200 and o["visible_fraction"] == 0.5 and o["occlusion"] == 1
    assert o["bbox_visible"] == [70.0, 40.0, 90.0, 50.0]
    assert _labels(job, 0, instance=inst, amodal=(200,))["objects"][0]["occlusion"] == 0
    assert _labels(job, 0, instance=inst, amodal=(1000,))["objects"][0]["occlusion"] == 2
    none = _labels(job, 0, amodal=(0,))["objects"][0]
    assert none["occlusion"] == 3 and none["visible_fraction"] is None and none["bbox_visible"] is None


def test_flags():
    job = _job()
    hole = np.zeros((H, W))
    hole[:60] = 1
    lab = _labels(job, 2, hole=hole)
    assert lab["coverage"] == 0.375 and lab["in_recording"] is False
    assert lab["flags"] == [labels.LOW_COVERAGE_FLAG, labels.OUTSIDE_FLAG]
    assert [w[0] for w in labels.warnings(lab)] == [labels.LOW_COVERAGE_FLAG, labels.OUTSIDE_FLAG]
    inside = J.Job.from_dict({**job.to_dict(), "assets": [{**job.to_dict()["assets"][0], "object_to_world": {
        str(f): _box(0, f * 1.0, 0, 0).tolist() for f in (1, 2, 3)}}]})
    lab = _labels(inside, 0)
    assert lab["objects"][0]["camera_inside"] and labels.CAMERA_INSIDE_FLAG in lab["flags"]
    assert any("inside the box of 'car'" in w[1] for w in labels.warnings(lab))


def test_recorded_objects_visibility_from_depth_and_removal():
    rec = [{"id": "parked", "size": [1.8, 4.4, 1.6], "boxes": {"1": _box(3, 15).tolist(), "2": _box(3, 15).tolist()}},
           {"id": "replaced", "class": "truck", "size": [2, 6, 3], "boxes": {"1": _box(-3, 20).tolist()}}]
    job = _job(recorded=rec, removal=[_box(-3, 20)])
    depth = np.full((H, W), np.inf)
    lab0 = _labels(job, 0, depth=depth)
    parked, replaced = lab0["objects"][1], lab0["objects"][2]
    assert parked["track_id"] == 2 and not parked["synthetic"] and parked["box_source"] == "recording"
    assert parked["amodal_pixels"] > 0 and parked["visible_pixels"] == 0 and parked["occlusion"] == 2
    assert replaced["removed"] and replaced["class"] == "truck" and replaced["track_id"] == 3
    assert parked["velocity"] == [0.0, 0.0, 0.0]
    # the depth layer shows a surface at the parked car's distance over its box: visible
    cam = _w2c([0, 1, 1.5])
    z = (cam @ np.append(_box(3, 15)[:3, 3], 1))[2]
    depth[:] = z
    lab = _labels(job, 0, depth=depth)
    assert lab["objects"][1]["visible_pixels"] == lab["objects"][1]["amodal_pixels"]
    assert lab["objects"][1]["occlusion"] == 0
    assert len(_labels(job, 2)["objects"]) == 1                     # frame 3: no recorded box, not labelled


def test_both_builders_write_the_fields_of_the_table_in_its_order():
    """An asset's and a recorded object's OBJECT have exactly ``OBJECT_FIELDS``' keys, in its order (the key order
    is part of the file), with values of its types; the carried measures are numbers (OpenLABEL's ``num``)."""
    rec = [{"id": "parked", "size": [1.8, 4.4, 1.6], "boxes": {"1": _box(3, 15).tolist()}}]
    lab = _labels(_job(recorded=rec), 0)
    assert [o["synthetic"] for o in lab["objects"]] == [True, False]
    python = {"int": (int,), "number": (int, float), "bool": (bool,), "string": (str,)}
    for o in lab["objects"]:
        assert list(o) == [f.name for f in labels.OBJECT_FIELDS]
        for f in labels.OBJECT_FIELDS:
            base = f.type.split("|")[0]
            if o[f.name] is None:
                assert f.nullable, f.name
            elif base in python:
                assert isinstance(o[f.name], python[base]) and (base == "bool") == isinstance(o[f.name], bool), f.name
    assert all(labels.FIELDS[n].type.split("|")[0] in ("int", "number") for n in labels.CARRIED_MEASURES)
    assert set(labels.CARRIED_IDENTITY) == {"track_id", "synthetic"}


def test_an_overflowing_transform_gives_no_geometry():
    """A transform scaled by 1e200 is a valid affine (the render draws nothing): its object is listed without a
    box, and the labels stay strict JSON."""
    import json

    d = _job().to_dict()
    d["assets"][0]["object_to_world"]["2"] = (np.diag([1e200, 1e200, 1e200, 1.0])).tolist()
    lab = _labels(J.Job.from_dict(d), 1)
    o = lab["objects"][0]
    assert o["box_world"] is None and o["bbox_amodal"] is None and not o["in_view"] and o["velocity"] is None
    json.dumps(lab, allow_nan=False)
    assert _labels(J.Job.from_dict(d), 0)["objects"][0]["velocity"] is None   # its neighbour has no box
