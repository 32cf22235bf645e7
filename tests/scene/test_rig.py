"""scene/rig.py: *Add Camera Rig* on a camera path, the rig read back as a ``core.rig.Rig``, and its job (through the
real bpy: a camera keyed along a short drive, no street)."""

import os
import sys

import bpy
import numpy as np
import pytest

from scpainter_blender.core import rig as core_rig
from scpainter_blender.core.geometry import cameras as C


def _modules(addon):
    return (sys.modules[addon + ".scpainter_blender.scene.rig"], sys.modules[addon + ".scpainter_blender.scene.kinds"])


def _path_camera(scene):
    """A camera path: a camera keyed over frames 1-5, 100 m from the origin (float32 matters there), turning."""
    cam = bpy.data.objects.new("Path", bpy.data.cameras.new("Path"))
    scene.collection.objects.link(cam)
    cam["scpainter_kind"] = "camera_path"
    cam.rotation_mode = "QUATERNION"
    for frame, x, yaw in ((1, 100.0, 0.0), (5, 108.0, 0.2)):
        cam.location = (x, -50.0, 1.5)
        cam.rotation_quaternion = (np.cos(yaw / 2), 0, 0, np.sin(yaw / 2))
        cam.rotation_quaternion = (cam.rotation_quaternion @ _euler_x(np.pi / 2))  # look along +y, level
        cam.keyframe_insert("location", frame=frame)
        cam.keyframe_insert("rotation_quaternion", frame=frame)
    scene.frame_start, scene.frame_end = 1, 5
    scene.camera = cam
    bpy.context.view_layer.objects.active = cam
    return cam


def _euler_x(angle):
    from mathutils import Euler

    return Euler((angle, 0.0, 0.0)).to_quaternion()


def _camera_to_world(obj):
    return C.rigid_inverse(C.world_to_camera_from_blender(np.array(obj.matrix_world, dtype=np.float64)))


def test_add_camera_rig_follows_the_path_and_reads_back_the_preset(addon, empty_scene):
    """The nuScenes preset at scale 1: one camera per sensor (named after it, its resolution stored, lens and shifts
    from K), the LiDAR, all under a rig empty that puts CAM_FRONT on the camera path at every frame; read back it is
    the preset (to 1e-6: the float64 values it was added with, which Blender's float32 still rounds to)."""
    rig_scene, kinds = _modules(addon)
    scene = empty_scene
    path = _path_camera(scene)
    assert bpy.ops.scpainter.add_camera_rig(preset="nuscenes", scale=1.0) == {"FINISHED"}
    rig_obj = kinds.rig_of(path)
    assert rig_obj.name == "SCPainter Rig" and rig_obj["scpainter_kind"] == "rig" and rig_obj.parent == path
    assert bpy.context.active_object == rig_obj
    preset = core_rig.preset("nuscenes")
    cams = kinds.rig_sensors(rig_obj, kinds.RIG_CAMERA)
    assert [c.name for c in cams] == list(core_rig.NUSCENES_CAMERAS)
    assert all(c["scpainter_kind"] == "rig_camera" and list(c["scpainter_resolution"]) == [1600, 900] for c in cams)
    (lidar,) = kinds.rig_sensors(rig_obj, kinds.RIG_LIDAR)
    assert lidar.name == "LIDAR_TOP" and lidar["scpainter_lidar_model"] == "nuscenes-32"
    for f in (1, 3, 5):
        scene.frame_set(f)
        got = rig_scene.read_rig(rig_obj)
        assert got.to_dict().keys() == preset.to_dict().keys() and got.name == "nuscenes"
        for a, b in zip(got.cameras, preset.cameras):
            assert a.name == b.name and a.resolution == b.resolution
            assert np.abs(a.K - b.K).max() < 1e-6 and np.abs(a.camera_to_ego - b.camera_to_ego).max() < 1e-6
        assert np.abs(got.lidar.lidar_to_ego - preset.lidar.lidar_to_ego).max() < 1e-6
        # the path camera is CAM_FRONT: the rig empty is core.rig.ego_path's ego pose; every camera hangs from it
        ego = core_rig.ego_path(_camera_to_world(path)[None], preset, "CAM_FRONT")[0]
        assert np.abs(rig_scene.ego_to_world(rig_obj) - ego).max() < 3e-5, f
        for c, rc in zip(cams, preset.cameras):
            assert np.abs(_camera_to_world(c) - core_rig.camera_to_world(ego, rc.camera_to_ego)).max() < 5e-5, c.name
            # what Blender's camera itself holds gives the K (float32 lens and shifts: to 1e-3 px)
            bc = C.blender_camera_from_K(rc.K, 1600, 900)
            assert abs(c.data.lens - bc.lens) < 1e-5 and abs(c.data.shift_x - bc.shift_x) < 1e-7
    # the quarter-size default: 400 x 225 with K scaled to the same rays; without the LiDAR on request
    assert bpy.ops.scpainter.add_camera_rig(preset="nuscenes", lidar=False) == {"FINISHED"}
    rig_obj = kinds.rig_of(path)  # replaced: one rig per camera path
    assert len([o for o in scene.objects if o.get("scpainter_kind") == "rig"]) == 1
    got = rig_scene.read_rig(rig_obj)
    assert got.lidar is None and all(c.resolution == (400, 225) for c in got.cameras)
    assert np.abs(got.cameras[3].K - preset.scaled(0.25).cameras[3].K).max() < 1e-6
    assert bpy.ops.scpainter.remove_camera_rig() == {"FINISHED"}
    assert kinds.rig_of(path) is None and not [o for o in scene.objects if o != path]
    assert not [d for d in bpy.data.cameras if d.name.startswith("CAM_")]


