"""scene/results.py: a render's condition previews and labelled previews loaded as image sequences, from PNGs
written here under the output layout's names."""

import os

import bpy
import numpy as np

from backend.png import write_png
from scpainter_blender.core.output_layout import OutputLayout
from scpainter_blender.scene import results, runs


def _write(layout, frames, labelled=True):
    for f in frames:
        write_png(layout.condition_preview(f), np.full((4, 6, 3), f / 10.0))
        if labelled:
            write_png(layout.labelled_preview(f), np.full((4, 6, 3), 1.0 - f / 10.0))


def test_render_loads_conditions_and_labels(empty_scene, tmp_path):
    layout = OutputLayout(str(tmp_path / "out"))
    os.makedirs(layout.conditions)
    _write(layout, (1, 2, 3))
    report = runs.finish(bpy.context, "render", layout.root, {"output_dir": layout.root, "frames": 3})
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
    runs.finish(bpy.context, "render", layout.root, {"output_dir": layout.root, "frames": 2})
    assert results.CONDITIONS in bpy.data.images and results.LABELS not in bpy.data.images
