"""Importing the reconstruction again on the street: Replace Reconstruction swaps the points and the recorded camera
and keeps what was built on them; a plain import keeps a camera path as the scene camera."""

import os

import bpy
import numpy as np
import pytest

from scpainter_blender.core import job as J


def _of_kind(scene, kind):
    return [o for o in scene.objects if o.get("scpainter_kind") == kind]


def _street_args(street):
    return dict(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                trajectory_path=os.path.join(street.root, "metric.npz"))


def test_replace_keeps_camera_paths_assets_and_removal_boxes(empty_scene, street, tmp_path, capfd):
    from tests_support import street_with_car

    scene = street_with_car(street, tmp_path, count=500)
    (old_pts,) = _of_kind(scene, "points")
    (old_cam,) = _of_kind(scene, "recorded_camera")
    (path,) = _of_kind(scene, "camera_path")
    (car,) = _of_kind(scene, "gaussian_asset")
    bpy.context.view_layer.objects.active = car
    assert bpy.ops.scpainter.add_removal_box() == {"FINISHED"}
    (box,) = _of_kind(scene, "removal_box")
    scene.frame_end = 12  # the artist's output range
    names = (old_pts.name, old_cam.name)
    old_mesh = old_pts.data.name
    capfd.readouterr()

    assert bpy.ops.scpainter.replace_reconstruction(**_street_args(street), confidence_percentile=70.0) == \
        {"FINISHED"}
    said = capfd.readouterr().out
    (pts,) = _of_kind(scene, "points")
    (cam,) = _of_kind(scene, "recorded_camera")
    assert (pts.name, cam.name) == names  # the new objects under the old names: whatever named them still does
    assert pts["scpainter_confidence_percentile"] == 70.0 and old_mesh not in bpy.data.meshes
    assert cam["scpainter_frame_start"] == 1 and path["scpainter_source_camera"] == cam.name
    assert _of_kind(scene, "camera_path") == [path] and _of_kind(scene, "gaussian_asset") == [car]
    assert scene.camera == path and (scene.frame_start, scene.frame_end) == (1, 12)
    assert set(pts.users_collection) == set(cam.users_collection)
    from scpainter_blender.scene import placement

    assert placement.applied_removal_boxes(pts) == [box] and box["scpainter_points_object"] == pts.name
    mods = [m.name for m in pts.modifiers]
    assert mods.index(f"SCPainter Remove {box.name}") < mods.index("SCPainter Points")  # removed, then drawn
    assert f"'{names[0]}' replaced" in said and f"removal boxes carried over: '{box.name}'" in said

    job_path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    job = J.load(job_path).to_dict()
    assert job["scene"]["confidence_percentile"] == 70.0 and len(job["scene"]["removal_boxes"]) == 1
    assert [a["name"] for a in job["assets"]] == [car.name] and len(job["frames"]) == 12
    m = street.metric()
    assert np.abs(np.array(job["scene"]["vggt_to_world"]) - m["vggt_to_world"]).max() < 1e-4


def test_replace_refuses_a_bad_file_and_changes_nothing(empty_scene, street, tmp_path):
    assert bpy.ops.scpainter.import_vggt(**_street_args(street)) == {"FINISHED"}
    before = sorted(o.name for o in empty_scene.objects)
    with pytest.raises(RuntimeError, match=r"nope\.npz"):
        bpy.ops.scpainter.replace_reconstruction(filepath=str(tmp_path / "nope.npz"))
    assert sorted(o.name for o in empty_scene.objects) == before


def test_replace_follows_the_recorded_camera_and_needs_a_reconstruction(empty_scene, tmp_path):
    """Looking through the recorded camera, the scene camera becomes the new one; with nothing to replace the
    operator is greyed out."""
    from vggt_cases import drive, write

    assert not bpy.ops.scpainter.replace_reconstruction.poll()
    a, _, _ = drive(S=3, H=12, W=16, seed=1)
    b, _, _ = drive(S=4, H=12, W=16, seed=2)
    assert bpy.ops.scpainter.import_vggt(filepath=write(tmp_path, a, "a.npz"), depth_edge_ratio=0.0) == {"FINISHED"}
    assert bpy.ops.scpainter.replace_reconstruction(filepath=write(tmp_path, b, "b.npz"),
                                                    depth_edge_ratio=0.0) == {"FINISHED"}
    (cam,) = _of_kind(empty_scene, "recorded_camera")
    (pts,) = _of_kind(empty_scene, "points")
    assert empty_scene.camera == cam and pts["scpainter_source"].endswith("b.npz")
    assert pts["scpainter_num_frames"] == 4 and (empty_scene.frame_start, empty_scene.frame_end) == (1, 3)


