"""What the tests of ``blender -c scpainter`` (tests/cli/) share: the add-on's cli package, the last JSON event a
command printed, and a saved street scene to run commands on."""

import json
import sys

import bpy


def cli(addon):
    """The installed add-on's ``scpainter_blender.cli`` (``addon``: its package name), as Blender imports it."""
    return sys.modules[addon + ".scpainter_blender.cli"]


def last_event(capsys):
    """The last JSON event line on standard output since the previous read."""
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    return json.loads(lines[-1])


#: The scene camera of ``street_blend``'s scene (street_with_car's camera path) and its output folder's name.
CAM, CAM_DIR = "Camera path 2 m left", "Camera_path_2_m_left"


def street_blend(street, folder, second_path=False):
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
