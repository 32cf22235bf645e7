"""``blender -c scpainter import ...``: the headless command, called as Blender calls it (execute(argv))."""

import json
import os
import sys

import bpy
import numpy as np
import pytest


def _cli(addon):
    return sys.modules[addon + ".scpainter_blender.cli"]


def _last_event(capsys):
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    return json.loads(lines[-1])


def test_import_and_save(addon, empty_scene, street, tmp_path, capsys):
    out = tmp_path / "not yet" / "batch.blend"     # a folder that does not exist yet is made
    code = _cli(addon).execute(["import", street.predictions_path, "--trajectory",
                                os.path.join(street.root, "metric.npz"), "--save", str(out)])
    ev = _last_event(capsys)
    assert code == 0, ev
    assert ev["event"] == "done" and ev["scale_method"] == "trajectory"
    assert abs(ev["scale"] - float(street.metric()["metres_per_unit"])) < 1e-4
    assert ev["blend"] == str(out) and out.stat().st_size > 1_000_000
    assert sorted(os.listdir(out.parent)) == ["batch.blend"]       # no temporary file left
    bpy.ops.wm.open_mainfile(filepath=str(out))
    pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
    assert len(pts.data.vertices) == ev["points"]
    M = np.array(pts["scpainter_vggt_to_world"]).reshape(4, 4)
    assert np.abs(M - street.metric()["vggt_to_world"]).max() < 1e-4
    bpy.ops.wm.read_homefile(use_empty=True)


def test_bad_input_exit_code_2(addon, empty_scene, tmp_path, capsys):
    cli = _cli(addon)
    assert cli.execute(["import", str(tmp_path / "nope.npz")]) == 2
    assert "nope.npz" in _last_event(capsys)["message"]
    assert cli.execute(["import"]) == 2  # argparse errors are reported, not sys.exit() from inside Blender
    assert "predictions" in _last_event(capsys)["message"]
    assert cli.execute(["import", "x.npz", "--camera-height", "1.6", "--scale-factor", "2"]) == 2
    # options no import can use are bad input named by the option, not an internal error (0 was taken for 1.0)
    for args, flag in ((["--scale-factor", "0"], "--scale-factor"), (["--scale-factor", "nan"], "--scale-factor"),
                       (["--confidence-percentile", "150"], "--confidence-percentile")):
        assert cli.execute(["import", str(tmp_path / "x.npz"), *args]) == 2, args
        ev = _last_event(capsys)
        assert ev["file"] == "(command line)" and ev["field"] == flag, ev
    assert len(bpy.data.objects) == 0
    not_blend = tmp_path / "predictions.npz"                   # a scene command given the wrong kind of file
    np.savez(not_blend, depth=np.zeros(3))
    assert cli.execute(["render", str(not_blend)]) == 2
    ev = _last_event(capsys)
    assert ev["file"] == str(not_blend) and "cannot open it as a scene" in ev["message"]
    # batch: a data root that is no folder, and a list's misplaced data-root: line, before any work
    assert cli.execute(["batch", "a.blend", "--data-root", str(not_blend)]) == 2
    ev = _last_event(capsys)
    assert ev["file"] == "(command line)" and ev["field"] == "--data-root" and "is not a folder" in ev["message"]
    (tmp_path / "list.txt").write_text("a.blend\ndata-root: .\n")   # a data-root: line after a path
    assert cli.execute(["batch", "--list", str(tmp_path / "list.txt")]) == 2
    ev = _last_event(capsys)
    assert ev["file"] == str(tmp_path / "list.txt") and ev["field"] == "line 2"


