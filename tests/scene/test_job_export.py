"""Job export from a scene, checked against cameras and transforms computed independently."""

import os

import bpy
import numpy as np
import pytest

from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core import job as J
from scpainter_blender.core import shapes


def _build_scene(street, tmp_path):
    bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                  trajectory_path=os.path.join(street.root, "metric.npz"))
    bpy.ops.scpainter.new_camera_path(shift=2.0)
    ply = str(tmp_path / "car_01.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=500, seed=1))
    bpy.ops.scpainter.import_gaussians(filepath=ply, target_length=4.4)
    car = bpy.context.active_object
    car.rotation_euler = (0.0, 0.0, 0.3)
    for frame, x in ((1, 3.0), (16, 10.0)):  # drives 7 m along x over the clip, linearly
        car.location = (x, 12.0, 0.0)
        car.keyframe_insert("location", frame=frame)
    from bpy_extras import anim_utils

    ad = car.animation_data
    bag = anim_utils.action_get_channelbag_for_slot(ad.action, ad.action_slot) if hasattr(ad, "action_slot") \
        else ad.action
    for fc in bag.fcurves:
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"
    return car, ply


def test_export_matches_independent_cameras_and_transforms(empty_scene, street, tmp_path):
    car, ply = _build_scene(street, tmp_path)
    path = str(tmp_path / "out" / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
    job = J.load(path).to_dict()
    metric = street.metric()
    S = street.params.num_frames
    assert job["resolution"] == [street.params.width, street.params.height]
    assert [f["frame"] for f in job["frames"]] == list(range(1, S + 1))
    truth = metric["world_to_camera_left_2m"]
    for i, fr in enumerate(job["frames"]):
        assert np.abs(np.array(fr["K"]) - metric["K"][i]).max() < 1e-3
        w2c = np.array(fr["world_to_camera"])
        assert np.abs(C.camera_centers(w2c) - C.camera_centers(truth[i])).max() < 2e-3
        assert np.abs(w2c[:3, :3] - truth[i][:3, :3]).max() < 1e-4
        assert fr["source_frames"] == list(range(S))
    sc = job["scene"]
    assert J.resolve(path, sc["predictions"]) == os.path.abspath(street.predictions_path)
    assert np.abs(np.array(sc["vggt_to_world"]) - metric["vggt_to_world"]).max() < 1e-4
    assert "removal_boxes" not in sc and "generate" not in job
    # imported with the default depth-edge ratio: the job's own defaults (outliers included)
    assert sc["point_cleaning"] == J.PointCleaning().to_dict()
    # the asset, frame by frame: T(x(f), 12, 0) · Rz(0.3) · uniform scale · file_to_data, x linear in f
    (asset,) = job["assets"]
    assert asset["name"] == car.name and J.resolve(path, asset["ply"]) == os.path.abspath(ply)
    D = np.array(car["scpainter_file_to_data"]).reshape(4, 4)
    s = car.scale[0]
    c, sn = np.cos(0.3), np.sin(0.3)
    for f in range(1, S + 1):
        x = 3.0 + 7.0 * (f - 1) / 15.0
        M = np.eye(4)
        M[:3, :3] = s * np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]])
        M[:3, 3] = [x, 12.0, 0.0]
        assert np.abs(np.array(asset["object_to_world"][str(f)]) - M @ D).max() < 1e-5, f
    assert job["output_dir"] == "."
    # a .blend saved before the a_to_b rule holds the transforms under their old names: the export is the same
    pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
    for obj, new, old in ((pts, "scpainter_vggt_to_world", "scpainter_world_from_vggt"),
                          (car, "scpainter_file_to_data", "scpainter_data_from_file")):
        obj[old] = obj[new]
        del obj[new]
    old_path = str(tmp_path / "out" / "job_old_names.json")
    assert bpy.ops.scpainter.export_job(filepath=old_path) == {"FINISHED"}
    assert J.load(old_path).to_dict() == job