def test_reimport_keeps_the_camera_path_as_scene_camera(empty_scene, street, tmp_path, capfd):
    """A plain import into a scene looking through a camera path adds the recorded camera without taking the
    path's place, and says so; without a camera path the new recorded camera is the scene camera, as before."""
    from tests_support import street_with_car

    scene = street_with_car(street, tmp_path, count=500)
    (path,) = _of_kind(scene, "camera_path")
    assert scene.camera == path
    capfd.readouterr()
    assert bpy.ops.scpainter.import_vggt(**_street_args(street)) == {"FINISHED"}
    assert scene.camera == path and len(_of_kind(scene, "recorded_camera")) == 2
    new_cam = _of_kind(scene, "recorded_camera")[1]
    assert (f"{new_cam.name!r} was added; the camera path {path.name!r} stays the scene camera"
            in capfd.readouterr().out)
    scene.camera = new_cam  # a recorded camera active: the next import's recorded camera takes over
    assert bpy.ops.scpainter.import_vggt(**_street_args(street)) == {"FINISHED"}
    assert scene.camera == _of_kind(scene, "recorded_camera")[2]


def test_replace_multi_camera_recording_replaces_every_sensor_camera(empty_scene, tmp_path):
    """A multi-camera recording replaced: no old sensor camera is left behind, the new ones take their names."""
    from scpainter_blender.core.vggt import npz as vggt_io
    from scpainter_blender.core.vggt import sensors as S
    from tests.core.geometry.rig_cases import predictions, small_rig

    arrays, sensors, _ = predictions(small_rig())
    path = str(tmp_path / "predictions.npz")
    vggt_io.save_predictions(path, **arrays)
    S.write(S.default_path(path), sensors)
    assert bpy.ops.scpainter.import_vggt(filepath=path, propose_boxes=False) == {"FINISHED"}
    before = sorted(o.name for o in bpy.context.scene.objects)
    old = {o.name: o.as_pointer() for o in bpy.context.scene.objects}
    assert bpy.ops.scpainter.replace_reconstruction(filepath=path, confidence_percentile=10.0) == {"FINISHED"}
    assert sorted(o.name for o in bpy.context.scene.objects) == before   # same names, nothing left over
    assert all(o.as_pointer() != old[o.name] for o in bpy.context.scene.objects)   # every one of them new
    cams = [o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "recorded_camera"]
    assert sorted(c["scpainter_sensor"] for c in cams) == ["CAM_BACK", "CAM_FRONT"]


def test_replace_multi_camera_recording_compares_scene_frames_and_sensors(empty_scene, tmp_path):
    """The "different frame count" warning counts scene frames, not VGGT frames (sensors × scene frames), and a
    different sensor set is said: two sensors at 6 scene frames (12 VGGT frames) replaced by three at 4 (12 VGGT
    frames too) warns of both; the same recording again warns of neither."""
    from scpainter_blender.core.vggt import npz as vggt_io
    from scpainter_blender.core.vggt import sensors as S
    from scpainter_blender.scene import replace
    from tests.core.geometry.rig_cases import predictions, small_rig

    paths = {}
    for key, names, samples in (("two", ("CAM_FRONT", "CAM_BACK"), 6),
                                ("three", ("CAM_FRONT", "CAM_BACK", "CAM_FRONT_LEFT"), 4)):
        arrays, sensors, _ = predictions(small_rig(names=names), samples=samples)
        (tmp_path / key).mkdir()
        paths[key] = str(tmp_path / key / "predictions.npz")
        vggt_io.save_predictions(paths[key], **arrays)
        S.write(S.default_path(paths[key]), sensors)
    assert bpy.ops.scpainter.import_vggt(filepath=paths["two"], propose_boxes=False) == {"FINISHED"}
    same = replace.replace_reconstruction(bpy.context, paths["two"])
    assert not [w for w in same.warnings if "scene frames" in w or "sensors" in w]
    r = replace.replace_reconstruction(bpy.context, paths["three"])
    assert ("the new recording has 4 scene frames, the old one 6: the frame range stays 1–6 (the camera paths are "
            "keyed over it); make new camera paths to follow the new recording") in r.warnings
    assert "the new recording's sensors are CAM_BACK, CAM_FRONT, CAM_FRONT_LEFT, the old one's CAM_BACK, " \
           "CAM_FRONT" in r.warnings
    back = replace.replace_reconstruction(bpy.context, paths["two"])
    assert "the new recording has 6 scene frames, the old one 4: the frame range stays 1–6 (the camera paths are " \
           "keyed over it); make new camera paths to follow the new recording" in back.warnings
    assert "the new recording's sensors are CAM_BACK, CAM_FRONT, the old one's CAM_BACK, CAM_FRONT, CAM_FRONT_LEFT: " \
           "the cameras of CAM_FRONT_LEFT are removed; check the camera paths made from them" in back.warnings
    cams = [o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "recorded_camera"]
    assert sorted(c["scpainter_sensor"] for c in cams) == ["CAM_BACK", "CAM_FRONT"]
