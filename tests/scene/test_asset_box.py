"""scene/asset_box.py: a Gaussian asset's 3D box, estimated at import, flipped, edited and exported to the job, checked
against the procedural car's own mesh and computed independently in numpy."""

import os

import bpy
import numpy as np
import pytest

from scpainter_blender.core import job as J
from scpainter_blender.core import shapes
from scpainter_blender.core.geometry import boxes
from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria
from scpainter_blender.scene import asset_box, kinds, placement

SEED = 2
FILE_YAW = np.radians(25.0)     # the car turned in its own file (INRIA case): the estimate must find the heading
FILE_SCALE = 0.5                # and stored at half size (file units)


def _true_box():
    """(centre (3,), size (width, length, height)) of the procedural car's mesh (shapes.add_car, as
    procedural_car_gaussians builds it with seed ``SEED``): its vertices' bounds (the wheels' lowest vertex is on
    z = 0; their caps stick out past the body's sides)."""
    rng = np.random.default_rng(SEED)
    rng.uniform(0.1, 0.8, 3)  # the paint, drawn first
    b = shapes.MeshBuilder()
    shapes.add_car(b, rng, "paint", "glass", "tyre")
    V = np.concatenate(b.verts)
    lo, hi = V.min(0), V.max(0)
    return (lo + hi) / 2, hi - lo