def test_leaves_out_what_the_scene_does_not_use(empty_scene, street, tmp_path):
    car, _ = _build_scene(street, tmp_path)
    car["scpainter_review"] = "rejected"  # stage-2 rejected assets are not rendered
    pts = next(o for o in empty_scene.objects if o.get("scpainter_kind") == "points")
    pts.location.x += 1.0  # the artist nudged the reconstruction: vggt_to_world follows
    from scpainter_blender.scene import node_groups, points

    mod = points.points_modifier(pts)
    node_groups.set_input(mod, "Current Frame Only", True)
    node_groups.set_input(mod, "Frame Window", 1)
    job = bpy.ops.scpainter.export_job(filepath=str(tmp_path / "job.json"))
    job = J.load(tmp_path / "job.json").to_dict()
    assert "assets" not in job
    W = np.array(job["scene"]["vggt_to_world"])
    assert np.abs(W[:3, 3] - (street.metric()["vggt_to_world"][:3, 3] + [1, 0, 0])).max() < 1e-4
    assert job["frames"][0]["source_frames"] == [0, 1]
    assert job["frames"][5]["source_frames"] == [4, 5, 6]
    assert job["frames"][-1]["source_frames"] == [14, 15]


def test_scene_imported_before_the_depth_edge_setting_exports_it_off(empty_scene, tmp_path):
    """A points object without ``scpainter_depth_edge_ratio`` (imported before the import had the depth-edge test)
    shows unfiltered points: its job says null (off), so the backend loads the same points, not the default's."""
    from backend.render import frames
    from vggt_cases import drive, write

    arrays, _, _ = drive(S=2, H=12, W=16)   # random depth per pixel: every pixel is a depth edge
    path = write(tmp_path, arrays)
    assert bpy.ops.scpainter.import_vggt(filepath=path, confidence_percentile=0.0,
                                         depth_edge_ratio=0.0) == {"FINISHED"}   # what an old import did
    pts = next(o for o in empty_scene.objects if o.get("scpainter_kind") == "points")
    assert pts["scpainter_depth_edge_ratio"] == 0.0
    for o in (pts, empty_scene.camera):
        del o["scpainter_depth_edge_ratio"]
    job_path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    job = J.load(job_path)
    assert job.to_dict()["scene"]["point_cleaning"] == {"depth_edge_ratio": None,
                                                        "outliers": J.PointCleaning().to_dict()["outliers"]}
    scene = frames.load_scene(job, job_path, "cpu")
    assert len(scene.xyz) == len(pts.data.vertices) == 2 * 12 * 16 and scene.cleaning["depth_edge_points"] == 0


def test_needs_a_camera_and_a_saved_blend(empty_scene, tmp_path):
    # bad input (a SceneError): the report names the .blend and the property, and says what to do
    with pytest.raises(RuntimeError, match=r"\(unsaved \.blend\): scene\.scpainter_output_dir: .*not saved yet.*"
                                           r"save the \.blend"):
        bpy.ops.scpainter.export_job()
    with pytest.raises(RuntimeError, match=r"scene\.camera: the scene has no active camera \(add one"):
        bpy.ops.scpainter.export_job(filepath=str(tmp_path / "job.json"))
    assert not (tmp_path / "job.json").exists()


def test_an_operator_reports_a_bug_by_its_type(addon, empty_scene, tmp_path, monkeypatch, capfd):
    """Anything but an InputError (a plain ValueError included) is a bug of the add-on: the report says so with the
    exception's type, the traceback goes to the console."""
    import sys

    def shape_bug(*args, **kwargs):
        raise ValueError("shape bug: (3, 4) and (4, 4)")

    monkeypatch.setattr(sys.modules[addon + ".scpainter_blender.scene.job_export"], "export_job", shape_bug)
    with pytest.raises(RuntimeError, match=r"ValueError: shape bug: \(3, 4\) and \(4, 4\) \(an internal error in "
                                           r"SCPainter, not a problem with the input"):
        bpy.ops.scpainter.export_job(filepath=str(tmp_path / "job.json"))
    err = capfd.readouterr().err
    assert "Traceback (most recent call last)" in err and "in shape_bug" in err


