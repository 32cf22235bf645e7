"""Render Conditions with nothing to render is answered in Blender, without a backend (runs/render_plan.py).

The proof that no backend starts: after a first render the preferences point Backend Python at a file that does
not exist, so any backend start fails; a second click with nothing changed still finishes, reports "up to date"
and touches no file. An edit (a car moved, a class changed) makes the same click need the backend again."""

import os
import sys

import bpy
import pytest

from scpainter_blender.core.output_layout import OutputLayout
from tests_support import street_with_car

CAM_DIR = "Camera_path_2_m_left"


@pytest.fixture
def scene(addon, street, tmp_path):
    scene = street_with_car(street, tmp_path)
    scene.render.resolution_percentage = 25
    scene.frame_end = 3
    scene.scpainter_output_dir = str(tmp_path / "out")
    prefs = bpy.context.preferences.addons[addon].preferences
    prefs.backend_python, prefs.device = sys.executable, "CPU"
    yield scene, prefs
    prefs.backend_python, prefs.device = "", "AUTO"
    bpy.ops.wm.read_homefile(use_empty=True)


def _times(layout):
    return {f: os.stat(layout.condition_exr(f)).st_mtime_ns for f in (1, 2, 3)}


def test_an_unchanged_scene_is_up_to_date_without_a_backend(scene, tmp_path, capsys):
    sc, prefs = scene
    layout = OutputLayout(tmp_path / "out" / CAM_DIR)
    assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}
    before = _times(layout)
    prefs.backend_python = str(tmp_path / "no-such-python")      # any backend start would fail now
    capsys.readouterr()
    assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}
    assert "up to date" in capsys.readouterr().out
    assert _times(layout) == before
    assert bpy.data.images[f"SCPainter Conditions · {sc.camera.name}"]["scpainter_frames"] == 3

    car = next(o for o in sc.objects if o.get("scpainter_kind") == "gaussian_asset")
    car.location.x += 0.3                                          # an edit: the backend has work again
    with pytest.raises(RuntimeError, match="Backend Python not found"):   # ... and cannot start
        bpy.ops.scpainter.render_conditions()
    prefs.backend_python = sys.executable
    assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}
    assert _times(layout) != before

    car["scpainter_class"] = "van"                                  # a label-only edit: new labels, by the backend
    prefs.backend_python = str(tmp_path / "no-such-python")
    with pytest.raises(RuntimeError, match="Backend Python not found"):
        bpy.ops.scpainter.render_conditions()
    prefs.backend_python = sys.executable
    assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}
    prefs.backend_python = str(tmp_path / "no-such-python")
    assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}    # and then up to date again


def test_render_all_paths_skips_the_paths_that_are_up_to_date(scene, tmp_path, capsys):
    """Render All Paths renders the paths with work and answers the others without a backend."""
    sc, prefs = scene
    bpy.ops.scpainter.new_camera_path(shift=-2.0)                  # a second path: the scene camera now
    assert bpy.ops.scpainter.render_all_camera_paths() == {"FINISHED"}
    prefs.backend_python = str(tmp_path / "no-such-python")       # any backend start would fail now
    capsys.readouterr()
    assert bpy.ops.scpainter.render_all_camera_paths() == {"FINISHED"}
    out = capsys.readouterr().out
    told = [line for line in out.splitlines() if line.startswith("scpainter render '")]   # each camera's outcome
    assert "2 camera paths: 2 finished" in out and len(told) == 2 and all("up to date" in t for t in told), out
