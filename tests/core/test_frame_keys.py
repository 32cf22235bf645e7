"""core.frame_keys: what enters a frame's layers key and what does not; the record's extents."""

import os

import numpy as np

from scpainter_blender.core import frame_keys, outputs
from scpainter_blender.core import job as J
from scpainter_blender.core.geometry import visibility
from scpainter_blender.core.output_layout import OutputLayout
from scpainter_blender.core.splats import reader
from tests_support import small_job


def _keys(path, job, extents=None, radius=0, half=False):
    inputs = frame_keys.Inputs.of(path, job)
    if extents is None:
        g = reader.load(J.resolve(path, job.assets[0].ply))
        extents = [visibility.asset_bounds(g.means, g.quats, g.scales)] * len(job.assets)
    return frame_keys.frame_keys(job, frame_keys.scene_key(job, inputs, radius, half), inputs, extents)


def test_an_asset_enters_only_the_keys_of_frames_that_can_see_it(tmp_path):
    path = small_job(tmp_path, frames=(1, 2, 3))
    job = J.load(path)
    keys = _keys(path, job)
    behind = np.eye(4)
    behind[:3, 3] = [0.0, 0.0, -50.0]                  # behind the camera in frame 2 only
    job.assets[0].object_to_world[2] = behind
    moved = _keys(path, job)
    assert moved[1] == keys[1] and moved[3] == keys[3] and moved[2] != keys[2]
    behind2 = behind.copy()
    behind2[0, 3] = 1.0                                 # moved again, still out of view: frame 2's key stays
    job.assets[0].object_to_world[2] = behind2
    assert _keys(path, job) == moved


def test_label_fields_do_not_enter_the_layers_keys_but_the_scene_and_precision_do(tmp_path):
    path = small_job(tmp_path, frames=(1, 2))
    job = J.load(path)
    keys = _keys(path, job)
    job.assets[0].category = "van"
    job.fps = 25.0
    assert _keys(path, job) == keys
    assert frame_keys.labels_key(keys[1], frame_keys.job_digest(job)) != \
        frame_keys.labels_key(keys[1], frame_keys.job_digest(J.load(path)))
    assert set(_keys(path, job, half=True).values()).isdisjoint(keys.values())
    assert set(_keys(path, job, radius=1).values()).isdisjoint(keys.values())
    job.scene.confidence_percentile = 10.0
    assert set(_keys(path, job).values()).isdisjoint(keys.values())
    # the first camera is the renderer's float32 origin: moving it changes every frame's arithmetic
    job = J.load(path)
    job.frames[0].world_to_camera = job.frames[0].world_to_camera.copy()
    job.frames[0].world_to_camera[0, 3] += 0.01
    new = _keys(path, job)
    assert new[1] != keys[1] and new[2] != keys[2]


def test_an_asset_with_nothing_to_draw_is_in_no_key(tmp_path):
    path = small_job(tmp_path, frames=(1,))
    job = J.load(path)
    assert visibility.asset_bounds(np.full((3, 3), np.nan), np.ones((3, 4)), np.ones((3, 3))) == (None, float("inf"))
    nothing = _keys(path, job, extents=[(None, float("inf"))])
    job.assets[0].object_to_world[1] = np.diag([2.0, 2.0, 2.0, 1.0])
    assert _keys(path, job, extents=[(None, float("inf"))]) == nothing


def test_record_keeps_each_asset_files_extent_while_its_stamp_holds(tmp_path):
    path = small_job(tmp_path, frames=(1, 2))
    job = J.load(path)
    inputs = frame_keys.Inputs.of(path, job)
    g = reader.load(J.resolve(path, job.assets[0].ply))
    extents = [visibility.asset_bounds(g.means, g.quats, g.scales)]
    layout = OutputLayout(tmp_path / "out")
    os.makedirs(layout.conditions)
    rec = frame_keys.record("k", OutputLayout.condition_names([1, 2]), False, job, inputs, extents)
    outputs.write_json(layout.record, rec)
    back = frame_keys.recorded_extents(frame_keys.read_record(layout), job, inputs)
    assert np.array_equal(back[0][0], extents[0][0]) and back[0][1] == extents[0][1]
    changed = frame_keys.Inputs(inputs.points, [[inputs.assets[0][0] + 1, inputs.assets[0][1]]])
    assert frame_keys.recorded_extents(rec, job, changed) is None
    # nothing rendered yet: every frame is to render; a record of the former schema: only the backend can say
    assert frame_keys.plan_from_record(layout.root, path, job).render == {1, 2}
    outputs.write_json(layout.record, {**rec, "schema": "scpainter.conditions/1"})
    assert frame_keys.plan_from_record(layout.root, path, job) is None
