"""Render Conditions / Generate through the operators (blocking in background mode), with the real backend in a
subprocess; without a checkpoint Generate makes the inpainting baseline, labelled as such everywhere; failures
(crash, hang, missing interpreter) leave the scene and finished outputs alone."""

import json
import stat
import sys

import bpy
import pytest

from tests_support import street_with_car


@pytest.fixture
def street_scene(addon, street, tmp_path, tiny_checkpoint):
    scene = street_with_car(street, tmp_path)
    scene.render.resolution_percentage = 50
    scene.frame_end = 4                               # four frames keep the tiny model's CPU time small
    scene.scpainter_output_dir = str(tmp_path / "out")
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.backend_python, prefs.device, prefs.checkpoint_dir = sys.executable, "CPU", tiny_checkpoint
    yield scene
    prefs.backend_python, prefs.device, prefs.checkpoint_dir = "", "AUTO", ""
    bpy.ops.wm.read_homefile(use_empty=True)


#: The camera path street_with_car makes (the scene camera), and its output folder inside the scene's.
CAM = "Camera path 2 m left"
CAM_DIR = "Camera_path_2_m_left"


def _name(kind):
    """The datablock name of result ``kind`` of the scene camera (results.result_name)."""
    return f"{kind} · {CAM}"


def _state():
    """What a run must not touch unless it finished: datablocks and the camera's backgrounds."""
    cam = bpy.context.scene.camera
    return (len(bpy.data.images), len(bpy.data.movieclips), len(bpy.data.objects),
            len(cam.data.background_images), cam.data.show_background_images)


def test_render_then_generate_load_results_behind_the_camera(street_scene, tmp_path, addon, capsys, tiny_checkpoint):
    assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}
    out = tmp_path / "out" / CAM_DIR                                 # the scene camera's folder in the scene's
    assert len(list((out / "conditions").glob("frame_*.exr"))) == 4
    img = bpy.data.images[_name("SCPainter Conditions")]
    assert img.source == "SEQUENCE" and img["scpainter_frames"] == 4
    cam = street_scene.camera.data
    assert cam.show_background_images and cam.background_images[0].image == img
    assert cam.background_images[0].image_user.frame_start == 1      # file N shows at frame N
    # no checkpoint: the baseline (OpenCV inpainting), under names that say so
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.checkpoint_dir = ""
    capsys.readouterr()
    assert bpy.ops.scpainter.generate() == {"FINISHED"}
    assert "scpainter generate (Baseline): generate 4/4" in capsys.readouterr().out   # the progress lines
    manifest = json.loads((out / "generated" / "manifest.json").read_text())
    assert manifest["model"] == "baseline" and manifest["checkpoint"] is None
    assert "generate" not in json.loads((out / "job.json").read_text())   # no checkpoint, no setting: nothing
    baseline = bpy.data.images[_name("SCPainter Baseline")]
    assert baseline.source == "SEQUENCE" and baseline["scpainter_frames"] == 4
    assert baseline["scpainter_model"] == "baseline" and "OpenCV Telea" in baseline["scpainter_description"]
    assert bpy.data.movieclips[_name("SCPainter Video (Baseline)")].frame_duration == 4
    assert _name("SCPainter Generated") not in bpy.data.images and _name("SCPainter Video") not in bpy.data.movieclips
    assert cam.background_images[0].image == baseline and len(cam.background_images) == 1
    # with the checkpoint: the model's video replaces the baseline's datablocks (the same files on disk)
    prefs.checkpoint_dir = tiny_checkpoint
    assert bpy.ops.scpainter.generate() == {"FINISHED"}
    assert json.loads((out / "generated" / "manifest.json").read_text())["model"] == "scpainter"
    assert (out / "generated.mp4").is_file() and len(list((out / "generated").glob("frame_*.png"))) == 4
    assert bpy.data.images[_name("SCPainter Generated")].source == "SEQUENCE"
    assert bpy.data.images[_name("SCPainter Generated")]["scpainter_model"] == "scpainter"
    assert bpy.data.movieclips[_name("SCPainter Video")].frame_duration == 4
    assert _name("SCPainter Baseline") not in bpy.data.images
    assert _name("SCPainter Video (Baseline)") not in bpy.data.movieclips
    assert cam.background_images[0].image.name == _name("SCPainter Generated") and len(cam.background_images) == 1
    # conditions, their labelled previews, generated
    assert sorted(i.name for i in bpy.data.images if i.name.startswith("SCPainter")) == [
        _name("SCPainter Conditions"), _name("SCPainter Generated"), _name("SCPainter Labels")]


