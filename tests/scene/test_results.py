"""scene/results.py: a render's condition previews and labelled previews loaded as image sequences, from PNGs
written here under the output layout's names."""

import os

import bpy
import numpy as np

from backend.png import write_png
from scpainter_blender.core.output_layout import OutputLayout
from scpainter_blender.runs import camera_run
from scpainter_blender.scene import results


def _write(layout, frames, labelled=True):
    for f in frames:
        write_png(layout.condition_preview(f), np.full((4, 6, 3), f / 10.0))
        if labelled:
            write_png(layout.labelled_preview(f), np.full((4, 6, 3), 1.0 - f / 10.0))


def test_render_loads_conditions_and_labels(empty_scene, tmp_path):
    layout = OutputLayout(str(tmp_path / "out"))
    os.makedirs(layout.conditions)
    _write(layout, (1, 2, 3))
    report = camera_run.finish(bpy.context, "render", layout.root, {"output_dir": layout.root, "frames": 3})
    assert "3 frames" in report
    cond, labels = bpy.data.images[results.CONDITIONS], bpy.data.images[results.LABELS]
    assert labels.name == "SCPainter Labels" and labels.source == "SEQUENCE" and labels.use_fake_user
    assert bpy.path.abspath(labels.filepath) == layout.labelled_preview(1)
    assert bpy.path.abspath(cond.filepath) == layout.condition_preview(1)
    assert labels["scpainter_frames"] == cond["scpainter_frames"] == 3
    # rendered again into another folder: the same datablock, pointed there (no pile of images)
    other = OutputLayout(str(tmp_path / "again"))
    os.makedirs(other.conditions)
    _write(other, (4, 5))
    assert results.load_labels(other.conditions) == labels
    assert bpy.path.abspath(labels.filepath) == other.labelled_preview(4) and labels["scpainter_frames"] == 2
    assert len([i for i in bpy.data.images if i.name.startswith(results.LABELS)]) == 1


def test_no_labelled_previews_no_labels(empty_scene, tmp_path):
    """A backend from before labels writes only the condition previews: no labels image."""
    layout = OutputLayout(str(tmp_path / "out"))
    os.makedirs(layout.conditions)
    _write(layout, (1, 2), labelled=False)
    assert results.load_labels(layout.conditions) is None
    camera_run.finish(bpy.context, "render", layout.root, {"output_dir": layout.root, "frames": 2})
    assert results.CONDITIONS in bpy.data.images and results.LABELS not in bpy.data.images


def _camera(name):
    obj = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _write_generated(layout, frames):
    os.makedirs(layout.generated, exist_ok=True)
    for f in frames:
        write_png(layout.generated_frame(f), np.full((4, 6, 3), f / 10.0))


def test_each_camera_has_its_own_results_named_after_it(empty_scene, tmp_path):
    """Results are loaded as their camera's ("<kind> · <camera>") and shown behind that camera; loading another
    camera's never renames, repoints or removes the first's, also when the generator changes (baseline, model)."""
    a, b = _camera("Path A"), _camera("Path B")
    empty_scene.camera = a
    out_a, out_b = OutputLayout(str(tmp_path / "Path_A")), OutputLayout(str(tmp_path / "Path_B"))
    for layout, frames in ((out_a, (1, 2, 3)), (out_b, (1, 2))):
        os.makedirs(layout.conditions)
        _write(layout, frames)
        _write_generated(layout, frames)
    camera_run.finish(bpy.context, "render", out_a.root, {"frames": 3}, camera="Path A")
    camera_run.finish(bpy.context, "render", out_b.root, {"frames": 2}, camera="Path B")
    cond_a = bpy.data.images["SCPainter Conditions · Path A"]
    cond_b = bpy.data.images["SCPainter Conditions · Path B"]
    assert bpy.path.abspath(cond_a.filepath) == out_a.condition_preview(1) and cond_a["scpainter_frames"] == 3
    assert bpy.path.abspath(cond_b.filepath) == out_b.condition_preview(1) and cond_b["scpainter_frames"] == 2
    assert "SCPainter Labels · Path A" in bpy.data.images and "SCPainter Labels · Path B" in bpy.data.images
    assert a.data.background_images[0].image == cond_a and b.data.background_images[0].image == cond_b
    assert empty_scene.camera == a                               # B's results went behind B; the scene camera stays
    # B's baseline video, then A's model video: each camera's own datablocks, the other camera's left as they are
    camera_run.finish(bpy.context, "generate", out_b.root, {"model": "baseline", "frames_dir": out_b.generated,
                                                      "video": out_b.video}, camera="Path B")
    base_b = bpy.data.images["SCPainter Baseline · Path B"]
    assert base_b["scpainter_model"] == "baseline" and b.data.background_images[0].image == base_b
    assert len(b.data.background_images) == 1 and a.data.background_images[0].image == cond_a
    camera_run.finish(bpy.context, "generate", out_a.root, {"model": "scpainter", "frames_dir": out_a.generated,
                                                      "video": out_a.video}, camera="Path A")
    gen_a = bpy.data.images["SCPainter Generated · Path A"]
    assert "SCPainter Baseline · Path B" in bpy.data.images and b.data.background_images[0].image == base_b
    assert bpy.path.abspath(gen_a.filepath) == out_a.generated_frame(1)
    assert bpy.path.abspath(base_b.filepath) == out_b.generated_frame(1)
    # B's model video replaces B's baseline (the same files), A's stays
    camera_run.finish(bpy.context, "generate", out_b.root, {"model": "scpainter", "frames_dir": out_b.generated,
                                                      "video": out_b.video}, camera="Path B")
    assert base_b.name == "SCPainter Generated · Path B" and b.data.background_images[0].image == base_b
    assert "SCPainter Baseline · Path B" not in bpy.data.images and gen_a.name == "SCPainter Generated · Path A"
    assert sorted(i.name for i in bpy.data.images) == sorted(
        f"SCPainter {kind} · Path {c}" for kind in ("Conditions", "Labels", "Generated") for c in "AB")
    # rendered again: the same datablocks (found by what they hold, whatever their names became)
    cond_a.name = "my conditions"
    assert results.load_conditions(out_a.conditions, "Path A") == cond_a and cond_a.name == "my conditions"


def test_a_results_slot_from_before_cameras_is_reused(empty_scene, tmp_path):
    """A .blend from before per-camera results: its "SCPainter Conditions" stays as it is, and the camera's
    background slot showing it now shows the camera's own results."""
    cam = _camera("Path A")
    empty_scene.camera = cam
    old_layout = OutputLayout(str(tmp_path / "old"))
    os.makedirs(old_layout.conditions)
    _write(old_layout, (1, 2))
    old = results.load_conditions(old_layout.conditions)               # no camera: the bare name, as before
    for key in (results.RESULT, results.CAMERA):
        del old[key]                                                    # as a .blend saved before writes it
    results.show_behind_camera(empty_scene, old)
    new_layout = OutputLayout(str(tmp_path / "Path_A"))
    os.makedirs(new_layout.conditions)
    _write(new_layout, (1, 2, 3))
    camera_run.finish(bpy.context, "render", new_layout.root, {"frames": 3})   # the scene camera's run
    new = bpy.data.images["SCPainter Conditions · Path A"]
    assert old.name == "SCPainter Conditions" and bpy.path.abspath(old.filepath) == old_layout.condition_preview(1)
    assert len(cam.data.background_images) == 1 and cam.data.background_images[0].image == new
