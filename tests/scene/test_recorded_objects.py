"""Recorded objects in Blender: the street's own parked cars imported from a scpainter.objects/1 file with the
reconstruction (as the demo does), checked against the street's ground truth through the import's estimated metric
transform; written into the job; a removal box made from one; a bad file leaves the scene as it was."""

import numpy as np
import pytest

#: How far an imported car's box may lie from the street's ground truth carried into the imported world (the
#: estimated vggt_to_world against the true one). Measured on the default street with the camera-height scale:
#: centres ≤ 0.0026 m, axes < 0.001°, sizes the file's; the bounds keep a margin of ~8× on the centres.
CENTRE_M = 0.02
ANGLE_DEG = 0.1


def _import_with_objects(street, tmp_path, **kw):
    import bpy

    path = street.write_objects(str(tmp_path / "street_objects.json"))
    r = bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="CAMERA_HEIGHT",
                                      camera_height=street.params.camera_height_m, objects=path, **kw)
    assert r == {"FINISHED"}
    return path


def _truth_in_imported_world(street, pts):
    """{track id: (box_to_world, size)} of the street's cars carried into the imported world: imported ∘ true⁻¹."""
    from scpainter_blender.core.geometry import boxes, similarity
    from scpainter_blender.scene import keys

    W_est = np.array(pts[keys.VGGT_TO_WORLD], np.float64).reshape(4, 4)
    G = W_est @ np.linalg.inv(street.metric()["vggt_to_world"])   # street world -> imported world (a similarity)
    s, _, _ = similarity.decompose_similarity(G)
    out = {}
    for c in street.info["cars"]:
        T, size = boxes.place_box(np.eye(4), np.asarray(c["size"]), G @ np.asarray(c["box_to_world"]))
        out[f"street_car_{c['instance']}"] = (T, size / s)   # the file's metric sizes, kept as they are
    return out


def test_the_streets_cars_land_on_the_ground_truth_and_go_into_the_job(empty_scene, street, tmp_path):
    import bpy

    from scpainter_blender.core import job as job_mod
    from scpainter_blender.scene import job_export, keys, kinds, placement, recorded_objects

    _import_with_objects(street, tmp_path)
    scene = bpy.context.scene
    pts = kinds.point_cloud(scene)
    objs = kinds.recorded_objects(scene)
    assert len(objs) == len(street.info["cars"]) == 5
    assert all(o.users_collection[0].name == recorded_objects.COLLECTION and o.empty_display_size == 0.5 and
               o[keys.CLASS] == "car" and o[keys.IGNORE] is False or o[keys.IGNORE] == 0 for o in objs)
    truth = _truth_in_imported_world(street, pts)
    centre_err, angle_err = [], []
    n = street.params.num_frames
    for o in objs:
        assert list(o[keys.TRACK_FRAMES]) == list(range(scene.frame_start, scene.frame_start + n))
        for f in (scene.frame_start, scene.frame_start + n - 1):
            scene.frame_set(f)
            T, size = placement.box_matrix(o)
            T0, size0 = truth[o[keys.TRACK_ID]]
            np.testing.assert_allclose(size, size0, atol=1e-4)
            centre_err.append(np.linalg.norm(T[:3, 3] - T0[:3, 3]))
            angle_err.append(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3].T @ T0[:3, :3]) - 1) / 2, -1, 1))))
    print(f"recorded cars against the ground truth: centres ≤ {max(centre_err):.4f} m, "
          f"axes ≤ {max(angle_err):.3f}°")
    assert max(centre_err) < CENTRE_M and max(angle_err) < ANGLE_DEG

    # the job (every camera path's) carries them as scene.recorded_objects, each box where the scene has it
    job = job_export.build_job(bpy.context, str(tmp_path / "job.json"))
    rec = {o.id: o for o in job.scene.recorded_objects}
    assert sorted(rec) == sorted(truth)
    scene.frame_set(scene.frame_start)
    for o in objs:
        T, _ = placement.box_matrix(o)
        np.testing.assert_allclose(rec[o[keys.TRACK_ID]].boxes[scene.frame_start], T, atol=1e-9)
    again = job_mod.Scene.from_dict(job.scene.to_dict(), "job.json").recorded_objects   # valid job JSON
    assert [o.id for o in again] == [o.id for o in job.scene.recorded_objects]

    # a removal box from a recorded car: the same box, at the current frame
    bpy.ops.object.select_all(action="DESELECT")
    objs[0].select_set(True)
    bpy.context.view_layer.objects.active = objs[0]
    assert bpy.ops.scpainter.removal_box_from_recorded() == {"FINISHED"}
    box = kinds.removal_boxes(scene)[0]
    np.testing.assert_allclose(placement.box_matrix(box)[1], placement.box_matrix(objs[0])[1], atol=1e-6)