def _files(folder):
    """{path: (mtime_ns, bytes)} of the condition frames in an output folder (record.json aside: a resumed render
    may write it again)."""
    return {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in (folder / "conditions").iterdir()
            if p.name != "record.json"}


def test_each_camera_path_renders_into_its_own_folder(street_scene, tmp_path, addon, capsys):
    """Two camera paths: each run writes into its camera's folder (<scene output folder>/<camera>/) and loads its
    results under its camera's name behind that camera; the second never touches the first's files or
    datablocks. Render / Generate All Camera Paths run every path (blocking in background mode) and leave the scene
    camera as it was."""
    street_scene.frame_end = 2
    a = street_scene.camera
    assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}
    out = tmp_path / "out"
    a_dir, b_dir = out / CAM_DIR, out / "Camera_path_2_m_right"
    first = _files(a_dir)
    assert len([p for p in first if p.suffix == ".exr"]) == 2
    assert bpy.ops.scpainter.new_camera_path(shift=-2.0) == {"FINISHED"}
    b = street_scene.camera
    street_scene.camera = a
    capsys.readouterr()
    assert bpy.ops.scpainter.render_all_camera_paths() == {"FINISHED"}
    printed = capsys.readouterr().out
    # A is up to date: answered without a backend (no progress); B renders. The progress is sampled every 0.1 s (a
    # warm backend renders the two frames between two samples, a busy CPU may finish B before the first sample), but
    # each camera's run is printed once it has started, before the first sample: the sequence always holds B's
    # (a warning: the street's parked cars the import proposed are not reviewed yet, said again when up to date)
    assert "'Camera path 2 m left': WARNING: Condition layers of 2 frames" in printed and "up to date" in printed
    assert "proposal_01" in printed
    assert "scpainter render, camera 1/2: " not in printed and "scpainter render, camera 2/2: " in printed
    assert street_scene.camera == a                                    # each path passed to its job, nothing set
    assert _files(a_dir) == first                                       # A's frames reused, never rewritten
    assert len(list((b_dir / "conditions").glob("frame_*.exr"))) == 2
    assert (b_dir / "conditions" / "frame_000001.exr").read_bytes() != (a_dir / "conditions" /
                                                                         "frame_000001.exr").read_bytes()
    jobs = [json.loads((d / "job.json").read_text()) for d in (a_dir, b_dir)]
    assert jobs[0]["frames"][0]["world_to_camera"] != jobs[1]["frames"][0]["world_to_camera"]
    cond = {c: bpy.data.images[f"SCPainter Conditions · {c.name}"] for c in (a, b)}
    assert bpy.path.abspath(cond[a].filepath).startswith(str(a_dir))
    assert bpy.path.abspath(cond[b].filepath).startswith(str(b_dir))
    assert a.data.background_images[0].image == cond[a] and b.data.background_images[0].image == cond[b]
    # every path's baseline video, each into its folder and behind its camera
    bpy.context.preferences.addons[addon].preferences.checkpoint_dir = ""
    assert bpy.ops.scpainter.generate_all_camera_paths() == {"FINISHED"}
    for cam, folder in ((a, a_dir), (b, b_dir)):
        assert (folder / "generated.mp4").is_file()
        img = bpy.data.images[f"SCPainter Baseline · {cam.name}"]
        assert bpy.path.abspath(img.filepath).startswith(str(folder)) and img["scpainter_frames"] == 2
        assert cam.data.background_images[0].image == img and len(cam.data.background_images) == 1
        assert f"SCPainter Video (Baseline) · {cam.name}" in bpy.data.movieclips
    assert _files(a_dir) == first and street_scene.camera == a


