"""A project folder moves: the files a .blend's objects were imported from are stored relative to it (``//``), so a
copy of the folder reads its own files and the old folder can go."""

import os
import shutil
import sys

import bpy

from scpainter_blender.core import job as J, shapes


def test_a_copied_project_reads_its_own_files(addon, empty_scene, tmp_path):
    """Imported into an unsaved scene (absolute: nothing to be relative to), saved into the project folder (the path
    becomes ``//car.ply``), the folder copied elsewhere and the original deleted: the copy opens, exports, and its job
    reads the copy's ``car.ply``. *Save As* elsewhere remaps the path (it still reaches the same file), *Save Copy*
    leaves the open file's value as it was, and with Blender's Relative Paths preference off paths stay absolute."""
    old, new = tmp_path / "old" / "project", tmp_path / "new" / "project"
    old.mkdir(parents=True)
    ply = str(old / "car.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=60, seed=1))
    assert bpy.ops.scpainter.import_gaussians(filepath=ply, target_length=4.4) == {"FINISHED"}
    car = bpy.context.active_object
    assert car["scpainter_source"] == ply  # the .blend is not saved yet
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam
    bpy.ops.wm.save_as_mainfile(filepath=str(old / "scene.blend"))
    assert car["scpainter_source"] == "//car.ply"

    shutil.copytree(old, new)
    shutil.rmtree(old)
    bpy.ops.wm.open_mainfile(filepath=str(new / "scene.blend"))
    job_path = str(new / "job.json")
    assert bpy.ops.scpainter.export_job(filepath=job_path) == {"FINISHED"}
    (asset,) = J.load(job_path).assets
    assert asset.ply == "car.ply" and os.path.isfile(J.resolve(job_path, asset.ply))
    assert J.resolve(job_path, asset.ply) == str(new / "car.ply")

    paths = sys.modules[addon + ".scpainter_blender.scene.paths"]
    car = bpy.data.objects["car"]
    (tmp_path / "elsewhere").mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "elsewhere" / "moved.blend"))
    assert car["scpainter_source"] == "//../new/project/car.ply"
    assert paths.resolve(car["scpainter_source"]) == str(new / "car.ply")
    bpy.ops.wm.save_as_mainfile(filepath=str(new / "copy.blend"), copy=True)
    assert car["scpainter_source"] == "//../new/project/car.ply"  # the open file is still elsewhere/moved.blend
    bpy.ops.wm.open_mainfile(filepath=str(new / "copy.blend"))
    assert bpy.data.objects["car"]["scpainter_source"] == "//car.ply"  # the copy's own, beside it
    prefs = bpy.context.preferences.filepaths
    prefs.use_relative_paths = False
    try:
        assert paths.stored(str(new / "car.ply")) == str(new / "car.ply")
    finally:
        prefs.use_relative_paths = True


def test_a_copied_project_shows_its_own_results(addon, empty_scene, tmp_path):
    """Issue 42 (h1's leftover): a render's previews were loaded by absolute path, so a copied project showed the
    old folder's results (or none once it was gone). Loaded into a saved .blend they are ``//``-relative, and the
    copy's image sequence reads the copy's files."""
    import numpy as np

    from backend.png import write_png
    from scpainter_blender.core.output_layout import OutputLayout

    results = sys.modules[addon + ".scpainter_blender.scene.results"]
    old, new = tmp_path / "old" / "project", tmp_path / "new" / "project"
    layout = OutputLayout(str(old / "out"))
    os.makedirs(layout.conditions)
    for f in (1, 2):
        write_png(layout.condition_preview(f), np.full((4, 6, 3), f / 10.0))
    bpy.ops.wm.save_as_mainfile(filepath=str(old / "scene.blend"))
    img = results.load_conditions(layout.conditions)
    assert img.filepath == "//out/conditions/" + os.path.basename(layout.condition_preview(1))
    bpy.ops.wm.save_mainfile()
    shutil.copytree(old, new)
    shutil.rmtree(old)
    bpy.ops.wm.open_mainfile(filepath=str(new / "scene.blend"))
    img = bpy.data.images[results.CONDITIONS]
    assert bpy.path.abspath(img.filepath) == OutputLayout(str(new / "out")).condition_preview(1)
    assert os.path.isfile(bpy.path.abspath(img.filepath))
