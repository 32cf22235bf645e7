"""Placement tools on the street: fit, snap to the ground, removal boxes, replace a parked car, review stages."""

import os

import bpy
import numpy as np
import pytest
from mathutils import Matrix

from scpainter_blender.core.geometry import fits as G
from scpainter_blender.core import job as J
from scpainter_blender.core import shapes
from tests_support import evaluated_counts


@pytest.fixture
def street_scene(empty_scene, street, tmp_path):
    bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                  trajectory_path=os.path.join(street.root, "metric.npz"),
                                  confidence_percentile=0.0)
    pts = next(o for o in empty_scene.objects if o.get("scpainter_kind") == "points")
    ply = str(tmp_path / "car.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=2000, seed=5))
    empty_scene.cursor.location = (-1.75, 9.0, 2.0)  # over the left lane, floating
    bpy.ops.scpainter.import_gaussians(filepath=ply)
    return pts, bpy.context.active_object


def _world_box(obj):
    """World corners (8, 3) of an asset's data bounds."""
    lo = np.array(obj["scpainter_size"]) * [-0.5, -0.5, 0.0]
    hi = np.array(obj["scpainter_size"]) * [0.5, 0.5, 1.0]
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    M = np.array(obj.matrix_world)
    return c @ M[:3, :3].T + M[:3, 3]


def test_fit_asset(street_scene):
    _, car = street_scene
    assert bpy.ops.scpainter.fit_asset(length=4.0) == {"FINISHED"}
    bpy.context.view_layer.update()
    size = np.ptp(_world_box(car), axis=0)
    assert size[1] == pytest.approx(4.0, rel=1e-5) and size[0] < size[1]
    assert bpy.ops.scpainter.fit_asset(length=4.8, width=2.0, height=1.5, uniform=False) == {"FINISHED"}
    bpy.context.view_layer.update()
    assert np.allclose(np.ptp(_world_box(car), axis=0), [2.0, 4.8, 1.5], rtol=1e-5)


def test_snap_to_ground(street_scene):
    _, car = street_scene
    car.rotation_euler = (0.2, 0.0, 0.4)  # tilted and turned: snapping stands it up and keeps the heading
    bpy.context.view_layer.update()
    assert bpy.ops.scpainter.snap_to_ground() == {"FINISHED"}
    bpy.context.view_layer.update()
    M = np.array(car.matrix_world)
    assert abs(M[2, 3]) < 0.02                       # the road is z = 0 in the street's metric world
    up = M[:3, 2] / np.linalg.norm(M[:3, 2])
    assert up[2] > np.cos(np.radians(1.0))           # upright on the flat road
    fwd = M[:3, 1] / np.linalg.norm(M[:3, 1])
    assert np.degrees(np.arctan2(-fwd[0], fwd[1])) == pytest.approx(np.degrees(0.4), abs=1.0)
    assert car.animation_data is None  # not animated: nothing keyed


def test_snap_keys_an_animated_car(street_scene, capfd):
    """A car driving along the road (location and Euler rotation keys, floating 2 m up): Snap to Ground keys what
    it sets at the current frame, so the next frame change does not put the old height back; All Keyframes snaps
    it at every key, where its animation puts it. The car keeps its rotation mode (its Euler keys keep playing)."""
    _, car = street_scene
    scene = bpy.context.scene
    car.rotation_mode = "XYZ"
    for frame, y, yaw in ((1, 9.0, 0.4), (16, 20.0, 0.6)):
        car.location = (-1.75, y, 2.0)
        car.rotation_euler = (0.2, 0.0, yaw)
        car.keyframe_insert("location", frame=frame)
        car.keyframe_insert("rotation_euler", frame=frame)

    def pose(frame):
        scene.frame_set(frame)
        M = np.array(car.matrix_world)
        fwd = M[:3, 1] / np.linalg.norm(M[:3, 1])
        return M[2, 3], (M[:3, 2] / np.linalg.norm(M[:3, 2]))[2], np.arctan2(-fwd[0], fwd[1])

    scene.frame_set(1)
    capfd.readouterr()
    assert bpy.ops.scpainter.snap_to_ground() == {"FINISHED"}
    assert "keyed at frame 1 (All Keyframes snaps every key)" in capfd.readouterr().out
    pose(8)
    z, up, heading = pose(1)  # after a frame change: the snap lasted
    assert abs(z) < 0.02 and up > np.cos(np.radians(1.0)) and heading == pytest.approx(0.4, abs=0.02)
    assert car.rotation_mode == "XYZ" and pose(16)[0] == pytest.approx(2.0)  # only the current frame was keyed
    car.location.x += 0.5                           # moved by hand at frame 16, not keyed: All Keyframes keeps it
    assert bpy.ops.scpainter.snap_to_ground(all_keys=True) == {"FINISHED"}
    assert "keyed at its 2 keyframes (1, 16)" in capfd.readouterr().out
    assert scene.frame_current == 16  # where the artist was
    assert car.location.x == pytest.approx(-1.25, abs=0.05)  # the hand edit, keyed (snapping moves it along z)
    for frame, yaw in ((1, 0.4), (8, None), (16, 0.6)):
        z, up, heading = pose(frame)
        assert abs(z) < 0.02 and up > np.cos(np.radians(1.0)), frame
        if yaw is not None:
            assert heading == pytest.approx(yaw, abs=0.02), frame


def test_snap_away_from_the_road_is_a_scene_error(street_scene):
    """Bad input (a SceneError naming the asset), reported as such: not a bug, and the asset stays where it is."""
    _, car = street_scene
    car.location = (500.0, 500.0, 2.0)
    with pytest.raises(RuntimeError, match=rf"\(unsaved \.blend\): objects\['{car.name}'\]: only 0 scene points "
                                           r"under the asset \(move it over the reconstructed road"):
        bpy.ops.scpainter.snap_to_ground()
    assert tuple(car.location) == (500.0, 500.0, 2.0)


def test_removal_box_removes_the_parked_car_points(street_scene, street, tmp_path):
    pts, _ = street_scene
    car = street.info["cars"][0]
    T = np.array(car["box_to_world"])
    L, W, H = car["size"][1], car["size"][0], car["size"][2]
    from scpainter_blender.scene.placement import scene_points_world  # the repo's copy of the installed module

    world = scene_points_world(pts)
    inside = G.points_in_box(world, T, [W + 0.1, L + 0.1, H + 0.1])
    assert inside.sum() > 500  # the recorded car is in the reconstruction
    bpy.context.scene.cursor.location = (0, 0, 0)
    assert bpy.ops.scpainter.add_removal_box(length=L + 0.1, width=W + 0.1, height=H + 0.1) == {"FINISHED"}
    box = bpy.context.active_object
    box.location = T[:3, 3].tolist()
    box.rotation_euler = (0, 0, float(np.arctan2(T[1, 0], T[0, 0])))
    bpy.context.view_layer.update()
    assert [m.name for m in pts.modifiers][-1] == "SCPainter Points"  # removal happens before the preview
    assert evaluated_counts(pts)[0] == len(world) - inside.sum()
    # exported with the job, as the box the artist placed
    bpy.ops.scpainter.export_job(filepath=str(tmp_path / "job.json"))
    (b,) = J.load(tmp_path / "job.json").to_dict()["scene"]["removal_boxes"]
    assert np.abs(np.array(b["box_to_world"]) - T).max() < 1e-5
    assert np.allclose(b["size"], [W + 0.1, L + 0.1, H + 0.1], rtol=1e-6)
    # a deleted box removes nothing
    bpy.data.objects.remove(box)
    pts.update_tag()
    assert evaluated_counts(pts)[0] == len(world)


def test_replace_car_aligns_and_checks(street_scene, street):
    pts, asset = street_scene
    car = street.info["cars"][1]
    T = np.array(car["box_to_world"])
    bpy.ops.scpainter.add_removal_box(length=car["size"][1], width=car["size"][0], height=car["size"][2])
    box = bpy.context.active_object
    box.matrix_world = Matrix(T.tolist())
    box.scale = (car["size"][0] / 2, car["size"][1] / 2, car["size"][2] / 2)
    bpy.context.view_layer.update()
    for o in bpy.context.view_layer.objects:
        o.select_set(o in (box, asset))
    bpy.context.view_layer.objects.active = asset
    assert bpy.ops.scpainter.replace_car() == {"FINISHED"}
    bpy.context.view_layer.update()
    corners = _world_box(asset)
    local = (corners - T[:3, 3]) @ T[:3, :3]  # in the box's frame: fills it exactly
    half = np.array(car["size"]) / 2
    assert np.allclose(np.abs(local), half, atol=1e-4)
    assert asset["scpainter_target_box"] == box.name
    assert asset["scpainter_stage1"] == "ok"  # the same car shape as the recorded one


def test_stage1_flags_wrong_proportions_and_stage2_rejects(street_scene, tmp_path):
    _, good = street_scene
    b = shapes.MeshBuilder()
    b.box((0, 0, 1.0), (2.0, 2.2, 2.0), "van")  # a cube, nothing like a car
    cube = str(tmp_path / "cube.ply")
    shapes.save_as_amodal3r(cube, shapes.surface_gaussians(b, {"van": (0.5, 0.5, 0.5)}, 500))
    bpy.ops.scpainter.import_gaussians(filepath=cube)
    bad = bpy.context.active_object
    assert bpy.ops.scpainter.check_assets() == {"FINISHED"}
    assert good["scpainter_stage1"] == "ok" and bad["scpainter_stage1"] == "flagged"
    assert bpy.ops.scpainter.review_asset(name=bad.name, status="rejected") == {"FINISHED"}
    assert bpy.ops.scpainter.review_asset(name=good.name, status="accepted") == {"FINISHED"}
    bpy.ops.scpainter.export_job(filepath=str(tmp_path / "job.json"))
    assert [a["name"] for a in J.load(tmp_path / "job.json").to_dict()["assets"]] == [good.name]


def test_placement_needs_an_asset(empty_scene):
    assert not bpy.ops.scpainter.fit_asset.poll()
    assert not bpy.ops.scpainter.snap_to_ground.poll()
    assert not bpy.ops.scpainter.add_removal_box.poll()