def test_labels_fields_fps_and_recorded_frames(empty_scene, tmp_path):
    """``fps`` is the scene's (fps / fps_base); ``scene.recorded_frames`` the scene frames the recording covers,
    from the recorded camera's first frame and the points' frame count; a .blend imported before these properties
    exports without it."""
    from vggt_cases import drive, write

    arrays, _, _ = drive(S=3, H=12, W=16)
    path = write(tmp_path, arrays)
    scene = empty_scene
    scene.frame_start = 5  # the import starts the recording at the scene's first frame
    assert bpy.ops.scpainter.import_vggt(filepath=path, depth_edge_ratio=0.0) == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (5, 7)
    scene.frame_end = 9  # the output runs past the recording
    scene.render.fps, scene.render.fps_base = 30, 1.001
    job_path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    job = J.load(job_path)
    assert job.fps == scene.render.fps / scene.render.fps_base == pytest.approx(30 / 1.001, rel=1e-7)
    assert job.scene.recorded_frames == [5, 7]
    assert [f.frame for f in job.frames] == [5, 6, 7, 8, 9]
    scene.frame_step = 2  # every other frame, as Blender's own render takes them
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    assert [f.frame for f in J.load(job_path).frames] == [5, 7, 9]
    scene.frame_step = 1
    pts = next(o for o in scene.objects if o.get("scpainter_kind") == "points")
    del pts["scpainter_num_frames"]  # an old .blend (or a recorded camera without its first frame)
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    assert "recorded_frames" not in J.load(job_path).to_dict()["scene"]
    scene.render.fps, scene.render.fps_base = 1000, 1.0  # beyond what a job holds: not written, not refused
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    assert J.load(job_path).fps is None


def test_multi_camera_recording_frames_are_scene_frames(empty_scene, tmp_path):
    """A multi-camera recording (CAM_FRONT and CAM_BACK, four timestamps: VGGT frames F0 B0 F1 B1 ...) imported at
    scene frame 5 with *Current Frame Only* and a Frame Window of 1: an output frame takes every sensor's frames
    grouped within one scene frame of it, as the viewport shows them; ``recorded_frames`` spans the four scene
    frames (5-8), not the eight VGGT frames. Moving the Frame Offset moves the points' frames in both."""
    from scpainter_blender.core.vggt import npz as vggt_io, sensors as S
    from scpainter_blender.scene import job_export, node_groups, points
    from tests.core.geometry.rig_cases import predictions, small_rig
    from tests_support import evaluated_counts

    arrays, sensors, _ = predictions(small_rig())
    path = str(tmp_path / "predictions.npz")
    vggt_io.save_predictions(path, **arrays)
    S.write(S.default_path(path), sensors)
    scene = empty_scene
    scene.frame_start = 5
    assert bpy.ops.scpainter.import_vggt(filepath=path, propose_boxes=False, current_frame_only=True, frame_window=1,
                                         confidence_percentile=0.0, depth_edge_ratio=0.0) == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (5, 8)
    pts = next(o for o in scene.objects if o.get("scpainter_kind") == "points")
    assert list(pts["scpainter_scene_frames"]) == [0, 0, 1, 1, 2, 2, 3, 3]
    want = {5: [0, 1, 2, 3], 6: [0, 1, 2, 3, 4, 5], 7: [2, 3, 4, 5, 6, 7], 8: [4, 5, 6, 7]}
    per_frame = arrays["depth"].shape[1] * arrays["depth"].shape[2]
    for f, frames in want.items():
        assert job_export.source_frames(pts, f) == frames, f
        scene.frame_set(f)
        assert evaluated_counts(pts)[0] == len(frames) * per_frame, f
    assert job_export.recorded_frames(scene, pts) == [5, 8]
    node_groups.set_input(points.points_modifier(pts), "Frame Offset", 6)  # scene frame 6 shows the first
    pts.update_tag()
    scene.frame_set(6)
    assert job_export.source_frames(pts, 6) == [0, 1, 2, 3] and evaluated_counts(pts)[0] == 4 * per_frame
    job_path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    job = J.load(job_path)
    assert [f.source_frames for f in job.frames] == [[0, 1], [0, 1, 2, 3], [0, 1, 2, 3, 4, 5], [2, 3, 4, 5, 6, 7]]
    assert job.scene.recorded_frames == [5, 8]