def test_a_bad_objects_file_imports_nothing(empty_scene, street, tmp_path):
    import bpy

    from scpainter_blender.core import files
    from scpainter_blender.scene import kinds

    path = street.write_objects(str(tmp_path / "o.json"))
    doc = files.read_json(path)
    doc["num_frames"] = street.params.num_frames + 1  # a recording one frame longer than the reconstruction
    doc["world_to_camera"].append(doc["world_to_camera"][-1])
    bad = tmp_path / "bad.json"
    bad.write_text(__import__("json").dumps(doc))
    with pytest.raises(RuntimeError, match=r"bad.json: \(frames\): the recording has 17 frames, the "
                                           r"reconstruction 16"):
        bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, objects=str(bad))
    assert not list(bpy.context.scene.objects) and not kinds.recorded_objects(bpy.context.scene)

    # into a scene already imported (operators/recorded_objects.py); a second time is refused, adding nothing
    assert bpy.ops.scpainter.import_vggt(filepath=street.predictions_path) == {"FINISHED"}
    assert bpy.ops.scpainter.import_recorded_objects(filepath=path) == {"FINISHED"}
    assert len(kinds.recorded_objects(bpy.context.scene)) == 5
    with pytest.raises(RuntimeError, match="already has recorded objects of tracks"):
        bpy.ops.scpainter.import_recorded_objects(filepath=path)
    assert len(kinds.recorded_objects(bpy.context.scene)) == 5



@pytest.mark.parametrize("missing", [None, 5])
def test_a_multi_camera_recordings_objects_import_later_as_with_the_import(empty_scene, tmp_path, missing):
    """A multi-camera recording (two sensors, 8 VGGT frames at 4 scene frames): *Import Recorded Objects* after the
    import maps the boxes as the import does with ``objects``: through the camera of the sensor the recording's
    camera names (CAM_BACK here; the reference CAM_FRONT by default), recording frame i at that sensor's i-th scene
    frame, onto the boxes' true world poses. ``missing``: CAM_BACK's image of scene frame 3 left out (VGGT frame 5):
    its three frames are at scene frames 1, 2 and 4."""
    import json

    import bpy

    from scpainter_blender.core.geometry import cameras
    from scpainter_blender.core.recording import plain
    from scpainter_blender.core.vggt import npz as vggt_io
    from scpainter_blender.core.vggt import sensors as S
    from scpainter_blender.scene import kinds, recorded_objects
    from tests.core.geometry.rig_cases import predictions, small_rig
    from tests.core.recording.recording_fixtures import pose, yaw

    arrays, sensors, c2w = predictions(small_rig())       # frames F0 B0 F1 B1 ...: the import's world is c2w's
    if missing is not None:
        keep = np.arange(len(c2w)) != missing
        arrays = {k: v[keep] for k, v in arrays.items()}
        sensors = S.Sensors([s for s, k in zip(sensors.sensor, keep) if k], sensors.timestamp_us[keep])
        c2w = c2w[keep]
    path = str(tmp_path / "predictions.npz")
    vggt_io.save_predictions(path, **arrays)
    S.write(S.default_path(path), sensors)
    files, truth = {}, {}
    for name in ("CAM_FRONT", "CAM_BACK"):               # the boxes in the world, with the sensor's own path
        idx = sensors.frames_of(name)
        n = len(idx)
        truth[name] = [{"id": "car-a", "class": "car", "size": [1.8, 4.4, 1.5],
                        "boxes": {f: pose(yaw(0.3), [12.0, -3.0, 0.75]) for f in range(n)}},
                       {"id": "ped-b", "class": "pedestrian", "size": [0.6, 0.7, 1.8],
                        "boxes": {f: pose(yaw(1.2), [-6.0 + f, 4.0, 0.9]) for f in (1, 2)}}]
        files[name] = str(tmp_path / f"objects_{name}.json")
        doc = plain.document(n, truth[name], cameras.rigid_inverse(c2w[idx]))
        (tmp_path / f"objects_{name}.json").write_text(json.dumps(doc))
    scene_frame = {name: 1 + sensors.scene_frames()[sensors.frames_of(name)] for name in files}
    assert list(scene_frame["CAM_BACK"]) == ([1, 2, 3, 4] if missing is None else [1, 2, 4])

    def boxes():
        objs = recorded_objects.job_objects(bpy.context.scene, list(range(1, 5)))
        return {o.id: o.boxes for o in objs}

    def check(got, name):
        assert sorted(got) == ["car-a", "ped-b"]
        for t in truth[name]:
            assert sorted(got[t["id"]]) == [scene_frame[name][f] for f in sorted(t["boxes"])]
            for f, B in t["boxes"].items():
                np.testing.assert_allclose(got[t["id"]][scene_frame[name][f]], B, atol=1e-4)

    def clear():
        for o in kinds.recorded_objects(bpy.context.scene):
            bpy.data.objects.remove(o, do_unlink=True)

    assert bpy.ops.scpainter.import_vggt(filepath=path, propose_boxes=False, objects=files["CAM_BACK"],
                                         objects_camera="CAM_BACK") == {"FINISHED"}
    at_import = boxes()
    check(at_import, "CAM_BACK")
    clear()
    assert bpy.ops.scpainter.import_recorded_objects(filepath=files["CAM_BACK"], objects_camera="CAM_BACK") \
        == {"FINISHED"}
    later = boxes()
    check(later, "CAM_BACK")
    for tid, bs in at_import.items():
        for f, B in bs.items():
            np.testing.assert_allclose(later[tid][f], B, atol=1e-5)
    clear()                                              # no camera named: the reference sensor's
    assert bpy.ops.scpainter.import_recorded_objects(filepath=files["CAM_FRONT"]) == {"FINISHED"}
    check(boxes(), "CAM_FRONT")
