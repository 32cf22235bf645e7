"""core.labels: a frame's labels from the job and its layers (geometry, recorded objects, flags, timestamps)."""

import numpy as np
import pytest

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


def test_a_removed_recorded_object_and_one_without_a_box_at_the_frame():
    rec = [{"id": "parked", "size": [1.8, 4.4, 1.6], "boxes": {"1": _box(3, 15).tolist(), "2": _box(3, 15).tolist()}},
           {"id": "replaced", "class": "truck", "size": [2, 6, 3], "boxes": {"1": _box(-3, 20).tolist()}}]
    job = _job(recorded=rec, removal=[_box(-3, 20)])
    lab0 = _labels(job, 0)
    parked, replaced = lab0["objects"][1], lab0["objects"][2]
    assert parked["track_id"] == 2 and not parked["synthetic"] and parked["box_source"] == "recording"
    assert parked["velocity"] == [0.0, 0.0, 0.0] and not parked["ignore"]
    assert replaced["removed"] and replaced["class"] == "truck" and replaced["track_id"] == 3
    assert replaced["visible_pixels"] == 0 and replaced["amodal_pixels"] > 0 and not replaced["points_missing"]
    assert labels.ignore_region(replaced) is None
    assert len(_labels(job, 2)["objects"]) == 1                     # frame 3: no recorded box, not labelled


# -- recorded objects' pixels from the layers: a synthetic frame ray-cast here -------------------------------------

#: a car of the recording in its box (1.8 x 4.4 x 1.6, box frame), seen from the side: a body over the whole
#: footprint and a narrower, shorter cabin, so its box's upper corners are empty
CAR_SIZE = np.array([1.8, 4.4, 1.6])
CAR_PARTS = [((0.0, 0.0, -0.35), (1.8, 4.4, 0.9)), ((0.0, -0.1, 0.4), (1.6, 2.2, 0.6))]   # (centre, size)
CAMERA = [0.0, 1.0, 1.5]       # frame 1 of ``_job``


def _car_box(x=1.5, y=10.0, yaw=90.0):
    return _box(x, y, yaw, 0.8)


def _raycast(shapes, w2c=None, width=W, height=H, k=K):
    """(depth (H, W) metres along the optical axis, +inf where no shape, index (H, W) of the nearest shape, -1
    where none) of ``shapes`` [(box_to_world, size)] seen by ``w2c``: each pixel centre's ray against each box."""
    w2c = _w2c(CAMERA) if w2c is None else w2c
    c2w = cameras.rigid_inverse(w2c)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    d = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(np.array(k)).T @ c2w[:3, :3].T   # world, unit depth
    best, which = np.full((height, width), np.inf), np.full((height, width), -1)
    for i, (T, size) in enumerate(shapes):
        R, t = T[:3, :3], T[:3, 3]
        o, db = (c2w[:3, 3] - t) @ R, d @ R
        with np.errstate(all="ignore"):
            a, b = (-np.asarray(size) / 2 - o) / db, (np.asarray(size) / 2 - o) / db
        t0, t1 = np.minimum(a, b).max(-1), np.maximum(a, b).min(-1)
        hit = (t0 <= t1) & (t0 > 0) & (t0 < best)
        best[hit], which[hit] = t0[hit], i
    return best, which


def _part(T, centre, size):
    P = np.eye(4)
    P[:3, 3] = centre
    return T @ P, np.array(size)


def _scene(car=True, wall_x=None, far_wall=True, T=None):
    """depth, hole, instance of the car (``T``: its box) before a far wall (y = 40), and a nearer wall hiding the
    image left of world x = ``wall_x`` (y = 5); (the car's pixels, the near wall's pixels)."""
    T = _car_box() if T is None else T
    shapes = [_part(T, c, s) for c, s in CAR_PARTS] if car else []
    if far_wall:
        shapes.append((_box(0, 40, 0, 0), np.array([200.0, 0.1, 200.0])))
    if wall_x is not None:
        shapes.append((_box(wall_x - 50, 5, 0, 0), np.array([100.0, 0.1, 100.0])))
    depth, which = _raycast(shapes)
    n_car = 2 if car else 0
    return depth, np.isinf(depth).astype(float), which < n_car if car else np.zeros_like(depth, bool), \
        which == len(shapes) - 1 if wall_x is not None else np.zeros_like(depth, bool)