def test_frames_outside_the_recording_are_warned(empty_scene, addon, tmp_path, capfd):
    """A frame range reaching past the recording (the camera stands still there, the frames are mostly holes) is
    exported as asked, with a warning from the operator, and the same words under the panel's Job box
    (``job_notes``); two reconstructions that render are said there as the refusal the export will be."""
    import sys

    from vggt_cases import drive, write

    job_export = sys.modules[addon + ".scpainter_blender.scene.job_export"]
    arrays, _, _ = drive(S=3, H=12, W=16)
    path = write(tmp_path, arrays)
    scene = empty_scene
    assert bpy.ops.scpainter.import_vggt(filepath=path, depth_edge_ratio=0.0) == {"FINISHED"}
    assert job_export.warnings(bpy.context) == [] and job_export.job_notes(bpy.context) == []
    scene.frame_start, scene.frame_end = 0, 5  # one frame before the recording (1-3), two after
    capfd.readouterr()
    job_path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    said = "3 of the 6 output frames (0, 4–5) lie outside the recording (frames 1–3)"
    assert f"Warning: {said}" in capfd.readouterr().out
    assert [f.frame for f in J.load(job_path).frames] == [0, 1, 2, 3, 4, 5]  # written all the same
    (w,) = job_export.warnings(bpy.context)
    assert w["code"] == "outside_recording" and w["message"].startswith(said)
    assert "set the frame range to 1–3" in w["message"]
    assert job_export.job_notes(bpy.context) == [("WARNING", w["message"])]
    assert bpy.ops.scpainter.import_vggt(filepath=path, depth_edge_ratio=0.0) == {"FINISHED"}  # a second cloud
    ((level, text),) = job_export.job_notes(bpy.context)
    assert level == "ERROR" and text.startswith("2 reconstructions render") and "Replace Reconstruction" in text


