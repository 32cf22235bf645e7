"""*Drive Along Lane* on the street (scene/drive_lane.py): the car keyed as the scenario command's moving cars are
placed (``core.variation.placement.drive``), on the true road plane z = 0, in its lane, at its speed."""

import os
import sys

import bpy
import numpy as np
import pytest

from scpainter_blender.core import shapes
from scpainter_blender.core.geometry import boxes
from scpainter_blender.core.variation import placement, variants
from scpainter_blender.core.variation.road import Road


def _mod(addon, name):
    return sys.modules[f"{addon}.scpainter_blender.scene.{name}"]


@pytest.fixture
def street_car(empty_scene, street, tmp_path):
    """The street at its true scale and a car (with its box) standing in the left lane at y = 8 m."""
    bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                  trajectory_path=os.path.join(street.root, "metric.npz"))
    ply = str(tmp_path / "car.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=2000, seed=5))
    empty_scene.cursor.location = (-1.75, 8.0, 0.0)
    bpy.ops.scpainter.import_gaussians(filepath=ply)
    return empty_scene, bpy.context.active_object


def _world_box(addon, car, frame):
    """(box_to_world, size) of the car's box at ``frame``, as the job exports it."""
    bpy.context.scene.frame_set(frame)
    box = _mod(addon, "kinds").asset_box(car)
    return boxes.rigid_box(np.array(car.matrix_world, np.float64) @ _mod(addon, "asset_box").box_to_data(car, box))


def _expected(addon, car, lane, speed, start_frame):
    """The core's poses for the scene, found independently of the operator's cache: the job from the recorded
    camera, a new Road, ``placement.drive`` from where the car's box stands at the start frame."""
    drive_lane = _mod(addon, "drive_lane")
    job, job_path = drive_lane.drive_job(bpy.context)
    path = variants.reference_path(job)
    road = Road(variants.scene_points(job, job_path), path.centres, seed=0)
    T0, size = _world_box(addon, car, start_frame)
    frames = [f.frame for f in job.frames if f.frame >= start_frame]
    t = (np.array(frames, np.float64) - start_frame) / job.frame_rate()[0]
    reach = road.road_arc(path, lane_m=lane)
    arc, poses = placement.drive(road, path, size, lane, speed, path.project(T0[:2, 3])[0], t, reach=reach)
    return frames, arc, np.stack(poses), size, path


def test_keyed_transforms_are_the_scenario_commands_drive(addon, street_car):
    scene, car = street_car
    frames, arc, expected, size, path = _expected(addon, car, 2.0, 6.0, 3)
    assert bpy.ops.scpainter.drive_along_lane(lane_offset=2.0, speed=6.0, start_frame=3) == {"FINISHED"}
    assert car.rotation_mode == "QUATERNION"
    for f, T in zip(frames, expected):
        got, got_size = _world_box(addon, car, f)
        assert np.allclose(got, T, atol=2e-4) and np.allclose(got_size, size, atol=1e-4)
        assert T[2, 3] - size[2] / 2 == pytest.approx(0.0, abs=0.03)      # standing on the street's road, z = 0
        assert T[2, 2] > np.cos(np.radians(1.0))                           # upright on the flat road
        xy, head = path.at(np.array([path.project(T[:2, 3])[0]]))
        assert T[:2, 1] @ head[0] > np.cos(np.radians(1.0))               # its front along the drive
    # before the start frame it holds its start pose; speed × time = distance driven
    assert np.allclose(_world_box(addon, car, 1)[0], expected[0], atol=2e-4)
    seconds = (frames[-1] - frames[0]) / (scene.render.fps / scene.render.fps_base)
    assert arc[-1] - arc[0] == pytest.approx(6.0 * seconds)
    moved = path.project(expected[-1][:2, 3])[0] - path.project(expected[0][:2, 3])[0]
    assert moved == pytest.approx(6.0 * seconds, abs=0.05)
    for data_path, count in (("location", 3), ("rotation_quaternion", 4)):   # one key per frame, linear
        curves = [fc for fc in _mod(addon, "compat").object_fcurves(car, "x") if fc.data_path == data_path]
        assert len(curves) == count
        assert all([int(k.co[0]) for k in fc.keyframe_points] == frames for fc in curves)
        assert {k.interpolation for fc in curves for k in fc.keyframe_points} == {"LINEAR"}


def test_lane_offset_moves_it_sideways_and_a_second_drive_replaces_the_first(addon, street_car):
    scene, car = street_car
    drive_lane = _mod(addon, "drive_lane")
    lanes = {}
    for lane in (0.0, 2.5):
        d = drive_lane.drive_along_lane(bpy.context, car, lane, 5.0, 1)
        lanes[lane] = d.box_to_world
        assert d.frames == list(range(scene.frame_start, scene.frame_end + 1)) and d.stopped_at is None
    path = variants.reference_path(drive_lane.drive_job(bpy.context)[0])
    for A, B in zip(lanes[0.0], lanes[2.5]):
        s, off = path.project(A[:2, 3])
        s2, off2 = path.project(B[:2, 3])
        assert off2 - off == pytest.approx(2.5, abs=0.01) and s2 == pytest.approx(s, abs=0.01)
    curves = [fc for fc in _mod(addon, "compat").object_fcurves(car, "x") if fc.data_path == "location"]
    assert len(curves) == 3 and all(len(fc.keyframe_points) == len(lanes[0.0]) for fc in curves)
    assert np.allclose(_world_box(addon, car, 5)[0], lanes[2.5][4], atol=2e-4)
    # what the panel offers: the lane the car stands in now
    assert drive_lane.lane_where_it_stands(bpy.context, car, 1) == pytest.approx(2.5, abs=0.01)


def test_oncoming_and_stopping_at_the_end_of_the_road(addon, street_car):
    scene, car = street_car
    drive_lane = _mod(addon, "drive_lane")
    back = drive_lane.drive_along_lane(bpy.context, car, 2.0, -4.0, 1)
    assert back.box_to_world[-1][1, 3] < back.box_to_world[0][1, 3]          # drives towards −y ...
    assert back.box_to_world[0][1, 1] < -0.99                                # ... facing it
    fast = drive_lane.drive_along_lane(bpy.context, car, 2.0, 70.0, 1)
    assert fast.stopped_at is not None
    i = fast.frames.index(fast.stopped_at)
    assert np.array_equal(fast.box_to_world[i], fast.box_to_world[-1])       # held at the end
    level, text = drive_lane.summary(car, fast, 2.0, 70.0)
    assert level == "WARNING" and f"from frame {fast.stopped_at}" in text
    assert bpy.ops.scpainter.drive_along_lane(lane_offset=2.0, speed=70.0, start_frame=1) == {"FINISHED"}


def test_refusals(addon, street_car):
    scene, car = street_car
    drive_lane, props = _mod(addon, "drive_lane"), _mod(addon, "props")
    with pytest.raises(props.SceneError, match="start_frame"):
        drive_lane.drive_along_lane(bpy.context, car, 0.0, 5.0, scene.frame_end + 1)
    car.location = (-1.75, 400.0, 0.0)          # far beyond the reconstructed road
    with pytest.raises(props.SceneError, match="beyond the road"):
        drive_lane.drive_along_lane(bpy.context, car, 0.0, 5.0, 1)
    car.location = (-1.75, 8.0, 0.0)
    with pytest.raises(props.SceneError, match="lane_offset"):
        drive_lane.drive_along_lane(bpy.context, car, 45.0, 5.0, 1)
    _mod(addon, "asset_box").remove(car)
    with pytest.raises(props.SceneError, match="has no box"):
        drive_lane.drive_along_lane(bpy.context, car, 0.0, 5.0, 1)
    _mod(addon, "asset_box").estimate(car)
    pts = _mod(addon, "kinds").point_cloud(scene)
    bpy.data.objects.remove(pts, do_unlink=True)
    with pytest.raises(props.SceneError, match="no points object"):
        drive_lane.drive_along_lane(bpy.context, car, 0.0, 5.0, 1)
    # the operator reports it; without an active car it is not offered
    with pytest.raises(RuntimeError, match="no points object"):
        bpy.ops.scpainter.drive_along_lane(speed=5.0)
    bpy.context.view_layer.objects.active = None
    with pytest.raises(RuntimeError, match="Select a Gaussian car asset"):
        bpy.ops.scpainter.drive_along_lane()
    with pytest.raises(props.SceneError, match="no Gaussian car asset"):
        drive_lane.drive_along_lane(bpy.context, None, 0.0, 5.0, 1)