def _recorded_job(T=None, **extra):
    T = _car_box() if T is None else T
    return _job(recorded=[{"id": "parked", "size": CAR_SIZE.tolist(), "boxes": {"1": T.tolist()}, **extra}])


def _recorded(job, depth, hole, instance=None):
    lab = _labels(job, 0, depth=depth, hole=hole, instance=instance)
    return lab, lab["objects"][1]


def test_a_recorded_objects_mask_is_its_points_not_its_box():
    """The car fills part of its box's silhouette: its mask is the car's pixels exactly, fully visible (occlusion 0,
    not 1 as the box's empty corners counted hidden), no holes, nothing unlabelled."""
    depth, hole, car, _ = _scene()
    lab, o = _recorded(_recorded_job(), depth, hole)
    box_pixels = boxes.polygon_mask(boxes.project_box(_car_box(), CAR_SIZE, K, _w2c(CAMERA), W, H)["polygon"], W, H)
    assert car.sum() > 500 and box_pixels.sum() > car.sum() + 100                   # the box's corners are empty
    assert o["visible_pixels"] == o["amodal_pixels"] == car.sum() and o["bbox_visible"] == labels.pixel_box(car)
    assert o["occlusion"] == 0 and o["visible_fraction"] == 1.0 and o["hole_fraction"] == 0.0
    assert not o["points_missing"] and not o["ignore"] and labels.ignore_region(o) is None
    assert lab["unlabelled_fraction"] == 0.0 and labels.UNLABELLED_FLAG not in lab["flags"]
    # the same mask pixel by pixel, from the function itself
    w2c = _w2c(CAMERA)
    proj = boxes.project_box(_car_box(), CAR_SIZE, K, w2c, W, H)
    window = boxes.polygon_window(proj["polygon"], W, H)
    origin, rays = labels.ray_frames(cameras.rigid_inverse(w2c @ _car_box()), K)
    m = labels.recorded_pixels(window, origin, rays, CAR_SIZE, labels.lateral_margin(K, proj["depth_range"][1]),
                               depth, hole > 0.5, np.zeros((H, W), bool))
    (x0, y0), inside = window
    full = np.zeros((H, W), bool)
    full[y0:y0 + inside.shape[0], x0:x0 + inside.shape[1]] = m["visible"]
    assert np.array_equal(full, car) and m["hidden"].sum() == 0 and m["holes"].sum() == 0
    assert m["empty"].sum() == box_pixels.sum() - car.sum()