def test_input_error_by_name_is_exit_2_anything_else_exit_1(addon, empty_scene, tmp_path, capsys, monkeypatch):
    """Bad input is an InputError, caught by name (exit 2, file and field); a plain ValueError is a bug (exit 1,
    its traceback on standard error), as in the backend."""
    cli = _cli(addon)
    errors = sys.modules[addon + ".scpainter_blender.core.errors"]
    importer = sys.modules[addon + ".scpainter_blender.scene.importer"]
    for argv, field in ((["batch", "--command", "render"], "items"), (["render", "x.blend", "--device", "gpu"],
                                                                     "--device"),
                        (["batch", "a.blend", "--shard", "2/2"], "--shard"), (["batch", "a.blend", "--shard", "x"],
                                                                              "--shard"),
                        (["render", "x.blend", "--backend-python", "/nonexistent/python"], "--backend-python"),
                        (["generate", "x.blend", "--checkpoint", str(tmp_path / "none")], "--checkpoint")):
        assert cli.execute(argv) == 2, argv
        ev = _last_event(capsys)
        assert ev["event"] == "error" and ev["file"] == errors.COMMAND_LINE and ev["field"] == field, ev

    def shape_bug(*args, **kwargs):
        raise ValueError("shape bug: (3,) and (4,)")

    monkeypatch.setattr(importer, "import_vggt", shape_bug)
    assert cli.execute(["import", str(tmp_path / "p.npz")]) == 1
    captured = capsys.readouterr()
    ev = json.loads([line for line in captured.out.splitlines() if line.startswith("{")][-1])
    assert ev["message"] == "ValueError: shape bug: (3,) and (4,)" and "file" not in ev
    assert "not a problem with the input" in ev["hint"]
    assert "Traceback (most recent call last)" in captured.err and "in shape_bug" in captured.err

    def bad_file(context, path, opts):
        raise errors.InputError(path, "depth", "expected (S, H, W) or (S, H, W, 1)", hint="save it again")

    monkeypatch.setattr(importer, "import_vggt", bad_file)
    assert cli.execute(["import", str(tmp_path / "p.npz")]) == 2
    ev = _last_event(capsys)
    assert ev["file"] == str(tmp_path / "p.npz") and ev["field"] == "depth" and ev["hint"] == "save it again"