def _car_and_two_cameras(scene, tmp_path):
    """A 60-Gaussian car (so the job has something to render) and two cameras A and B looking at it from 8 m and
    10 m; A is the scene camera. Returns (car, A, B)."""
    ply = str(tmp_path / "car.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=60, seed=1))
    assert bpy.ops.scpainter.import_gaussians(filepath=ply, target_length=4.4) == {"FINISHED"}
    car = bpy.context.active_object
    cams = []
    for name, y in (("A", -8.0), ("B", -10.0)):
        cam = bpy.data.objects.new(name, bpy.data.cameras.new(name))
        scene.collection.objects.link(cam)
        cam.location, cam.rotation_euler = (0.5, y, 1.0), (np.pi / 2, 0.0, 0.0)
        cams.append(cam)
    scene.camera = cams[0]
    return car, *cams


def test_each_frame_is_seen_by_the_camera_blender_renders_it_with(empty_scene, addon, tmp_path):
    """Timeline markers bound to cameras switch the scene camera: each output frame's K and world_to_camera are
    those of the camera Blender's own frame evaluation makes the scene camera (A for 1–5, B for 6–10, with its own
    lens); a camera given to the export (a camera path's run) is used for every frame. A camera the renderer cannot
    draw — orthographic, panoramic — is refused naming it, its type and the frame, never exported as a pinhole."""
    import sys

    job_export = sys.modules[addon + ".scpainter_blender.scene.job_export"]
    camera_mod = sys.modules[addon + ".scpainter_blender.scene.camera"]
    scene = empty_scene
    _, A, B = _car_and_two_cameras(scene, tmp_path)
    B.data.lens = 35.0
    scene.frame_start, scene.frame_end = 1, 10
    scene.timeline_markers.new("A", frame=1).camera = A
    scene.timeline_markers.new("B", frame=6).camera = B
    path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
    job = J.load(path)
    seen = []
    for fr in job.frames:
        scene.frame_set(fr.frame)  # Blender's own switch, frame by frame
        cam = scene.camera
        seen.append(cam.name)
        assert np.allclose(fr.world_to_camera, camera_mod.world_to_camera(cam), atol=1e-9), fr.frame
        assert np.allclose(fr.K, camera_mod.K_of_camera_object(scene, cam), atol=1e-9), fr.frame
    assert seen == ["A"] * 5 + ["B"] * 5
    assert not np.allclose(job.frames[0].K, job.frames[-1].K)
    fixed = job_export.build_job(bpy.context, path, camera=A)  # a camera path's run: its own camera throughout
    assert all(np.allclose(f.world_to_camera, job.frames[0].world_to_camera) for f in fixed.frames)

    B.data.type = "ORTHO"
    with pytest.raises(RuntimeError, match=r"objects\['B'\]\.data\.type: the camera at frame 6 is orthographic "
                                           r"\(ORTHO\): the renderer draws perspective cameras only \(set its"):
        bpy.ops.scpainter.export_job(filepath=path)
    B.data.type = "PANO"
    with pytest.raises(RuntimeError, match=r"objects\['B'\]\.data\.type: the camera at frame 6 is panoramic"):
        bpy.ops.scpainter.export_job(filepath=path)
    with pytest.raises(Exception, match=r"objects\['B'\]\.data\.type: the camera is panoramic \(\w+\) \(PANO\)"):
        job_export.build_job(bpy.context, path, camera=B)
    assert J.load(path).to_dict() == job.to_dict()  # nothing written by a refusal


def test_a_cropped_render_region_is_the_jobs_image_checked_with_cycles(empty_scene, addon, tmp_path):
    """*Render Region* with *Crop to Render Region*: the job's size is the image Cycles writes and its K the whole
    frame's with the principal point moved to the region's corner, so a lit point projects where Cycles draws it;
    a region without crop is the whole frame (Blender writes a whole-frame image); the percentage rounds down as
    Blender's does (23 px at 50 % is 11)."""
    import sys

    camera_mod = sys.modules[addon + ".scpainter_blender.scene.camera"]
    scene = empty_scene
    car, A, _ = _car_and_two_cameras(scene, tmp_path)
    car.location = (0.0, -20.0, 0.0)  # behind the cameras: Cycles sees only the lamp below
    lamp_at = np.array([0.9, 0.0, 1.4])
    mesh = bpy.data.meshes.new("lamp")
    h = 0.1
    mesh.from_pydata([(-h, 0, -h), (h, 0, -h), (h, 0, h), (-h, 0, h)], [], [(0, 1, 2, 3)])
    lamp = bpy.data.objects.new("lamp", mesh)
    lamp.location = lamp_at.tolist()
    scene.collection.objects.link(lamp)
    from scpainter_blender.scene import compat

    mat = bpy.data.materials.new("white")
    tree = compat.node_tree(mat, clear=True)
    tree.links.new(tree.nodes.new("ShaderNodeEmission").outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs[0])
    mesh.materials.append(mat)
    r = scene.render
    scene.render.engine, scene.cycles.samples, scene.cycles.device = "CYCLES", 16, "CPU"
    r.filter_size = 0.01  # no pixel filter: the lamp's pixels are its own
    r.resolution_x, r.resolution_y, r.resolution_percentage = 80, 60, 100
    r.use_border = r.use_crop_to_border = True
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 0.43, 0.93, 0.33, 0.9
    scene.frame_start = scene.frame_end = 1
    path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
    job = J.load(path)
    r.filepath = str(tmp_path / "r.exr")
    r.image_settings.file_format = "OPEN_EXR"  # linear: a partly covered pixel weighs what it covers
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(r.filepath, check_existing=False)
    w, h = img.size
    pix = np.array(img.pixels[:]).reshape(h, w, 4)[::-1, :, 0]  # rows down
    bpy.data.images.remove(img)
    assert (job.width, job.height) == (w, h) == (40, 35)
    weight = np.clip(pix, 0.0, 1.0)
    assert weight.sum() > 4, "the lamp is in the cropped image"
    v, u = np.mgrid[:h, :w] + 0.5  # pixel centres
    seen = [(u * weight).sum() / weight.sum(), (v * weight).sum() / weight.sum()]
    x = job.frames[0].K @ (job.frames[0].world_to_camera @ np.append(lamp_at, 1.0))[:3]
    assert np.abs(x[:2] / x[2] - seen).max() < 0.25, (x[:2] / x[2], seen)
    r.use_crop_to_border = False  # a region without crop: Blender writes the whole frame
    assert bpy.ops.scpainter.export_job(filepath=path) == {"FINISHED"}
    whole = J.load(path)
    assert (whole.width, whole.height) == (80, 60)
    assert np.allclose(whole.frames[0].K, camera_mod.K_of_camera_object(scene, A))
    assert np.allclose(whole.frames[0].K[:2, 2] - job.frames[0].K[:2, 2], [34, 60 - 54])
    r.use_border = False
    r.resolution_x, r.resolution_y, r.resolution_percentage = 23, 13, 50
    assert camera_mod.render_size(scene) == (11, 6)