def test_edits_are_what_the_rig_reads_and_bad_ones_are_named(addon, empty_scene):
    """The rig is editable: a turned camera and a longer lens are what is read (camera_to_ego = its matrix relative
    to the rig · the OpenCV axes; K from the lens at its stored resolution); an edit the rig cannot be is refused
    naming the object and the field."""
    rig_scene, kinds = _modules(addon)
    path = _path_camera(empty_scene)
    assert bpy.ops.scpainter.add_camera_rig(preset="nuscenes", scale=0.25) == {"FINISHED"}
    rig_obj = kinds.rig_of(path)
    left = bpy.data.objects["CAM_FRONT_LEFT"]
    back = bpy.data.objects["CAM_BACK"]
    before = rig_scene.read_rig(rig_obj)
    turn = np.eye(4)
    turn[:3, :3] = C.quaternion_to_rotation(np.array([np.cos(0.05), 0.0, 0.0, np.sin(0.05)]))  # 0.1 rad about ego z
    turn[:3, 3] = [0.0, 0.0, 0.2]  # and 20 cm up
    left.matrix_basis = rig_scene._matrix(turn @ np.array(left.matrix_basis, dtype=np.float64))
    back.data.lens *= 1.5
    after = rig_scene.read_rig(rig_obj)
    i_left, i_back = core_rig.NUSCENES_CAMERAS.index("CAM_FRONT_LEFT"), core_rig.NUSCENES_CAMERAS.index("CAM_BACK")
    want = turn @ before.cameras[i_left].camera_to_ego
    assert np.abs(after.cameras[i_left].camera_to_ego - want).max() < 1e-5
    assert np.allclose(after.cameras[i_back].K[0, 0], 1.5 * before.cameras[i_back].K[0, 0], rtol=1e-6)
    untouched = [i for i in range(6) if i not in (i_left, i_back)]
    assert all(np.array_equal(after.cameras[i].K, before.cameras[i].K) for i in untouched)
    back.data.lens = 1e5  # a field of view no camera has at 400 x 225
    with pytest.raises(Exception, match=r"objects\['CAM_BACK'\] \(rig\.cameras\[3\]\.K\): does not fit the camera's "
                                        r"400 x 225 resolution"):
        rig_scene.read_rig(rig_obj)
    back.data.lens = 20.0
    back["scpainter_resolution"] = "400 x 225"  # typed over by hand
    with pytest.raises(Exception, match=r"objects\['CAM_BACK'\]\['scpainter_resolution'\]: expected two positive "
                                        r"numbers, got '400 x 225'"):
        rig_scene.read_rig(rig_obj)
    back["scpainter_resolution"] = [400, 225]
    back["scpainter_sensor"] = "CAM_FRONT"  # two sensors with one name
    with pytest.raises(Exception, match=r"objects\['CAM_BACK'\] \(rig\.cameras\[3\]\.name\): 'CAM_FRONT' is also the "
                                        r"name of rig\.cameras\[0\]: two sensors with one name"):
        rig_scene.read_rig(rig_obj)