def _rz(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module", params=["inria", "trellis"])
def car(request, tmp_path_factory):
    """(kind, path, car_to_file 4x4 similarity): the procedural car as an INRIA file turned by FILE_YAW and scaled
    by FILE_SCALE, or as Amodal3R saves it (TRELLIS axes: file frame ≠ data frame)."""
    g = shapes.procedural_car_gaussians(count=12000, seed=SEED)
    path = str(tmp_path_factory.mktemp("assets") / f"car_{request.param}.ply")
    if request.param == "trellis":
        return request.param, path, shapes.save_as_amodal3r(path, g)
    A = np.eye(4)
    A[:3, :3] = FILE_SCALE * _rz(FILE_YAW)
    A[:3, 3] = [3.0, -1.0, 0.5]
    splats_inria.write_ply(path, splats.encode(shapes.transform_gaussians(g, A)))
    return request.param, path, A


def _import(car, yaw=0.4, scale=1.7, location=(5.0, 12.0, 0.3)):
    """The car imported, then placed at a known yaw, uniform scale and location; the view layer updated."""
    kind, path, _ = car
    assert bpy.ops.scpainter.import_gaussians(filepath=path, axes="AUTO") == {"FINISHED"}
    asset = bpy.context.active_object
    assert asset["scpainter_axes"] == ("TRELLIS" if kind == "trellis" else "NONE")
    asset.rotation_euler = (0.0, 0.0, yaw)
    asset.scale = (scale,) * 3
    asset.location = location
    bpy.context.view_layer.update()
    return asset


def _expected_world_box(car, asset):
    """The car's true box in the world: its mesh box through car_to_file, file_to_data and matrix_world."""
    _, _, car_to_file = car
    centre, size = _true_box()
    T = np.eye(4)
    T[:3, 3] = centre
    M = (np.array(asset.matrix_world, np.float64) @ np.array(asset["scpainter_file_to_data"]).reshape(4, 4)
         @ car_to_file)
    return boxes.place_box(T, size, M)


def test_import_estimates_the_true_box(empty_scene, car):
    asset = _import(car)
    box = kinds.asset_box(asset)
    assert box is not None and kinds.is_kind(box, kinds.ASSET_BOX) and box.parent == asset
    assert box.empty_display_type == "CUBE" and box.empty_display_size == asset_box.DISPLAY_SIZE
    assert asset[asset_box.CLASS_PROPERTY] == J.DEFAULT_CLASS
    front = kinds.asset_front(box)
    assert kinds.is_kind(front, kinds.ASSET_FRONT) and front.empty_display_type == "SINGLE_ARROW"
    assert kinds.owning_asset(front) == kinds.owning_asset(box) == kinds.owning_asset(asset) == asset
    T, size = placement.box_matrix(box)
    T_true, size_true = _expected_world_box(car, asset)
    assert np.abs(size - size_true).max() <= 0.05, (size, size_true)
    assert np.abs(T[:3, 3] - T_true[:3, 3]).max() <= 0.05
    # the front (+y) is the car's: the heading of the box's y within 1° of the true one; z is up
    heading = lambda R: np.degrees(np.arctan2(-R[0, 1], R[1, 1]))  # noqa: E731  (y axis' angle from +y)
    assert abs(heading(T[:3, :3]) - heading(T_true[:3, :3])) <= 1.0
    assert T[2, 2] > 1 - 1e-9
    # the size in metres: the mesh's own times every scale in between
    if car[0] == "inria":
        assert np.allclose(size_true, _true_box()[1] * FILE_SCALE * 1.7)
    # the front arrow sits on the front face's centre and points along the box's +y
    F = np.array(front.matrix_world, np.float64)
    y = T[:3, 1]
    assert np.abs(F[:3, 3] - (T[:3, 3] + y * size[1] / 2)).max() < 1e-4
    assert np.abs(F[:3, 2] / np.linalg.norm(F[:3, 2]) - y).max() < 1e-5


def test_flip_turns_the_front_around(empty_scene, car):
    asset = _import(car)
    box = kinds.asset_box(asset)
    T0, s0 = placement.box_matrix(box)
    for o in bpy.context.selected_objects:
        o.select_set(False)
    box.select_set(True)  # the box selected (not the asset): the operator finds its asset
    bpy.context.view_layer.objects.active = box
    assert bpy.ops.scpainter.flip_asset_front() == {"FINISHED"}
    bpy.context.view_layer.update()
    T1, s1 = placement.box_matrix(box)
    assert np.allclose(s1, s0, atol=1e-6) and np.allclose(T1[:3, 3], T0[:3, 3], atol=1e-5)
    assert np.allclose(T1[:3, :3], T0[:3, :3] @ np.diag([-1.0, -1.0, 1.0]), atol=1e-6)
    F = np.array(kinds.asset_front(box).matrix_world, np.float64)
    assert np.abs(F[:3, 2] / np.linalg.norm(F[:3, 2]) + T0[:3, 1]).max() < 1e-5  # the arrow follows: now -y
    # an asset without a box: nothing to flip, said so
    asset_box.remove(asset)
    assert kinds.asset_box(asset) is None and not [o for o in bpy.data.objects if kinds.is_kind(o, kinds.ASSET_FRONT)]
    bpy.context.view_layer.objects.active = asset
    asset.select_set(True)
    with pytest.raises(RuntimeError, match="no box: Estimate Box first"):
        bpy.ops.scpainter.flip_asset_front()


def _camera_scene(scene, frames=3):
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.location = (0.0, -10.0, 1.5)
    cam.rotation_euler = (np.radians(85.0), 0.0, 0.0)
    scene.frame_start, scene.frame_end = 1, frames
    scene.render.resolution_x, scene.render.resolution_y = 64, 48


def _edit(box):
    box.location = np.array(box.location) + [0.05, -0.1, 0.02]
    box.rotation_euler.z += 0.2
    box.scale = np.array(box.scale) * [1.1, 0.9, 1.2]


def test_edited_box_exports_in_file_coordinates(empty_scene, car, tmp_path):
    asset = _import(car)
    _camera_scene(empty_scene)
    asset.keyframe_insert("location", frame=1)
    asset.location.x += 4.0  # the car drives: its box goes with it
    asset.rotation_euler.z += 0.3
    asset.keyframe_insert("location", frame=3)
    asset.keyframe_insert("rotation_euler", frame=3)
    box = kinds.asset_box(asset)
    _edit(box)
    asset[asset_box.CLASS_PROPERTY] = "van"
    path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
    job = J.load(path)  # validated: Job.from_dict
    (a,) = job.assets
    assert a.category == "van" and job.to_dict()["assets"][0]["class"] == "van"
    assert a.box is not None
    assert np.allclose(a.box.box_to_file[:3, :3].T @ a.box.box_to_file[:3, :3], np.eye(3), atol=1e-9)
    for f in (1, 2, 3):
        empty_scene.frame_set(f)
        placed_T, placed_size = boxes.place_box(a.box.box_to_file, a.box.size, a.object_to_world[f])
        # the empty's world box: parent world · parent inverse · basis (float64), through the one cube helper
        world = (np.array(asset.matrix_world, np.float64) @ np.array(box.matrix_parent_inverse, np.float64)
                 @ np.array(box.matrix_basis, np.float64))
        T, size = boxes.rigid_box(placement.cube_matrix(box, world))
        assert np.abs(placed_T - T).max() <= 1e-6 and np.abs(placed_size - size).max() <= 1e-6, f
        # and Blender's own (float32) matrix_world of the empty
        T32, size32 = placement.box_matrix(box)
        assert np.abs(placed_T - T32).max() <= 1e-5 and np.abs(placed_size - size32).max() <= 1e-5, f
    # the box in the file's own coordinates: the edit undone through the file's axes (TRELLIS: rotated, unit cube)
    D = np.array(asset["scpainter_file_to_data"]).reshape(4, 4)
    T_data, size_data = boxes.rigid_box(asset_box.box_to_data(asset, box))
    T_file, size_file = boxes.place_box(a.box.box_to_file, a.box.size, D)
    assert np.abs(T_file - T_data).max() < 1e-9 and np.abs(size_file - size_data).max() < 1e-9


def test_reestimate_replaces_an_edited_box(empty_scene, car):
    asset = _import(car)
    box = kinds.asset_box(asset)
    estimated = np.array(box.matrix_basis, np.float64)
    _edit(box)
    assert bpy.ops.scpainter.estimate_asset_box() == {"FINISHED"}  # the asset is the active object
    new = kinds.asset_box(asset)
    assert np.abs(np.array(new.matrix_basis, np.float64) - estimated).max() < 1e-6
    assert len([o for o in bpy.data.objects if kinds.is_kind(o, kinds.ASSET_BOX)]) == 1
    assert len([o for o in bpy.data.objects if kinds.is_kind(o, kinds.ASSET_FRONT)]) == 1


def test_set_axes_estimates_the_box_again(empty_scene, car):
    if car[0] != "trellis":
        pytest.skip("one case is enough: the TRELLIS file read as stored lies on its side")
    asset = _import(car)
    assert bpy.ops.scpainter.set_asset_axes(axes="NONE") == {"FINISHED"}
    box = kinds.asset_box(asset)
    T, size = boxes.estimate_box(asset_box.data_points(asset))
    assert np.abs(np.array(box.matrix_basis, np.float64) - T @ np.diag([*size, 1.0])).max() < 1e-5
    # as stored, the car stands on its tail (the file's z is its length): the box is (height, width, length)
    width, length, height = _true_box()[1]
    assert np.abs(size / size[1] - np.array([height, width, length]) / width).max() < 0.03
    assert len([o for o in bpy.data.objects if kinds.is_kind(o, kinds.ASSET_BOX)]) == 1


def test_asset_without_a_box_exports_none(empty_scene, car, tmp_path):
    asset = _import(car)
    _camera_scene(empty_scene, frames=1)
    asset_box.remove(asset)
    del asset[asset_box.CLASS_PROPERTY]  # an asset imported before boxes and classes
    path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
    d = J.load(path).to_dict()
    assert "box" not in d["assets"][0] and "class" not in d["assets"][0]
    assert d["fps"] == empty_scene.render.fps / empty_scene.render.fps_base
    assert os.path.isfile(path)