def test_all_camera_paths_followed_stopped_and_past_a_failure(street_scene, tmp_path, addon):
    """all_cameras.AllCameras as the UI timer drives it: a path whose folder cannot be had is reported and the next
    runs; the progress names the camera ("camera 2/3"); Esc stops the running path and starts no more.

    Nothing here depends on what a 0.05 s sample happens to catch (a warm backend renders the four frames between
    two samples; a busy CPU may finish a path before the first): each path's run is seen at its start (the
    constructor starts the first, the tick that ends one starts the next and returns "running"), and a run's progress
    is read from its recorded last progress event."""
    import time

    camera_run = sys.modules[f"{addon}.scpainter_blender.runs.camera_run"]
    all_cameras = sys.modules[f"{addon}.scpainter_blender.runs.all_cameras"]
    kinds = sys.modules[f"{addon}.scpainter_blender.scene.kinds"]
    a = street_scene.camera
    refused = a.copy()                                          # its folder would be the scene folder's assets/
    refused.name = "Assets"
    street_scene.collection.objects.link(refused)
    kinds.mark(refused, kinds.CAMERA_PATH)
    assert bpy.ops.scpainter.new_camera_path(shift=-2.0) == {"FINISHED"}
    paths = kinds.camera_paths(street_scene)
    assert [c.name for c in paths] == ["Assets", "Camera path 2 m left", "Camera path 2 m right"]
    props = sys.modules[f"{addon}.scpainter_blender.scene.props"]
    with pytest.raises(props.SceneError, match="scene.objects: the scene has no camera paths"):
        all_cameras.AllCameras(bpy.context, "render", camera_run.invocation(bpy.context, "render"), [])
    follow = all_cameras.AllCameras(bpy.context, "render", camera_run.invocation(bpy.context, "render"), paths)
    second = follow.follower                                           # camera 2/3's run: 1/3 was refused first
    texts = [follow.status_text]
    while (status := follow.tick(bpy.context)) == "running":
        texts.append(follow.status_text)
        if camera_run.ACTIVE.get("position") == (3, 3):                      # the last path's run has started
            follow.stop()                                              # Esc during the last path
            status = "cancelled"
            break
        time.sleep(0.05)
    assert status == "cancelled" and not camera_run.ACTIVE
    assert not any("camera 1/3" in t for t in texts)                   # never started: its folder was refused
    assert texts[0].startswith("SCPainter render, camera 2/3: ")
    assert texts[-1].startswith("SCPainter render, camera 3/3: ")
    assert second.camera == CAM and {k: second.job.progress[k] for k in ("stage", "done", "total")} == {
        "stage": "render", "done": 4, "total": 4}                      # camera 2/3 rendered its frames to the end
    level, message = follow.report(bpy.context, status)
    assert level == "ERROR" and message.startswith("render of 3 camera paths: 1 finished; 'Assets': ")
    assert "objects['Assets']: its output folder would be 'Assets'" in message
    assert "'Camera path 2 m right': render cancelled: finished outputs are kept" in message
    assert [(o[0], o[1]) for o in follow.outcomes] == [("Assets", "failed"), ("Camera path 2 m left", "finished"),
                                                       ("Camera path 2 m right", "cancelled")]
    assert not (tmp_path / "out" / "Assets").exists()
    assert len(list((tmp_path / "out" / CAM_DIR / "conditions").glob("frame_*.exr"))) == 4


def _fake_python(tmp_path, body):
    path = tmp_path / "fake-python"
    path.write_text("#!/bin/sh\n" + body + "\n")
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return str(path)


def test_crash_hang_and_missing_pieces_leave_the_scene_alone(street_scene, tmp_path, addon):
    prefs = bpy.context.preferences.addons[addon].preferences
    before = _state()
    prefs.backend_python = _fake_python(tmp_path, "echo 'Segmentation fault' >&2; exit 139")
    with pytest.raises(RuntimeError, match="code 139: Segmentation fault"):
        bpy.ops.scpainter.render_conditions()
    assert _state() == before
    prefs.backend_python = _fake_python(tmp_path, "exec sleep 60")
    with pytest.raises(RuntimeError, match="hung after 2 s"):
        bpy.ops.scpainter.render_conditions(timeout=2.0)
    assert _state() == before
    prefs.backend_python = str(tmp_path / "no-such-python")
    with pytest.raises(RuntimeError, match="Backend Python not found.*no-such-python"):
        bpy.ops.scpainter.render_conditions()
    prefs.backend_python, prefs.checkpoint_dir = sys.executable, str(tmp_path / "no-such-checkpoint")
    with pytest.raises(RuntimeError, match="no-such-checkpoint"):
        bpy.ops.scpainter.generate()
    assert _state() == before and not (tmp_path / "out" / CAM_DIR / "generated").exists()


