"""Labels from a real render: three cars — one partly hiding another, one cut by the image's border — rendered by
``python -m backend render``, their labels checked against the known placement (issue 27's acceptance test)."""

import os

import cv2
import numpy as np
import pytest

from backend.render import channels
from scpainter_blender.core import files, labels, outputs, shapes
from scpainter_blender.core import job as J
from scpainter_blender.core.geometry import boxes, cameras
from scpainter_blender.core.output_layout import OutputLayout
from scpainter_blender.core.splats import trellis
from tests.tests_support import run_backend_here as backend

W, H = 192, 112
K = [[110.0, 0, 96], [0, 110.0, 56], [0, 0, 1]]
#: the procedural car's true box in its own frame (Z up, front +y, on z = 0): chassis 1.8 x 4.4, wheels 2 cm out
CAR_BOX = (np.array([0.0, 0.0, 0.79]), np.array([1.84, 4.4, 1.58]))
CARS = {"front": ((0.8, 11.0), 90.0), "behind": ((-2.5, 17.0), 0.0), "border": ((9.0, 12.0), 10.0)}


def _placement(xy, yaw_deg):
    a = np.radians(yaw_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    T[:3, 3] = [xy[0], xy[1], 0.0]
    return T


def _w2c(centre):
    w2c = np.eye(4)
    w2c[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]      # looking along world +y
    w2c[:3, 3] = -w2c[:3, :3] @ np.asarray(centre, np.float64)
    return w2c


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("labels")
    car_to_file = shapes.save_as_amodal3r(str(tmp / "car.ply"), shapes.procedural_car_gaussians(count=20000, seed=4))
    s = np.cbrt(np.linalg.det(car_to_file[:3, :3]))
    # the first car's box given in the job (in file units), the others estimated by the render
    box_to_file = np.eye(4)
    box_to_file[:3, :3] = trellis.ZUP_TO_TRELLIS_FILE
    box_to_file[:3, 3] = car_to_file[:3, :3] @ CAR_BOX[0] + car_to_file[:3, 3]
    frames = (1, 2)
    assets = []
    for name, (xy, yaw) in CARS.items():
        a = {"name": name, "ply": "car.ply", "object_to_world": {
            str(f): (_placement((xy[0], xy[1] + 0.5 * (f - 1)), yaw) @ np.linalg.inv(car_to_file)).tolist()
            for f in frames}}
        if name == "front":
            a["box"] = {"box_to_file": box_to_file.tolist(), "size": (s * CAR_BOX[1]).tolist()}
        assets.append(a)
    job = {"schema": J.SCHEMA, "resolution": [W, H], "fps": 10.0, "output_dir": "out", "assets": assets,
           "frames": [{"frame": f, "K": K, "world_to_camera": _w2c([0, 0, 1.5]).tolist()} for f in frames]}
    J.save(tmp / "job.json", job)
    code, ev, err = backend("render", tmp / "job.json", "--device", "cpu")
    assert code == 0, err
    layout = OutputLayout(tmp / "out")
    return tmp, ev, [files.read_json(layout.frame_labels(f)) for f in frames], layout


def _by_name(lab):
    return {o["name"]: o for o in lab["objects"]}


def test_ids_and_visibility(rendered):
    tmp, _, labs, layout = rendered
    layers = channels.read(layout.condition_exr(1))
    ids = layers[channels.INSTANCE]
    objs = _by_name(labs[0])
    for i, name in enumerate(CARS, start=1):
        assert objs[name]["track_id"] == i and objs[name]["visible_pixels"] == int((ids == i).sum()) > 0
    # the instance pass is where each car's weight beats what lies behind it: within the asset mask's > 0.5
    assert np.all(layers[channels.ASSET_MASK][ids > 0] > 0.5 - 1e-6)
    front, behind, border = objs["front"], objs["behind"], objs["border"]
    assert front["visible_fraction"] == 1.0 and front["occlusion"] == 0 and front["truncation"] == 0.0
    assert 0.1 < behind["visible_fraction"] < 0.9 and behind["occlusion"] in (1, 2) and behind["truncation"] == 0.0
    assert border["truncation"] > 0.1 and border["bbox_amodal"][2] == W and border["visible_fraction"] > 0.9
    assert all(o["synthetic"] and o["class"] == "car" for o in objs.values())
    assert labs[0]["flags"] == [labels.LOW_COVERAGE_FLAG]        # no scene: the cars cover a fraction
    assert np.isclose(labs[0]["coverage"], 1 - layers[channels.HOLE].mean())


def test_boxes_against_the_known_placement(rendered):
    _, _, labs, _ = rendered
    for lab in labs:
        f = lab["frame"]
        objs = _by_name(lab)
        for name, (xy, yaw) in CARS.items():
            o = objs[name]
            T = _placement((xy[0], xy[1] + 0.5 * (f - 1)), yaw)
            true_centre = T[:3, :3] @ CAR_BOX[0] + T[:3, 3]
            tol = 1e-6 if name == "front" else 0.05
            assert o["box_source"] == ("job" if name == "front" else "estimated")
            assert np.allclose(o["box_world"]["center"], true_centre, atol=tol)
            assert np.allclose(o["box_world"]["size"], CAR_BOX[1][[1, 0, 2]], atol=tol)
            dyaw = np.angle(np.exp(1j * (o["box_world"]["yaw"] - np.radians(yaw + 90))))   # front = car's +y
            assert abs(np.degrees(dyaw)) <= (1e-6 if name == "front" else 1.0)
            assert np.allclose(o["velocity"], [0, 5.0, 0], atol=1e-6)                         # 0.5 m/frame, 10 fps
            # the 2D box is the projected 3D box's corners, clipped to the image
            w2c = np.array(lab["camera"]["world_to_camera"])
            Tb = np.eye(4)
            Tb[:3, :3] = cameras.quaternion_to_rotation(o["box_world"]["quaternion"]) @ boxes.OBJECT_TO_BOX.T
            Tb[:3, 3] = o["box_world"]["center"]
            l, w, h = o["box_world"]["size"]
            uv = cameras.project(np.array(K), w2c, boxes.corners(Tb, [w, l, h]))[0]
            expect = [max(uv[:, 0].min(), 0), max(uv[:, 1].min(), 0), min(uv[:, 0].max(), W), min(uv[:, 1].max(), H)]
            assert np.allclose(o["bbox_amodal"], expect, atol=1e-6)
            vis = o["bbox_visible"]
            assert vis[0] >= np.floor(expect[0]) - 1 and vis[2] <= np.ceil(expect[2]) + 1


def test_files_events_and_resume(rendered):
    tmp, ev, labs, layout = rendered
    kinds = [e.get("kind") for e in ev if e.get("event") == "artifact"]
    assert kinds.count("labels") == 2 and kinds.count("labelled") == 2
    assert os.path.getsize(layout.labelled_preview(1)) > 1000
    warnings = [e for e in ev if e.get("event") == "warning"]
    assert {w["code"] for w in warnings} == {labels.LOW_COVERAGE_FLAG} and {w["frame"] for w in warnings} == {1, 2}
    # a label-only edit (a class) rewrites the labels and keeps the layers' key
    job = J.load(tmp / "job.json")
    job.assets[1].category = "van"
    J.save(tmp / "job.json", job)
    record = files.read_json(layout.record)
    exr_times = [os.stat(layout.condition_exr(f)).st_mtime_ns for f in (1, 2)]
    code, ev2, err = backend("render", tmp / "job.json", "--device", "cpu")
    assert code == 0, err
    done = [e for e in ev2 if e.get("event") == "done"][0]
    assert done["rendered"] == 0 and done["relabelled"] == 2           # the layers kept, the labels made again
    assert [os.stat(layout.condition_exr(f)).st_mtime_ns for f in (1, 2)] == exr_times
    assert files.read_json(layout.record)["key"] == record["key"]
    new = files.read_json(layout.frame_labels(1))
    assert _by_name(new)["behind"]["class"] == "van"
    for name in CARS:                                                  # pixel counts as the render made them
        for k in ("visible_pixels", "amodal_pixels", "visible_fraction", "bbox_visible"):
            assert _by_name(new)[name][k] == _by_name(labs[0])[name][k]
    # nothing changed: every frame reused, the warnings said again
    code, ev3, err = backend("render", tmp / "job.json", "--device", "cpu")
    done = [e for e in ev3 if e.get("event") == "done"][0]
    assert done["rendered"] == 0 and done["skipped"] == 2 and done["warnings"] == 2


def test_exr_header_carries_the_camera(rendered):
    """OpenEXR's standard worldToCamera / worldToNDC (row vectors times the matrix, RenderMan axes, NDC over the
    display window) place a world point where the labels' camera puts it."""
    import OpenEXR

    _, _, labs, layout = rendered
    header = OpenEXR.File(layout.condition_exr(1)).header()
    w2c = np.array(labs[0]["camera"]["world_to_camera"])
    p = np.array([1.0, 14.0, 0.3, 1.0])
    cam = w2c @ p
    assert np.allclose(p @ header["worldToCamera"], [cam[0], -cam[1], cam[2], 1.0], atol=1e-4)
    ndc = p @ header["worldToNDC"]
    u, v = (np.array(K) @ cam[:3])[:2] / cam[2]
    assert np.allclose(ndc[:2] / ndc[3], [u / W, v / H], atol=1e-6)


def _behind_as_recorded(rendered, **extra):
    """The "behind" car's rendered pixels taken as a recorded object's points (its instance ids cleared, so its
    depth is a point's), in its true box, "front" still inserted: (labels, layers, box_to_world)."""
    tmp, _, labs, layout = rendered
    layers = channels.read(layout.condition_exr(1))
    ids = np.rint(layers[channels.INSTANCE]).astype(int)
    T = _placement(*CARS["behind"])
    T[:3, 3] += T[:3, :3] @ CAR_BOX[0]
    d = J.load(tmp / "job.json").to_dict()
    d["assets"] = d["assets"][:1]
    d["scene"] = {"predictions": "p.npz", "vggt_to_world": np.eye(4).tolist(), "recorded_objects": [
        {"id": "behind", "size": CAR_BOX[1].tolist(), "boxes": {"1": T.tolist()}, **extra}]}
    inst = np.where(ids == 1, 1, 0).astype(np.float32)
    lab = labels.frame_labels(J.Job.from_dict(d), 0, instance=inst, hole=layers[channels.HOLE],
                              depth=layers[channels.DEPTH], asset_hashes=["0" * 64],
                              amodal_pixels=np.array([_by_name(labs[0])["front"]["amodal_pixels"]]),
                              asset_boxes=[(np.eye(4), np.ones(3), "job")])
    return lab, layers, T


def test_a_recorded_car_of_rendered_points_is_labelled_by_its_shape(rendered):
    """The "behind" car as a recorded object (``_behind_as_recorded``): its mask is the car's pixels (not its
    box's), hidden where the inserted "front" car is nearer; background (no scene: holes) in its box's corners
    would be its ``hole_fraction``."""
    lab, layers, T = _behind_as_recorded(rendered)
    ids, track = np.rint(layers[channels.INSTANCE]).astype(int), 2
    o = lab["objects"][1]
    box = boxes.polygon_mask(boxes.project_box(T, CAR_BOX[1], K, _w2c([0, 0, 1.5]), W, H)["polygon"], W, H)
    # the Gaussians' extent beyond their means (the box's) and the screen-space blur put a ring of the car's
    # rendered pixels up to 2 px (30 cm at 17 m) outside its box's projection, 36 of 163 here: a recording's points
    # render one pixel each, inside it
    car = (ids == track) & box
    ring = (ids == track) & ~box
    near_box = cv2.dilate(box.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert car.sum() > 2 * ring.sum() and np.all(near_box[ring])
    assert o["visible_pixels"] == car.sum() and o["bbox_visible"] == labels.pixel_box(car)
    assert not o["points_missing"] and o["occlusion"] in (1, 2) and o["amodal_pixels"] > o["visible_pixels"]
    assert o["amodal_pixels"] == car.sum() + (box & (ids == 1)).sum()      # hidden: where "front" wins
    holes = (box & (layers[channels.HOLE] > 0.5)).sum()
    assert o["hole_fraction"] == holes / (car.sum() + holes)


def test_labels_of_the_former_schema_are_made_again_from_the_layers(rendered):
    """A labels file of ``labels.OLD_SCHEMAS`` (a folder rendered before the schema changed) is relabelled from the
    EXR's layers, not rendered again and not an error."""
    tmp, _, labs, layout = rendered
    for f in (1, 2):
        old = files.read_json(layout.frame_labels(f))
        for o in old["objects"]:
            for k in ("ignore", "points_missing", "hole_fraction"):
                del o[k]
        del old["unlabelled_fraction"]
        outputs.write_json(layout.frame_labels(f), {**old, "schema": labels.OLD_SCHEMAS[0], "key": "its /1 key"})
    code, ev, err = backend("render", tmp / "job.json", "--device", "cpu")
    assert code == 0, err
    done = [e for e in ev if e.get("event") == "done"][0]
    assert done["rendered"] == 0 and done["relabelled"] == 2
    new = files.read_json(layout.frame_labels(1))
    assert new["schema"] == labels.SCHEMA and new["unlabelled_fraction"] == 0.0
    for name in CARS:
        assert _by_name(new)[name]["amodal_pixels"] == _by_name(labs[0])[name]["amodal_pixels"]


def test_the_labelled_preview_greys_and_hatches_ignore_regions(rendered):
    from backend.render import labelled

    lab, layers, _ = _behind_as_recorded(rendered, ignore=True)
    o = lab["objects"][1]
    x0, y0, x1, y1 = (int(v) for v in labels.ignore_region(o))
    assert o["ignore"] and lab["unlabelled_fraction"] > 0
    black = np.zeros((H, W, 3), np.uint8)
    img = labelled.draw(black, lab)
    plain = labelled.draw(black, _behind_as_recorded(rendered)[0])          # not ignored: nothing greyed
    assert (img[y0:y1, x0:x1] != plain[y0:y1, x0:x1]).any(-1).mean() > 0.3
    # the hatching: the pixels whose centres a region holds, greyed once however many regions cover them
    once = np.zeros((20, 30, 3), np.uint8)
    labelled.hatch(once, [[2.0, 3.0, 12.0, 9.0]])
    twice = np.zeros((20, 30, 3), np.uint8)
    labelled.hatch(twice, [[2.0, 3.0, 12.0, 9.0], [1.6, 2.6, 11.4, 8.4]])
    assert np.array_equal(once, twice)
    inside = np.zeros((20, 30), bool)
    inside[3:9, 2:12] = True
    lines = inside & (np.add.outer(np.arange(20), np.arange(30)) % labelled.HATCH_PERIOD == 0)
    assert (once[lines] == labelled.HATCH_COLOUR).all() and (once[inside & ~lines] == 64).all()
    assert (once[~inside] == 0).all()