def test_render_warns_of_frames_outside_the_recording(addon, empty_scene, tmp_path, capsys):
    """``render`` of a scene whose frame range runs past its recording sends a ``warning`` event (code
    ``outside_recording``) saying which frames, before the backend runs, and counts it in the summary."""
    from vggt_cases import drive, write

    arrays, _, _ = drive(S=2, H=12, W=16)
    assert bpy.ops.scpainter.import_vggt(filepath=write(tmp_path, arrays), depth_edge_ratio=0.0) == {"FINISHED"}
    bpy.context.scene.frame_end = 4  # the recording is frames 1-2
    blend = str(tmp_path / "short.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.read_homefile(use_empty=True)
    code = _cli(addon).execute(["render", blend, "--device", "cpu", "--backend-python", sys.executable])
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    assert code == 0, events[-1]
    (w,) = [e for e in events if e["event"] == "warning" and "output frames" in e["message"]]
    assert w["code"] == "outside_recording"
    assert w["message"].startswith("2 of the 4 output frames (3–4) lie outside the recording (frames 1–2)")
    assert events.index(w) < len(events) - 1 and events[-1]["event"] == "done" and events[-1]["warnings"] >= 1


#: The scene camera of ``_street_blend``'s scene (street_with_car's camera path) and its output folder's name.
CAM, CAM_DIR = "Camera path 2 m left", "Camera_path_2_m_left"


def _street_blend(street, folder, second_path=False):
    """A saved scene: the street, a car, a 2 m path (the scene camera), half resolution, frames 1-3; with
    ``second_path`` also a path 2 m to the right."""
    from tests_support import street_with_car

    street_with_car(street, folder, count=2000, seed=3)
    bpy.context.scene.render.resolution_percentage = 50
    bpy.context.scene.frame_end = 3
    if second_path:
        left = bpy.context.scene.camera
        assert bpy.ops.scpainter.new_camera_path(shift=-2.0) == {"FINISHED"}
        bpy.context.scene.camera = left
    path = str(folder / "street.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


def test_render_generate_and_batch_headless(addon, street, tmp_path, capsys, tiny_checkpoint):
    import hashlib

    cli = _cli(addon)
    blend = _street_blend(street, tmp_path)
    digest = hashlib.sha256(open(blend, "rb").read()).hexdigest()
    common = ["--device", "cpu", "--backend-python", sys.executable]
    code = cli.execute(["render", blend, *common])
    ev = _last_event(capsys)
    assert code == 0, ev
    out = tmp_path / "scpainter" / "Scene" / CAM_DIR  # the default: //scpainter/<scene name>/<scene camera>/
    assert ev["output_dir"] == str(out) and ev["frames"] == 3 and len(list((out / "conditions").glob("*.exr"))) == 3
    # no checkpoint (none given, none in the preferences): the OpenCV inpainting baseline, said in the output
    code = cli.execute(["generate", blend, *common, "--inpaint", "navier-stokes", "--output", str(tmp_path / "gen")])
    ev = _last_event(capsys)
    assert code == 0, ev
    assert ev["model"] == "baseline" and "OpenCV Navier-Stokes inpainting" in ev["description"], ev
    assert os.path.isfile(ev["video"]) and ev["video"].startswith(str(tmp_path / "gen"))
    job = json.load(open(tmp_path / "gen" / CAM_DIR / "job.json"))       # --output: the scene's output folder
    assert job["generate"] == {"inpaint": "navier-stokes"}                 # the scene's setting, for this run
    code = cli.execute(["generate", blend, *common, "--checkpoint", tiny_checkpoint, "--output",
                        str(tmp_path / "gen")])
    ev = _last_event(capsys)
    assert code == 0, ev
    assert ev["model"] == "scpainter" and ev["description"].startswith("SCPainter model")
    assert os.path.isfile(ev["video"]) and ev["video"].startswith(str(tmp_path / "gen"))
    # a batch over a scene, a missing scene and the job file the first run wrote: one summary, exit 1
    (tmp_path / "list.txt").write_text(f"scpainter/Scene/{CAM_DIR}/job.json\n")
    # the job file reads the street's predictions from the cache, outside its folder: refused unless allowed
    code = cli.execute(["batch", "--list", str(tmp_path / "list.txt"), "--command", "render", *common])
    ev = _last_event(capsys)
    assert code == 1 and "scene.predictions" in ev["items"][0]["error"] and "--allow-outside" in ev["items"][0]["hint"]
    # ... or with the folders it reads named as data roots (passed on to the backend's batch)
    exported = json.load(open(out / "job.json"))
    roots = {os.path.dirname(os.path.join(out, p))
             for p in [exported["scene"]["predictions"], *(a["ply"] for a in exported["assets"])]}
    code = cli.execute(["batch", "--list", str(tmp_path / "list.txt"), "--command", "render", *common,
                        *[a for r in sorted(roots) for a in ("--data-root", r)]])
    ev = _last_event(capsys)
    assert code == 0 and ev["items"][0]["status"] == "ok", ev
    # ... or by the list itself (its data-root: lines, as vary writes them), beside a scene
    (tmp_path / "rooted.txt").write_text("".join(f"data-root: {r}\n" for r in sorted(roots))
                                         + f"scpainter/Scene/{CAM_DIR}/job.json\n")
    code = cli.execute(["batch", blend, "--list", str(tmp_path / "rooted.txt"), "--command", "render", *common])
    ev = _last_event(capsys)
    assert code == 0 and [r["status"] for r in ev["items"]] == ["ok", "ok"], ev
    code = cli.execute(["batch", blend, str(tmp_path / "missing.blend"), "--list", str(tmp_path / "list.txt"),
                        "--command", "render", "--allow-outside", *common])
    ev = _last_event(capsys)
    assert code == 1 and ev["failed"] == 1 and [r["status"] for r in ev["items"]] == ["ok", "failed", "ok"]
    assert "missing.blend" in ev["items"][1]["error"] and ev["items"][2]["skipped"] == 3   # already rendered
    code = cli.execute(["batch", blend, str(tmp_path / "missing.blend"), "--shard", "0/2", "--command", "render",
                        *common])
    ev = _last_event(capsys)
    assert code == 0 and [r["item"] for r in ev["items"]] == [blend] and ev["shard"] == "0/2"
    # batch generate without a checkpoint (a fresh process has only the preferences, here emptied): the baseline for
    # the scene, and its job file (the same job: run once, its item repeats the scene's result) says so too
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.checkpoint_dir = ""
    code = cli.execute(["batch", blend, "--list", str(tmp_path / "list.txt"), "--command", "generate",
                        "--allow-outside", *common])
    ev = _last_event(capsys)
    assert code == 0, ev
    assert [(r["status"], r["model"], r["skipped"]) for r in ev["items"]] == [("ok", "baseline", False)] * 2
    assert ev["items"][1]["seconds"] == ev["items"][0]["seconds"]   # one run, both items its result
    assert hashlib.sha256(open(blend, "rb").read()).hexdigest() == digest   # the .blend is never written
    prefs.backend_python, prefs.device, prefs.checkpoint_dir = "", "AUTO", ""
    bpy.ops.wm.read_homefile(use_empty=True)


def test_camera_option_runs_that_camera_into_its_folder(addon, street, tmp_path, capsys):
    """--camera NAME: that camera object's job, in its own folder inside the scene's; a name that is no camera of
    the scene is bad input naming the option and listing the cameras; without it, the scene camera."""
    cli = _cli(addon)
    blend = _street_blend(street, tmp_path, second_path=True)
    common = ["--device", "cpu", "--backend-python", sys.executable]
    scene_dir = tmp_path / "scpainter" / "Scene"
    code = cli.execute(["render", blend, "--camera", "Camera path 2 m right", *common])
    ev = _last_event(capsys)
    assert code == 0, ev
    right = scene_dir / "Camera_path_2_m_right"
    assert ev["camera"] == "Camera path 2 m right" and ev["output_dir"] == str(right) and ev["frames"] == 3
    assert len(list((right / "conditions").glob("frame_*.exr"))) == 3 and not (scene_dir / CAM_DIR).exists()
    code = cli.execute(["render", blend, *common])                     # the scene camera, into its own folder
    ev = _last_event(capsys)
    assert code == 0 and ev["camera"] == CAM and ev["output_dir"] == str(scene_dir / CAM_DIR), ev
    jobs = [json.loads((d / "job.json").read_text()) for d in (right, scene_dir / CAM_DIR)]
    assert jobs[0]["frames"][0]["world_to_camera"] != jobs[1]["frames"][0]["world_to_camera"]
    for command, name, what in (("render", "Nope", "is no object of the scene"),
                                ("generate", "car", "is a mesh, not a camera"),
                                ("export", "Nope", "is no object of the scene")):
        extra = ["--format", "kitti"] if command == "export" else []
        assert cli.execute([command, blend, "--camera", name, *extra, *common]) == 2, command
        ev = _last_event(capsys)
        assert ev["file"] == "(command line)" and ev["field"] == "--camera", ev
        assert (f"--camera: {name!r} {what} in {blend}; its cameras: 'Camera path 2 m left', 'Camera path 2 m "
                "right', ") in ev["message"], ev
        assert "recorded camera" in ev["message"]
    bpy.ops.wm.read_homefile(use_empty=True)


def test_export_arguments_are_bad_input(addon, empty_scene, tmp_path, capsys):
    cli = _cli(addon)
    errors = sys.modules[addon + ".scpainter_blender.core.errors"]
    for argv in (["export", "x.blend"], ["export", "x.blend", "--format", "yolo"]):
        assert cli.execute(argv) == 2, argv
        ev = _last_event(capsys)
        assert ev["file"] == errors.COMMAND_LINE and ev["field"] == "--format", ev
    not_blend = tmp_path / "predictions.npz"
    np.savez(not_blend, depth=np.zeros(3))
    assert cli.execute(["export", str(not_blend), "--format", "coco"]) == 2
    assert _last_event(capsys)["file"] == str(not_blend)


def test_export_headless(addon, street, tmp_path, capsys):
    cli = _cli(addon)
    blend = _street_blend(street, tmp_path)
    code = cli.execute(["export", blend, "--format", "kitti", "--device", "cpu", "--backend-python", sys.executable])
    ev = _last_event(capsys)
    assert code == 0, ev
    out = tmp_path / "scpainter" / "Scene" / CAM_DIR
    assert ev["command"] == "export" and ev["output_dir"] == str(out) and ev["format"] == "kitti"
    assert ev["out"] == str(out / "export" / "kitti") and ev["frames"] == 3 and ev["images"] == "conditions"
    assert sorted(os.listdir(out / "export" / "kitti" / "label_2")) == [f"00000{i}.txt" for i in range(3)]
    assert ev["objects"] >= 1                                        # the car beside the road
    code = cli.execute(["export", blend, "--format", "coco", "--out", str(tmp_path / "coco"), "--device", "cpu",
                        "--backend-python", sys.executable])
    ev = _last_event(capsys)
    assert code == 0 and ev["out"] == str(tmp_path / "coco") and ev["rendered"] == 0, ev


def test_import_convention_crop_and_report(addon, empty_scene, tmp_path, capsys):
    """--extrinsic-convention and --crop; the JSON summary says what loading decided and dropped."""
    from vggt_cases import drive, pad, write

    from scpainter_blender.core.geometry import cameras as C

    cli = _cli(addon)
    arrays, w2c, _ = drive(H=22, W=32)
    c2w = dict(pad(arrays, 5, 5), extrinsic=C.rigid_inverse(w2c))
    path = write(tmp_path, c2w)
    assert cli.execute(["import", path, "--scale-factor", "3"]) == 2
    msg = _last_event(capsys)["message"]
    assert "'extrinsic': holds camera-to-world poses" in msg and " m from the file's world_points" in msg
    assert "--extrinsic-convention on the command line): camera_to_world" in msg
    assert len(bpy.data.objects) == 0
    assert cli.execute(["import", path, "--crop", "1 2"]) == 2
    assert "crop '1 2'" in _last_event(capsys)["message"]
    assert cli.execute(["import", path, "--extrinsic-convention", "sideways"]) == 2
    capsys.readouterr()

    assert cli.execute(["import", path, "--extrinsic-convention", "camera_to_world", "--crop", "0 5 0 5"]) == 0
    ev = _last_event(capsys)
    rep = ev["predictions"]
    assert rep["extrinsic_convention"] == "camera_to_world" and not rep["extrinsic_convention_checked"]
    assert rep["crop"] == [0, 5, 0, 5] and rep["crop_requested"] == "explicit" and rep["original_size"] == [32, 32]
    assert (bpy.context.scene.render.resolution_x, bpy.context.scene.render.resolution_y) == (32, 22)
    bpy.ops.wm.read_homefile(use_empty=True)

    # no world_points, a few NaN depths: imported, and the summary says the convention was not checked
    plain = {k: v for k, v in arrays.items() if not k.startswith("world_points")}
    plain["depth"] = plain["depth"].copy()
    plain["depth"][0, 3, :2] = np.nan
    path = write(tmp_path, plain, "plain.npz")
    assert cli.execute(["import", path]) == 0
    ev = _last_event(capsys)
    rep = ev["predictions"]
    assert rep["extrinsic_convention"] == "world_to_camera" and rep["extrinsic_convention_checked"] is False
    assert rep["nonfinite_pixels"] == {"depth": [2, 0, 0, 0]} and rep["dropped_pixels"] == 2
    assert rep["crop"] == [0, 0, 0, 0] and rep["crop_requested"] == "auto"
    assert any("not checked (the file has no world_points)" in w for w in ev["warnings"])
    assert any("dropped 2 pixels" in w for w in ev["warnings"])
    bpy.ops.wm.read_homefile(use_empty=True)


def test_import_depth_edge_ratio(addon, empty_scene, tmp_path, capsys):
    """--depth-edge-ratio: a ratio, or off / 0; the default is the job's; the summary says what it left out; a
    ratio no job can hold is bad input named by the option."""
    from vggt_cases import drive, write

    from scpainter_blender.core import job as J

    cli = _cli(addon)
    S, H, W = 2, 12, 16
    path = write(tmp_path, drive(S=S, H=H, W=W)[0])  # random depth per pixel: every pixel is a depth edge
    default = J.POINT_CLEANING["depth_edge_ratio"]
    for args, ratio, points in (([], default, 0), (["--depth-edge-ratio", "off"], None, S * H * W),
                                (["--depth-edge-ratio", "0"], None, S * H * W),
                                (["--depth-edge-ratio", "100"], 100.0, S * H * W)):   # no jump is 100× a depth
        bpy.ops.wm.read_homefile(use_empty=True)
        assert cli.execute(["import", path, "--confidence-percentile", "0", *args]) == 0, args
        ev = _last_event(capsys)
        assert (ev["depth_edge_ratio"], ev["points"], ev["depth_edge_points"]) == (ratio, points, S * H * W - points)
        pts = next(o for o in bpy.context.scene.objects if o.get("scpainter_kind") == "points")
        assert pts["scpainter_depth_edge_ratio"] == (ratio or 0.0) and len(pts.data.vertices) == points
    bpy.ops.wm.read_homefile(use_empty=True)
    for value in ("-0.1", "1e-5", "nan", "200", "sometimes"):
        assert cli.execute(["import", path, "--depth-edge-ratio", value]) == 2, value
        ev = _last_event(capsys)
        assert ev["file"] == "(command line)" and ev["field"] == "--depth-edge-ratio", ev
        assert "expected a fraction of the pixel's depth" in ev["message"] and "off" in ev["message"]
    assert len(bpy.data.objects) == 0


def test_batch_on_ray_exports_the_scenes_and_runs_every_job_as_one_ray_batch(addon, street, tmp_path, capsys,
                                                                              ray_cluster):
    import hashlib
    import shutil

    from tests_support import small_job

    cli = _cli(addon)
    os.makedirs(tmp_path / "a")
    a = _street_blend(street, tmp_path / "a")
    b = str(tmp_path / "b" / "street.blend")               # a second scene, its own output folder beside it
    os.makedirs(os.path.dirname(b))
    shutil.copy(a, b)
    digest = hashlib.sha256(open(a, "rb").read()).hexdigest()
    job = small_job(tmp_path / "job")                       # a job file: straight to the backend, as given
    common = ["--device", "cpu", "--backend-python", sys.executable, "--ray", ray_cluster]
    items = [a, str(tmp_path / "missing.blend"), job, b]
    code = cli.execute(["batch", *items, "--command", "render", *common])
    captured = capsys.readouterr()
    ev = json.loads([line for line in captured.out.splitlines() if line.startswith("{")][-1])
    assert code == 1 and ev["failed"] == 1, ev                                 # the missing scene, and only it
    assert [r["item"] for r in ev["items"]] == items
    assert [r["status"] for r in ev["items"]] == ["ok", "failed", "ok", "ok"]
    assert "missing.blend" in ev["items"][1]["error"] and "worker" not in ev["items"][1]   # never sent to Ray
    for r, out, frames in ((ev["items"][0], tmp_path / "a" / "scpainter" / "Scene" / CAM_DIR, 3),
                           (ev["items"][2], tmp_path / "job" / "out", 2),
                           (ev["items"][3], tmp_path / "b" / "scpainter" / "Scene" / CAM_DIR, 3)):
        assert r["output_dir"] == str(out) and r["frames"] == frames and r["skipped"] == 0, r
        assert len(list((out / "conditions").glob("*.exr"))) == frames
        assert r["attempts"] == 1 and int(r["worker"].rsplit(":", 1)[1]) != os.getpid()   # in a Ray worker
    assert "scpainter: batch 3/3" in captured.err                               # the backend's progress, as it came
    assert ev["ray"] == ray_cluster and ev["jobs"] == 4 and ev["counts"] == {"ok": 3, "failed": 1}
    # again, generating: the conditions are up to date; without a checkpoint each scene's video is the baseline
    bpy.context.preferences.addons[addon].preferences.checkpoint_dir = ""
    code = cli.execute(["batch", a, b, "--command", "generate", *common])
    ev = _last_event(capsys)
    assert code == 0, ev
    assert [(r["status"], r["model"], r["skipped"]) for r in ev["items"]] == [("ok", "baseline", False)] * 2
    assert all(os.path.isfile(r["video"]) for r in ev["items"])
    # two scenes naming one output folder: the second is refused before anything runs; --shard is not for Ray
    code = cli.execute(["batch", a, a, "--command", "render", *common])
    ev = _last_event(capsys)
    assert code == 1 and [r["status"] for r in ev["items"]] == ["ok", "failed"]
    assert ev["items"][0]["skipped"] == 3 and ev["items"][1]["field"] == "scene.scpainter_output_dir"
    assert cli.execute(["batch", a, "--shard", "0/2", *common]) == 2 and _last_event(capsys)["field"] == "--shard"
    for option, value in (("--retries", "1000"), ("--cpus-per-job", "inf")):   # refused before any export
        assert cli.execute(["batch", a, option, value, *common]) == 2 and _last_event(capsys)["field"] == option
    assert hashlib.sha256(open(a, "rb").read()).hexdigest() == digest       # the .blend is never written
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.backend_python, prefs.device, prefs.checkpoint_dir = "", "AUTO", ""
    bpy.ops.wm.read_homefile(use_empty=True)


def test_help_returns_instead_of_exiting(addon, capsys):
    """--help prints the usage and returns 0: argparse's sys.exit would end Blender."""
    cli = _cli(addon)
    for argv in (["--help"], ["render", "--help"], ["batch", "--help"]):
        assert cli.execute(argv) == 0, argv
        assert capsys.readouterr().out.startswith("usage: "), argv


def test_execute_works_with_the_bpy_module_without_the_add_on_enabled(tmp_path):
    # README: "with the bpy module the same entry point is execute(argv)": it must not need register() first
    import subprocess

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    blend = tmp_path / "empty.blend"
    script = ("import sys, json, bpy; bpy.ops.wm.read_homefile(use_empty=True); "
              f"bpy.ops.wm.save_as_mainfile(filepath={str(blend)!r}); "
              "from scpainter_blender import cli; sys.exit(cli.execute(['batch', sys.argv[1]]))")
    r = subprocess.run([sys.executable, "-c", script, str(blend)], cwd=root, capture_output=True, text=True,
                       timeout=300)
    done = json.loads([line for line in r.stdout.splitlines() if line.startswith("{")][-1])
    assert r.returncode == 1 and done["event"] == "done", r.stderr[-2000:]
    (item,) = done["items"]
    # the scene has nothing to render: bad input named, not an AttributeError reported as a bug
    assert item["status"] == "failed" and "bug" not in item and item.get("field"), item
    assert done["counts"] == {"failed": 1} and done["jobs"] == 1