def test_followed_runs_cancel_finish_and_time_out(street_scene, tmp_path, addon):
    """The modal operator's state machine (camera_run.Follower), driven as the UI timer drives it: Esc keeps the frames
    done and leaves the scene alone; a followed run to the end loads its results; a hung backend times out."""
    import time

    from backend.render import channels

    camera_run = sys.modules[f"{addon}.scpainter_blender.runs.camera_run"]  # the installed add-on's module
    before = _state()
    # Esc once a sample sees the first frame rendered: twelve frames, so eleven are left to render after it (a
    # warm backend renders a frame in ~0.1 s; the loop samples every 0.05 s), even with the CPU shared
    street_scene.frame_end = 12
    follow = camera_run.Follower("render", *camera_run.start(bpy.context, "render"))
    seen = []
    # (a first frame rendered: the kernels' compile progress comes first when they are not cached yet)
    while follow.tick() == "running" and not (camera_run.ACTIVE and camera_run.ACTIVE["stage"] == "render"):
        seen.append(dict(camera_run.ACTIVE))
        time.sleep(0.05)
    assert camera_run.ACTIVE["command"] == "render" and "Esc" in follow.status_text and 0 < follow.fraction <= 1
    follow.stop()                                                   # Esc
    level, message = follow.report(bpy.context, "cancelled")
    assert level == "WARNING" and "kept" in message and not camera_run.ACTIVE
    frames = sorted((tmp_path / "out" / CAM_DIR / "conditions").glob("frame_*.exr"))
    assert 1 <= len(frames) < 12 and all(channels.read(f)["R"].shape == (147, 259) for f in frames)
    assert not list((tmp_path / "out" / CAM_DIR / "conditions").glob("*.tmp"))
    assert _state() == before
    street_scene.frame_end = 4
    # followed to the end: resumes, finishes, loads the previews behind the camera
    follow = camera_run.Follower("render", *camera_run.start(bpy.context, "render"))
    while (status := follow.tick()) == "running":
        time.sleep(0.05)
    assert status == "finished"
    level, message = follow.report(bpy.context, status)
    # finished, with a warning: the street's parked cars the import proposed are not reviewed yet (issue 41: no
    # visible object goes unlabelled silently), each an ignore region until accepted
    assert level == "WARNING" and message.startswith("Condition layers of 4 frames") and "proposal_01" in message
    assert bpy.data.images[_name("SCPainter Conditions")]["scpainter_frames"] == 4
    # Generate followed without a checkpoint: the baseline, said from the first tick to the report
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.checkpoint_dir = ""
    follow = camera_run.Follower("generate", *camera_run.start(bpy.context, "generate"),
                           model=camera_run.planned_model(bpy.context, "generate"))
    texts = [follow.status_text]
    while (status := follow.tick()) == "running":
        texts.append(follow.status_text if camera_run.ACTIVE else "")
        time.sleep(0.05)
    assert status == "finished" and texts[0].startswith("SCPainter generate (Baseline): starting 0/1")
    assert all(t.startswith("SCPainter generate (Baseline): ") for t in texts if t), texts
    # the run's own last progress event (recorded, not a sample: a warm backend may finish between two samples)
    assert {k: follow.job.progress[k] for k in ("stage", "done", "total", "model")} == {
        "stage": "generate", "done": 4, "total": 4, "model": "baseline"}
    level, message = follow.report(bpy.context, status)
    assert level == "WARNING" and message.startswith("Baseline video (OpenCV Telea inpainting, no model): ")
    assert "proposal_01" in message   # generate labels as render does: the unreviewed proposals said again
    assert "Checkpoint Folder" in message and bpy.data.images[_name("SCPainter Baseline")]["scpainter_frames"] == 4
    # a backend that never answers
    prefs.backend_python = _fake_python(tmp_path, "exec sleep 60")
    follow = camera_run.Follower("render", *camera_run.start(bpy.context, "render"), timeout=1.0)
    while (status := follow.tick()) == "running":
        time.sleep(0.05)
    assert status == "timeout" and follow.report(bpy.context, status)[0] == "ERROR" and not camera_run.ACTIVE