class _Layout:
    """What the panel's rig section asks of a UILayout, recorded; each property it shows is resolved on its data
    (a path that does not exist would draw nothing in Blender, silently) and each operator must be registered."""

    def __init__(self, drawn):
        self.drawn = drawn

    def box(self):
        return self

    column = row = lambda self, **kw: self

    def label(self, text="", icon="NONE"):
        self.drawn.append(("label", text))

    def prop(self, data, path, text=""):
        data.path_resolve(path)
        self.drawn.append(("prop", data.name, path))

    def operator(self, idname, **kw):
        assert hasattr(getattr(bpy.ops, idname.split(".")[0]), idname.split(".")[1]), idname
        self.drawn.append(("operator", idname))

    def operator_menu_enum(self, idname, prop, **kw):
        self.operator(idname)


def test_panel_shows_the_rig_of_the_active_path(addon, empty_scene):
    """The panel's rig section: Add Camera Rig (its presets) without one; with one, each camera with its resolution
    and lens, the LiDAR and its model, Replace and Remove; a selected rig camera shows its own path's rig."""
    main = sys.modules[addon + ".panels.main"]
    path = _path_camera(empty_scene)
    drawn = []
    main.SCPAINTER_PT_main.draw_rig(bpy.context, _Layout(drawn))
    assert drawn == [("label", "Camera Rig of Path"), ("operator", "scpainter.add_camera_rig")]
    assert bpy.ops.scpainter.add_camera_rig(preset="front", scale=0.25) == {"FINISHED"}
    bpy.context.view_layer.objects.active = bpy.data.objects["CAM_FRONT"]
    drawn.clear()
    main.SCPAINTER_PT_main.draw_rig(bpy.context, _Layout(drawn))
    assert drawn == [("label", "Camera Rig of Path"), ("label", "front: the path is CAM_FRONT"),
                     ("label", "CAM_FRONT"), ("prop", "CAM_FRONT", '["scpainter_resolution"]'),
                     ("prop", "CAM_FRONT", "lens"), ("label", "LIDAR_TOP: nuscenes-32"),
                     ("operator", "scpainter.add_camera_rig"),
                     ("operator", "scpainter.remove_camera_rig")]