def test_a_recorded_object_hidden_by_a_nearer_wall_and_by_an_inserted_asset():
    car = _scene()[2]
    depth, hole, shown, wall = _scene(wall_x=1.5)          # the wall hides the car's left part
    lab, o = _recorded(_recorded_job(), depth, hole)
    box_pixels = boxes.polygon_mask(boxes.project_box(_car_box(), CAR_SIZE, K, _w2c(CAMERA), W, H)["polygon"], W, H)
    hidden = (box_pixels & wall).sum()
    assert 0 < shown.sum() < car.sum() and o["visible_pixels"] == shown.sum()
    assert o["amodal_pixels"] == shown.sum() + hidden and o["occlusion"] == labels.occlusion_level(shown.sum(),
                                                                                                   shown.sum() + hidden)
    assert o["occlusion"] in (1, 2) and not o["points_missing"]
    # an inserted asset over the car's right part, in front of it: hidden too
    depth, hole, car, _ = _scene()
    inst = np.zeros((H, W))
    cols = np.nonzero(car.any(0))[0]
    right = cols[len(cols) // 2]
    inst[:, right:] = np.where(car[:, right:], 1, 0)
    depth = np.where(inst > 0, 6.0, depth)
    _, o = _recorded(_recorded_job(), depth, hole, inst)
    assert o["visible_pixels"] == (car & (inst == 0)).sum() and o["amodal_pixels"] == car.sum()
    assert o["occlusion"] == labels.occlusion_level(o["visible_pixels"], car.sum()) > 0


def test_a_recorded_object_whose_points_were_dropped_is_an_ignore_region():
    depth, hole, car, _ = _scene(car=False)                 # the far wall shows through the box: no car points
    job = _recorded_job()
    lab, o = _recorded(job, depth, hole)
    box_pixels = boxes.polygon_mask(boxes.project_box(_car_box(), CAR_SIZE, K, _w2c(CAMERA), W, H)["polygon"], W, H)
    assert o["points_missing"] and o["visible_pixels"] == o["amodal_pixels"] == box_pixels.sum()
    assert labels.ignore_region(o) == o["bbox_visible"] == labels.pixel_box(box_pixels)
    assert lab["unlabelled_fraction"] == box_pixels.sum() / (W * H) and labels.UNLABELLED_FLAG in lab["flags"]
    (code, message, name), = [w for w in labels.warnings(lab) if w[0] == labels.UNLABELLED_FLAG]
    assert name == "parked" and "'parked'" in message and "ignore region" in message
    # dropped as holes (nothing behind): the same, all of it holes
    depth, hole, _, _ = _scene(car=False, far_wall=False)
    _, o = _recorded(job, depth, hole)
    assert o["points_missing"] and o["hole_fraction"] == 1.0
    # wholly behind a nearer wall: hidden, not missing (labelled, occlusion 2)
    depth, hole, _, _ = _scene(car=False, wall_x=10.0)
    lab, o = _recorded(job, depth, hole)
    assert not o["points_missing"] and o["visible_pixels"] == 0 and o["occlusion"] == 2
    assert lab["unlabelled_fraction"] == 0.0 and labels.UNLABELLED_FLAG not in lab["flags"]


def test_hole_fraction_on_a_known_hole_pattern():
    depth, hole, car, _ = _scene()
    holes = car & (np.add.outer(np.arange(H), np.arange(W)) % 4 == 0)   # every fourth diagonal of the car
    depth, hole = np.where(holes, np.inf, depth), np.where(holes, 1.0, hole)
    _, o = _recorded(_recorded_job(), depth, hole)
    assert o["visible_pixels"] == (car & ~holes).sum() and o["hole_fraction"] == holes.sum() / car.sum()
    assert o["occlusion"] == 0 and not o["points_missing"]
    # an inserted asset: the share of its instance pixels that are holes (none where it wins), null when unseen
    inst = np.zeros((H, W))
    inst[40:50, 70:90] = 1
    asset = _labels(_job(), 0, instance=inst)["objects"][0]
    assert asset["hole_fraction"] == 0.0 and _labels(_job(), 0)["objects"][0]["hole_fraction"] is None
    assert not asset["ignore"] and not asset["points_missing"]


def test_an_ignored_recorded_object_shows_as_unlabelled_pixels():
    depth, hole, car, _ = _scene()
    lab, o = _recorded(_recorded_job(ignore=True), depth, hole)
    assert o["ignore"] and not o["points_missing"] and labels.ignore_region(o) == labels.pixel_box(car)
    assert lab["unlabelled_fraction"] == car.sum() / (W * H) > labels.UNLABELLED_SHARE
    assert labels.UNLABELLED_FLAG in lab["flags"]
    assert any("marked ignore" in w[1] for w in labels.warnings(lab))


def test_recorded_objects_at_once_are_each_alone():
    """The batched geometry (``_recorded_geometry``) gives each object the numbers it gets alone."""
    depth, hole, _, _ = _scene()
    rec = [{"id": f"r{i}", "size": CAR_SIZE.tolist(), "boxes": {"1": _car_box(x, y, yaw).tolist()}}
           for i, (x, y, yaw) in enumerate([(1.5, 10, 90), (-2, 14, 30), (4, 25, 0), (0, -5, 0)])]
    together = _recorded(_job(recorded=rec), depth, hole)[0]["objects"][1:]
    for i, r in enumerate(rec):
        alone = _recorded(_job(recorded=[r]), depth, hole)[1]
        assert {**alone, "track_id": 0} == {**together[i], "track_id": 0}


def test_extreme_recorded_boxes_and_layers():
    import json

    depth, hole, car, _ = _scene()
    # a box behind the camera: not in view, no pixels, not missing
    _, o = _recorded(_recorded_job(_car_box(1.5, -10)), depth, hole)
    assert not o["in_view"] and o["visible_pixels"] == o["amodal_pixels"] == 0 and not o["points_missing"]
    assert labels.ignore_region(o) is None and o["hole_fraction"] is None
    # the camera inside the box, points all around: flagged, not missing
    big = np.eye(4)
    big[:3, 3] = CAMERA
    lab = _labels(_job(recorded=[{"id": "around", "size": [100, 90, 100], "boxes": {"1": big.tolist()}}]), 0,
                  depth=depth, hole=hole)
    o = lab["objects"][1]
    assert o["camera_inside"] and labels.CAMERA_INSIDE_FLAG in lab["flags"] and not o["points_missing"]
    assert o["visible_pixels"] == (hole < 0.5).sum() and o["occlusion"] == 0
    # everything 1e5 m away from the origin: the same pixels
    shift = np.eye(4)
    shift[:3, 3] = [1e5, -1e5, 0.0]
    far = _job(recorded=[{"id": "parked", "size": CAR_SIZE.tolist(), "boxes": {"1": (shift @ _car_box()).tolist()}}])
    d = far.to_dict()
    for f in d["frames"]:
        f["world_to_camera"] = (np.array(f["world_to_camera"]) @ np.linalg.inv(shift)).tolist()
    _, o_far = _recorded(J.Job.from_dict(d), depth, hole)
    _, o = _recorded(_recorded_job(), depth, hole)
    assert {k: o_far[k] for k in ("visible_pixels", "amodal_pixels", "bbox_visible", "occlusion")} == \
        {k: o[k] for k in ("visible_pixels", "amodal_pixels", "bbox_visible", "occlusion")}
    # NaN depth rows count nowhere; the labels stay strict JSON
    rows = np.nonzero(car.any(1))[0]
    nan = depth.copy()
    nan[rows[::2]] = np.nan
    lab, o = _recorded(_recorded_job(), nan, hole)
    assert o["visible_pixels"] == (car & ~np.isnan(nan)).sum() and o["occlusion"] == 0
    json.dumps(lab, allow_nan=False)
    # a row of rays parallel to the box's top and bottom faces (principal point on a pixel centre): the same
    # pixels, no warning
    import warnings

    k2 = np.array(K)
    k2[1, 2] = 48.5
    d2, which = _raycast([_part(_car_box(), c, sz) for c, sz in CAR_PARTS] + [(_box(0, 40, 0, 0), [200, 0.1, 200])],
                         k=k2)
    proj = boxes.project_box(_car_box(), CAR_SIZE, k2, _w2c(CAMERA), W, H)
    origin, rays = labels.ray_frames(cameras.rigid_inverse(_w2c(CAMERA) @ _car_box()), k2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = labels.recorded_pixels(boxes.polygon_window(proj["polygon"], W, H), origin, rays, CAR_SIZE,
                                   labels.lateral_margin(k2, proj["depth_range"][1]), d2, np.isinf(d2),
                                   np.zeros((H, W), bool))
    assert m["visible"].sum() == (which < 2).sum()
    # an empty scene: every pixel a hole, nothing recorded
    lab = _labels(_job(), 0, hole=np.ones((H, W)))
    assert lab["unlabelled_fraction"] == 0.0 and lab["coverage"] == 0.0 and len(lab["objects"]) == 1


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
    """A transform scaled by 1e200 is refused by a job file (issue 42: ``fields.MAX_MATRIX_ENTRY``, by name); one
    made in code still labels: its object is listed without a box, and the labels stay strict JSON."""
    import json

    from scpainter_blender.core import fields

    d = _job().to_dict()
    huge = np.diag([1e200, 1e200, 1e200, 1.0])
    d["assets"][0]["object_to_world"]["2"] = huge.tolist()
    with pytest.raises(J.JobError) as e:
        J.Job.from_dict(d)
    assert e.value.field == "assets[0].object_to_world['2']" and f"{fields.MAX_MATRIX_ENTRY:g}" in e.value.message
    job = _job()
    job.assets[0].object_to_world[2] = huge
    lab = _labels(job, 1)
    o = lab["objects"][0]
    assert o["box_world"] is None and o["bbox_amodal"] is None and not o["in_view"] and o["velocity"] is None
    json.dumps(lab, allow_nan=False)
    assert _labels(job, 0)["objects"][0]["velocity"] is None   # its neighbour has no box