def test_check_backend_reports_what_is_missing(addon, tiny_checkpoint, tmp_path):
    preferences = sys.modules[f"{addon}.scpainter_blender.runs.preferences"]
    prefs = bpy.context.preferences.addons[addon].preferences
    try:
        prefs.backend_python, prefs.checkpoint_dir = sys.executable, tiny_checkpoint
        assert bpy.ops.scpainter.check_backend() == {"FINISHED"}
        doctor = preferences.DOCTOR
        assert doctor["ok"] and "ready" in doctor["text"] and "torch" in doctor["text"]
        prefs.checkpoint_dir = str(tmp_path)                         # a folder that is not a checkpoint
        assert bpy.ops.scpainter.check_backend() == {"FINISHED"}
        assert not preferences.DOCTOR["ok"] and "scpainter.json" in preferences.DOCTOR["text"]
        # an interpreter without numpy (Blender's own, say): the missing packages and the README's fix, no traceback
        fake = tmp_path / "no_numpy" / "numpy"
        fake.mkdir(parents=True)
        (fake / "__init__.py").write_text("raise ModuleNotFoundError(\"No module named 'numpy'\", name='numpy')\n")
        wrapper = tmp_path / "python-without-numpy"
        wrapper.write_text(f"#!/bin/sh\nPYTHONPATH={tmp_path / 'no_numpy'}:$PYTHONPATH exec {sys.executable} \"$@\"\n")
        wrapper.chmod(0o755)
        prefs.backend_python, prefs.checkpoint_dir = str(wrapper), ""
        assert bpy.ops.scpainter.check_backend() == {"FINISHED"}
        assert not preferences.DOCTOR["ok"] and "missing numpy" in preferences.DOCTOR["text"]
        assert f"{wrapper} -m pip install -r requirements.txt" in preferences.DOCTOR["text"]
        prefs.backend_python = str(tmp_path / "no-python")
        with pytest.raises(RuntimeError, match="Backend Python not found"):
            bpy.ops.scpainter.check_backend()
        assert not preferences.DOCTOR["ok"]
    finally:
        prefs.backend_python, prefs.checkpoint_dir = "", ""


def test_export_labels_operator_and_its_report(addon, empty_scene):
    """The operator offers the backend's formats (their one home: core.backend_protocol); the report of a finished
    export says the format, counts and where (nothing is loaded into the scene)."""
    protocol = sys.modules[addon + ".scpainter_blender.core.backend_protocol"]
    camera_run = sys.modules[addon + ".scpainter_blender.runs.camera_run"]
    rna = bpy.ops.scpainter.export_labels.get_rna_type()
    assert [i.identifier for i in rna.properties["format"].enum_items] == list(protocol.EXPORT_FORMAT_NAMES)
    done = {"format": "openlabel", "frames": 3, "objects": 7, "images": "conditions", "out": "/x/export/openlabel"}
    text = camera_run.finish(bpy.context, "export", "/x", done)
    assert text.startswith("OpenLABEL export: 3 frames, 7 objects") and "/x/export/openlabel" in text
    assert "condition previews" in text and len(bpy.data.images) == 0


def test_a_run_with_warnings_is_reported_as_a_warning():
    """The backend's warning events (weak frames, a camera inside a car) turn a finished run's report into a
    warning quoting the first and counting the rest."""
    from scpainter_blender.runs import camera_run

    assert camera_run.with_warnings("Condition layers of 4 frames", []) == ("INFO", "Condition layers of 4 frames")
    level, text = camera_run.with_warnings("Condition layers of 4 frames", [
        {"event": "warning", "code": "camera_inside_object", "message": "frame 3: the camera is inside 'car'"},
        {"event": "warning", "code": "low_coverage", "message": "frame 4: only 40% ..."}])
    assert level == "WARNING" and "2 warnings: frame 3: the camera is inside 'car' (and 1 more" in text