def _car(tmp_path):
    """A 60-Gaussian car 10 m ahead of the path's start (something for the job to render)."""
    from scpainter_blender.core import shapes

    ply = str(tmp_path / "car.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=60, seed=1))
    assert bpy.ops.scpainter.import_gaussians(filepath=ply, target_length=4.4) == {"FINISHED"}
    car = bpy.context.active_object
    car.location = (100.0, -40.0, 0.0)
    return car


def test_a_camera_path_with_a_rig_exports_a_rig_job(addon, empty_scene, tmp_path):
    """The job of a camera path with the nuScenes rig: ``rig`` is the preset (to 1e-6), each output frame (Frame
    Step 2: 1, 3, 5) carries ``ego_to_world`` putting CAM_FRONT on the camera path (``core.rig.ego_path``), no
    resolution; its CAM_FRONT camera job sees what the path camera sees. A marker switching to another camera is
    refused; without the rig the path's job is a single-camera job again."""
    from scpainter_blender.core import job as J

    rig_scene, kinds = _modules(addon)
    scene = empty_scene
    _car(tmp_path)
    path = _path_camera(scene)
    scene.frame_step = 2
    assert bpy.ops.scpainter.add_camera_rig(preset="nuscenes", scale=1.0) == {"FINISHED"}
    job_path = str(tmp_path / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    job = J.load(job_path)
    preset = core_rig.preset("nuscenes")
    assert job.resolution is None and "resolution" not in job.to_dict()
    got, want = job.rig.to_dict(), preset.to_dict()
    assert got["name"] == want["name"] == "nuscenes" and got["lidar"]["model"] == "nuscenes-32"
    for a, b in zip(got["cameras"] + [got["lidar"]], want["cameras"] + [want["lidar"]]):
        for key in b:
            if key in ("K", "camera_to_ego", "lidar_to_ego"):
                assert np.abs(np.array(a[key]) - np.array(b[key])).max() < 1e-6, (b["name"], key)
            else:
                assert a[key] == b[key]
    assert [f.frame for f in job.frames] == [1, 3, 5]
    (_, front), *_ = job.camera_jobs()
    for f, cf in zip(job.frames, front.frames):
        scene.frame_set(f.frame)
        ego = core_rig.ego_path(_camera_to_world(path)[None], preset, "CAM_FRONT")[0]
        assert np.abs(f.ego_to_world - ego).max() < 3e-5, f.frame
        assert f.K is None and f.world_to_camera is None
        assert np.abs(cf.world_to_camera - C.world_to_camera_from_blender(np.array(path.matrix_world))).max() < 5e-5
    assert front.resolution == (1600, 900) and os.path.normpath(front.output_dir) == "CAM_FRONT"
    # a timeline marker switching to another camera mid-job: one rig job follows one path
    other = bpy.data.objects.new("Other", bpy.data.cameras.new("Other"))
    scene.collection.objects.link(other)
    scene.timeline_markers.new("O", frame=3).camera = other
    marker = scene.timeline_markers.new("P", frame=1)
    marker.camera = path
    with pytest.raises(RuntimeError, match=r"scene\.timeline_markers: a timeline marker switches the camera from "
                                           r"'Path' to 'Other' at frame 3, and 'Path' has a camera rig"):
        bpy.ops.scpainter.export_job(filepath=job_path)
    scene.timeline_markers.clear()
    assert bpy.ops.scpainter.remove_camera_rig() == {"FINISHED"}
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    single = J.load(job_path)
    assert single.rig is None and single.frames[0].K is not None


def _rig_scene_exported(addon, scene, tmp_path, preset="nuscenes", lidar=True):
    """A car, a camera path with a rig (at 1 % size: 16 x 9 cameras) and the path's job exported into its output
    folder as a run exports it; (path camera, job path, output folder)."""
    from scpainter_blender.runs import camera_run

    _car(tmp_path)
    path = _path_camera(scene)
    scene.frame_end = 3
    assert bpy.ops.scpainter.add_camera_rig(preset=preset, scale=0.01, lidar=lidar) == {"FINISHED"}
    scene.scpainter_output_dir = str(tmp_path / "out")
    job_path, out = camera_run.export(bpy.context, camera=path)
    return path, job_path, out


def test_a_rig_jobs_results_load_behind_each_rig_camera(addon, empty_scene, tmp_path):
    """A rig job's output is one folder per camera: each camera's condition previews load under its rig camera's
    name and show behind it, and the camera path shows CAM_FRONT's (the sensor it is), the surround pictures
    (cameras and sweep) load as the path's image for an image editor; each camera's generated frames load likewise
    (the ``done`` event of a rig's generate names no one video: each camera's is in its folder)."""
    from backend.png import write_png
    from scpainter_blender.core.output_layout import OutputLayout
    from scpainter_blender.runs import camera_run
    from scpainter_blender.scene import results

    path, job_path, out = _rig_scene_exported(addon, empty_scene, tmp_path)
    assert os.path.dirname(job_path) == out
    for i, name in enumerate(core_rig.NUSCENES_CAMERAS):
        layout = OutputLayout(out).camera(name)
        os.makedirs(layout.conditions)
        for f in (1, 2, 3):
            write_png(layout.condition_preview(f), np.full((9, 16, 3), (i + f) / 10.0))
    for f in (1, 2, 3):  # the surround pictures the render writes with a LiDAR (cameras tiled beside the sweep)
        write_png(OutputLayout(out).surround(f), np.full((18, 64, 3), f / 10.0))
    report = camera_run.finish(bpy.context, "render", out, {"output_dir": out, "frames": 18}, camera=path.name)
    assert report.startswith("Condition layers of 6 cameras (CAM_FRONT, CAM_FRONT_RIGHT")
    surround = results.find(bpy.data.images, results.SURROUND, "Path")
    assert report.endswith(f"; the cameras and LIDAR_TOP in image {surround.name!r}")
    assert surround["scpainter_frames"] == 3 and bpy.path.abspath(surround.filepath) == OutputLayout(out).surround(1)
    for name in core_rig.NUSCENES_CAMERAS:
        (bg,) = bpy.data.objects[name].data.background_images
        assert bg.image == results.find(bpy.data.images, results.CONDITIONS, name)
        assert bpy.path.abspath(bg.image.filepath) == OutputLayout(out).camera(name).condition_preview(1)
        assert bg.image["scpainter_frames"] == 3
    (bg,) = path.data.background_images
    assert bg.image == bpy.data.objects["CAM_FRONT"].data.background_images[0].image
    # generated (the baseline here): each camera's frames replace its conditions behind it, named as its own
    for i, name in enumerate(core_rig.NUSCENES_CAMERAS):
        layout = OutputLayout(out).camera(name)
        os.makedirs(layout.generated)
        for f in (1, 2, 3):
            write_png(layout.generated_frame(f), np.full((9, 16, 3), (i + f) / 20.0))
    done = {"output_dir": out, "frames": 18, "model": "baseline", "video": None, "frames_dir": None,
            "cameras": list(core_rig.NUSCENES_CAMERAS)}
    report = camera_run.finish(bpy.context, "generate", out, done, camera=path.name)
    assert report.startswith("Baseline videos (no model) of 6 cameras")
    for name in core_rig.NUSCENES_CAMERAS:
        (bg,) = bpy.data.objects[name].data.background_images
        assert bg.image == results.find(bpy.data.images, results.BASELINE, name)
        assert bpy.path.abspath(bg.image.filepath) == OutputLayout(out).camera(name).generated_frame(1)


def test_render_plan_of_a_rig_job_asks_every_cameras_folder(addon, empty_scene, tmp_path):
    """Render Conditions' plan of a rig job (nothing rendered yet): the backend is needed (no record in any camera's
    folder), said without failing on the rig job's frames, which carry no K."""
    from scpainter_blender.runs import render_plan
    from scpainter_blender.runs.client import Invocation

    path, job_path, out = _rig_scene_exported(addon, empty_scene, tmp_path, preset="front")
    check = render_plan.check(bpy.context, Invocation("render"), path)
    assert check.job_path == job_path and check.out == out and check.done is None


def test_command_line_rig_option_names_what_is_wrong(addon, empty_scene, tmp_path, capsys):
    """``blender -c scpainter render SCENE.blend --rig ...`` mounts a rig for the run: an unknown preset is bad
    input on ``--rig`` listing the presets, a scale outside (0, 4] on ``--rig-scale`` (exit 2, nothing run)."""
    from tests.cli import cli_support as CS

    _car(tmp_path)
    _path_camera(empty_scene)
    blend = str(tmp_path / "rig.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    cli = CS.cli(addon)
    for extra, field, message in ((["--rig", "nuscnes"], "--rig", "no rig preset 'nuscnes': expected one of "
                                                                   "['front', 'nuscenes'] or a rig file (.json)"),
                                  (["--rig", "nuscene"], "--rig", "(did you mean 'nuscenes'?)"),
                                  (["--rig-scale", "0.1"], "--rig-scale", "only with --rig"),   # was ignored
                                  (["--rig", "front", "--rig-scale", "0"], "--rig-scale", "0 is not a scale in "
                                                                                         "(0, 4]")):
        assert cli.execute(["render", blend, *extra, "--backend-python", sys.executable]) == 2, extra
        ev = CS.last_event(capsys)
        assert ev["file"] == "(command line)" and ev["field"] == field and message in ev["message"], ev
        assert ev["hint"], ev   # "--rig nuscene" had none
    assert not (tmp_path / "scpainter").exists()
    # what a good --rig does before the run starts (the run itself is any scene's): the rig mounted on the run's
    # camera, a preset at --rig-scale or a rig file as it is, so the job the run exports is a rig job
    import argparse

    from scpainter_blender.core import job as J

    common = sys.modules[addon + ".scpainter_blender.cli.common"]
    camera_run = sys.modules[addon + ".scpainter_blender.runs.camera_run"]
    rig_file = str(tmp_path / "two.json")
    two = core_rig.preset("nuscenes", lidar=False).scaled(0.02)
    core_rig.save(rig_file, core_rig.Rig("two", two.cameras[:2]))
    for rig, scale, names, size in (("nuscenes", 0.01, list(core_rig.NUSCENES_CAMERAS) + ["LIDAR_TOP"], (16, 9)),
                                    (rig_file, 1.0, ["CAM_FRONT", "CAM_FRONT_RIGHT"], (32, 18))):
        common.open_blend(blend, argparse.Namespace())
        common.mount_rig(argparse.Namespace(rig=rig, rig_scale=scale), bpy.context.scene.camera)
        job = J.load(camera_run.export(bpy.context)[0])
        assert job.rig.sensor_names == names and job.rig.cameras[0].resolution == size, rig
    bpy.ops.wm.read_homefile(use_empty=True)


def test_a_rig_scene_renders_per_camera_then_is_up_to_date(addon, empty_scene, tmp_path, capsys):
    """A camera path with the nuScenes rig (1 % size: 16 x 9, three frames) exported as *Render Conditions* exports
    it and rendered by the backend (``python -m backend render``'s command line, parsed and run in this process:
    ``blender -c scpainter render`` starts the same on the job it exports): one output folder per camera with its
    condition layers, the ``done`` event listing the cameras; then *Render Conditions* knows, without a backend,
    that every camera is up to date, and loads each camera's results behind its rig camera."""
    import json

    from backend.__main__ import main
    from scpainter_blender.core.output_layout import OutputLayout
    from scpainter_blender.runs import camera_run, render_plan
    from scpainter_blender.runs.client import Invocation

    path, job_path, out = _rig_scene_exported(addon, empty_scene, tmp_path, lidar=False)
    capsys.readouterr()
    assert main(["render", job_path, "--device", "cpu", "--allow-outside"]) == 0
    done = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")][-1]
    assert done["event"] == "done" and done["cameras"] == list(core_rig.NUSCENES_CAMERAS) and done["frames"] == 18
    for name in core_rig.NUSCENES_CAMERAS:
        layout = OutputLayout(out).camera(name)
        assert [os.path.exists(layout.condition_preview(f)) for f in (1, 2, 3)] == [True] * 3, name
    found = render_plan.check(bpy.context, Invocation("render"), path)
    assert found.job_path == job_path and found.done is not None and found.done["up_to_date"]
    assert found.done["frames"] == 18 and found.done["cameras"] == list(core_rig.NUSCENES_CAMERAS)
    report = camera_run.finish(bpy.context, "render", found.out, found.done, camera=path.name)
    assert report.startswith("Condition layers of 6 cameras") and "(up to date" in report
    for name in core_rig.NUSCENES_CAMERAS:
        (bg,) = bpy.data.objects[name].data.background_images
        assert bpy.path.abspath(bg.image.filepath) == OutputLayout(out).camera(name).condition_preview(1)
    # the same cameras with a LiDAR: its sweeps are the backend's to plan (the caster's settings are in their keys)
    bpy.context.view_layer.objects.active = path
    assert bpy.ops.scpainter.add_camera_rig(preset="nuscenes", scale=0.01, lidar=True) == {"FINISHED"}
    assert render_plan.check(bpy.context, Invocation("render"), path).done is None
    assert bpy.ops.scpainter.add_camera_rig(preset="nuscenes", scale=0.01, lidar=False) == {"FINISHED"}
    assert render_plan.check(bpy.context, Invocation("render"), path).done["up_to_date"]
    # a camera's frames changed (its lens): the rig is no longer up to date
    bpy.data.objects["CAM_BACK"].data.lens *= 1.2
    assert render_plan.check(bpy.context, Invocation("render"), path).done is None


def test_the_recordings_own_rig_is_offered_when_the_import_stored_one(addon, empty_scene):
    """A multi-camera import stores its rig on the points object: *Add Camera Rig* then offers "recording" and
    mounts it as stored; a camera path made from the recorded camera of one sensor is that sensor (not CAM_FRONT).
    Asked for a LiDAR, a recording without one gets nuScenes' top LiDAR."""
    import json

    rig_scene, kinds = _modules(addon)
    path = _path_camera(empty_scene)
    assert [item[0] for item in rig_scene.preset_items(empty_scene)] == ["front", "nuscenes"]
    nus = core_rig.preset("nuscenes", lidar=False).scaled(0.1)
    stored = core_rig.Rig("recording", [nus.camera("CAM_FRONT"), nus.camera("CAM_FRONT_LEFT")])
    pts = bpy.data.objects.new("points", bpy.data.meshes.new("points"))
    empty_scene.collection.objects.link(pts)
    pts["scpainter_kind"] = "points"
    pts["scpainter_recording_rig"] = json.dumps(stored.to_dict())
    recorded = bpy.data.objects.new("Recorded CAM_FRONT_LEFT", bpy.data.cameras.new("rec"))
    empty_scene.collection.objects.link(recorded)
    recorded["scpainter_kind"], recorded["scpainter_sensor"] = "recorded_camera", "CAM_FRONT_LEFT"
    path["scpainter_source_camera"] = recorded.name
    assert [item[0] for item in rig_scene.preset_items(empty_scene)] == ["front", "nuscenes", "recording"]
    bpy.context.view_layer.objects.active = path
    assert bpy.ops.scpainter.add_camera_rig(preset="recording", scale=1.0, lidar=False) == {"FINISHED"}
    rig_obj = kinds.rig_of(path)
    assert rig_obj["scpainter_rig_follow"] == "CAM_FRONT_LEFT" == rig_scene.follow_of(rig_obj)
    got = rig_scene.read_rig(rig_obj)
    assert got.name == "recording" and got.lidar is None and [c.name for c in got.cameras] == ["CAM_FRONT",
                                                                                                "CAM_FRONT_LEFT"]
    assert all(np.abs(a.K - b.K).max() < 1e-6 and np.abs(a.camera_to_ego - b.camera_to_ego).max() < 1e-6
               for a, b in zip(got.cameras, stored.cameras))
    ego = core_rig.ego_path(_camera_to_world(path)[None], stored, "CAM_FRONT_LEFT")[0]
    assert np.abs(rig_scene.ego_to_world(rig_obj) - ego).max() < 3e-5
    assert bpy.ops.scpainter.add_camera_rig(preset="recording", scale=1.0, lidar=True) == {"FINISHED"}
    assert rig_scene.read_rig(kinds.rig_of(path)).lidar.name == "LIDAR_TOP"


def test_a_multi_camera_recording_renders_through_its_own_rig(addon, empty_scene, tmp_path, capsys):
    """End to end: VGGT run on three cameras at once (CAM_FRONT, CAM_FRONT_LEFT, CAM_BACK of a known rig, three
    timestamps along a drive, 16 x 12) imported with its sensors sidecar and *Current Frame Only*: one recorded
    camera per sensor and the recording's rig; scene frame k groups each sensor's k-th frame, which is what the
    viewport shows at k, what the job's output frame k takes (``source_frames``) and what ``recorded_frames``
    spans (1-3, not the nine VGGT frames). A camera path on CAM_FRONT's recorded drive with the preset "recording"
    renders through the backend: every rig camera at every frame sees its own sensor's points where that sensor
    saw them (the rear camera the rear sensor's, which lie behind the front one), at the depth it measured."""
    import json

    from backend.__main__ import main
    from backend.render import channels
    from scpainter_blender.core import job as J
    from scpainter_blender.core.output_layout import OutputLayout
    from scpainter_blender.core.vggt import npz as vggt_io, sensors as S
    from scpainter_blender.runs import camera_run
    from tests.core.geometry.rig_cases import predictions, small_rig
    from tests_support import evaluated_counts

    names = ("CAM_FRONT", "CAM_FRONT_LEFT", "CAM_BACK")
    arrays, sensors, _ = predictions(small_rig(names=names), samples=3)
    # each sensor sees a wall square to its axis at its own distance: a rendered depth says whose points show
    wall_m = {"CAM_FRONT": 3.0, "CAM_FRONT_LEFT": 4.0, "CAM_BACK": 5.0}
    arrays["depth"][:] = np.array([wall_m[n] for n in sensors.sensor], np.float32)[:, None, None]
    folder = tmp_path / "drive"
    folder.mkdir()
    npz = str(folder / "predictions.npz")
    vggt_io.save_predictions(npz, **arrays)
    S.write(S.default_path(npz), sensors)
    assert bpy.ops.scpainter.import_vggt(filepath=npz, propose_boxes=False, current_frame_only=True,
                                         confidence_percentile=0.0, depth_edge_ratio=0.0) == {"FINISHED"}
    scene = bpy.context.scene
    assert sorted(o.name for o in scene.objects if o.get("scpainter_kind") == "recorded_camera") == [
        f"drive {n}" for n in sorted(names)]
    assert (scene.frame_start, scene.frame_end) == (1, 3)
    pts = next(o for o in scene.objects if o.get("scpainter_kind") == "points")
    H, W = arrays["depth"].shape[1:]
    for f in (1, 2, 3):  # the viewport at scene frame f: the three sensors' frames taken at the f-th timestamp
        scene.frame_set(f)
        assert evaluated_counts(pts)[0] == 3 * H * W, f

    bpy.context.view_layer.objects.active = bpy.data.objects["drive CAM_FRONT"]
    assert bpy.ops.scpainter.new_camera_path(shift=0.0) == {"FINISHED"}
    path = scene.camera
    assert bpy.ops.scpainter.add_camera_rig(preset="recording", scale=1.0, lidar=False) == {"FINISHED"}
    scene.scpainter_output_dir = str(tmp_path / "out")
    job_path, out = camera_run.export(bpy.context, camera=path)
    job = J.load(job_path)
    assert job.rig.name == "recording" and job.rig.sensor_names == list(names)
    assert [f.source_frames for f in job.frames] == [[0, 1, 2], [3, 4, 5], [6, 7, 8]]
    assert job.scene.recorded_frames == [1, 3]
    capsys.readouterr()
    assert main(["render", job_path, "--device", "cpu", "--allow-outside"]) == 0
    done = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")][-1]
    assert done["event"] == "done" and done["cameras"] == list(names)
    for name in names:
        for f in (1, 2, 3):
            layers = channels.read(OutputLayout(out).camera(name).condition_exr(f))
            seen = layers[channels.HOLE] < 0.5
            # the rig stands where the ego was at CAM_FRONT's time: the others shot up to 16 ms later, 13 cm on
            own_wall = np.abs(layers[channels.DEPTH] - wall_m[name]) < 0.2
            assert seen.mean() > 0.9, (name, f, seen.mean())
            # CAM_FRONT_LEFT's right edge shows CAM_FRONT's nearer wall where the two cameras' views overlap
            share = own_wall[seen].mean()
            assert share == 1.0 if name != "CAM_FRONT_LEFT" else share > 0.9, (name, f, share)
