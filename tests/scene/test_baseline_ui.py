"""Without a checkpoint, Generate makes the OpenCV inpainting baseline: what the panel, the tooltip, the progress text
and the exported job say, without running the backend (the runs themselves: tests/runs/test_camera_run.py, tests/cli/)."""

import json
import sys

import bpy
import pytest


def _module(addon, name):
    return sys.modules[f"{addon}.{name}"]  # the installed add-on's module


@pytest.fixture
def prefs(addon):
    p = bpy.context.preferences.addons[addon].preferences
    yield p
    p.checkpoint_dir = ""


def test_generate_button_and_tooltip_say_baseline_without_a_checkpoint(empty_scene, addon, prefs, tmp_path):
    camera_run = _module(addon, "scpainter_blender.runs.camera_run")
    generate = _module(addon, "operators.backend_run").SCPAINTER_OT_generate
    prefs.checkpoint_dir = ""
    text, note = camera_run.generate_ui(bpy.context)                      # what the panel draws by the button
    assert text == "Generate (Baseline)" and camera_run.planned_model(bpy.context) == "baseline"
    said = " ".join(note)
    assert "OpenCV inpainting baseline, not the SCPainter model" in said
    assert "Preferences > Add-ons > SCPainter > Checkpoint Folder" in said
    tip = generate.description(bpy.context, None)
    assert "baseline" in tip and "not SCPainter's output" in tip and "Checkpoint Folder" in tip
    prefs.checkpoint_dir = str(tmp_path)
    assert camera_run.generate_ui(bpy.context) == ("Generate", ())
    assert camera_run.planned_model(bpy.context) == "scpainter"
    assert "baseline" not in generate.description(bpy.context, None)
    assert camera_run.planned_model(bpy.context, "render") is None


def test_progress_text_names_the_generator(addon):
    camera_run = _module(addon, "scpainter_blender.runs.camera_run")
    run = {"command": "generate", "model": "baseline", "stage": "render", "done": 2, "total": 4}
    assert camera_run.progress_text(run) == "generate (Baseline): render 2/4"
    assert camera_run.progress_text({**run, "model": "scpainter"}) == "generate (SCPainter): render 2/4"
    assert camera_run.progress_text({**run, "command": "render", "model": None}) == "render: render 2/4"
    # a rig job's progress names the rig camera its event names (the surround demo printed six "render 1/16")
    rig_run = {**run, "command": "render", "model": None, "sensor": "CAM_BACK", "done": 1, "total": 16}
    assert camera_run.progress_text(rig_run) == "render CAM_BACK: render 1/16"


def test_job_export_writes_the_inpainting_method_only_when_chosen(empty_scene, addon, prefs, tmp_path):
    """``generate`` holds the checkpoint of the preferences and the scene's Baseline Inpainting, each only when
    set: a default scene leaves the backend's defaults (and its auto generator) in charge."""
    from vggt_cases import drive, write

    job_export = _module(addon, "scpainter_blender.scene.job_export")
    arrays, _, _ = drive(S=2, H=12, W=16)  # something to render: a job of a camera alone is refused
    assert bpy.ops.scpainter.import_vggt(filepath=write(tmp_path, arrays)) == {"FINISHED"}
    path = str(tmp_path / "job.json")

    def exported(**kw):
        job_export.export_job(bpy.context, path, **kw)
        return json.loads(open(path).read()).get("generate")

    assert empty_scene.scpainter_baseline_inpaint == "DEFAULT" and exported() is None
    empty_scene.scpainter_baseline_inpaint = "NAVIER_STOKES"
    assert exported() == {"inpaint": "navier-stokes"}
    assert exported(checkpoint=str(tmp_path)) == {"checkpoint": str(tmp_path), "inpaint": "navier-stokes"}
    empty_scene.scpainter_baseline_inpaint = "TELEA"
    assert exported() == {"inpaint": "telea"}
    empty_scene.scpainter_baseline_inpaint = "DEFAULT"
    assert exported(checkpoint=str(tmp_path)) == {"checkpoint": str(tmp_path)}
