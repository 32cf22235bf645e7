"""bpy.ops.scpainter.new_camera_path against the street's ground-truth shifted drives."""

import os

import bpy
import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C


@pytest.mark.parametrize("shift", [2.0, -2.0, 3.0, -3.0])
def test_shifted_path_matches_ground_truth(empty_scene, street, shift):
    bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                  trajectory_path=os.path.join(street.root, "metric.npz"))
    assert bpy.ops.scpainter.new_camera_path(shift=shift) == {"FINISHED"}
    cam = empty_scene.camera
    assert cam["scpainter_kind"] == "camera_path" and cam["scpainter_shift_m"] == shift
    truth = street.metric()[f"world_to_camera_{'left' if shift > 0 else 'right'}_{abs(shift):g}m"]
    from scpainter_blender.scene.camera import world_to_camera_per_frame

    frames = range(empty_scene.frame_start, empty_scene.frame_end + 1)
    got = world_to_camera_per_frame(empty_scene, cam, frames)
    assert np.abs(C.camera_centers(got) - C.camera_centers(truth)).max() < 2e-3  # float32 keys, fitted scale
    assert np.abs(got[:, :3, :3] - truth[:, :3, :3]).max() < 1e-4
    # editable: one key per frame on location and rotation
    fcurves = [fc for fc in _fcurves(cam)]
    assert sorted({fc.data_path for fc in fcurves}) == ["location", "rotation_quaternion"]
    assert all(len(fc.keyframe_points) == len(frames) for fc in fcurves)
    source = bpy.data.objects[cam["scpainter_source_camera"]]
    assert cam.data != source.data and cam.data.lens == pytest.approx(source.data.lens)  # a copy of the lens


def _fcurves(obj):
    ad = obj.animation_data
    if hasattr(ad, "action_slot") and ad.action_slot is not None:
        from bpy_extras import anim_utils

        return anim_utils.action_get_channelbag_for_slot(ad.action, ad.action_slot).fcurves
    return ad.action.fcurves


def test_needs_a_recorded_camera(empty_scene):
    assert not bpy.ops.scpainter.new_camera_path.poll()
